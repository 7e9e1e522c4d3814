"""Corpus runs: batched, resumable, one manifest line per mesh (see :mod:`.runner`)."""
from .runner import MANIFEST, RunSummary, discover_inputs, read_manifest, run_corpus

__all__ = ["MANIFEST", "RunSummary", "discover_inputs", "read_manifest", "run_corpus"]
