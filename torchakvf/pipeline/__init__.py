"""Corpus runs: batched, resumable, one manifest line per mesh (see :mod:`.runner`)."""
from ..io.manifest import MANIFEST, read_manifest
from .inputs import discover_inputs
from .runner import RunSummary, run_corpus

__all__ = ["MANIFEST", "RunSummary", "discover_inputs", "read_manifest", "run_corpus"]
