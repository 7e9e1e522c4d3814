"""Choosing k per mesh: the algorithm is :mod:`torchakvf.parts.k_auto` (``segment(..., k="auto")``);
the evaluation imports it from here."""
from ..parts.k_auto import (
    DEFAULT_K_RANGE,
    DEFAULT_RULE,
    MERGE_TAU,
    RULES,
    SCAN_MIN_K,
    AutoSegmentation,
    KChoice,
    KScan,
    check_k_range,
    choose_k,
    pick_k,
    scan_k,
    scan_options,
    scan_overseg,
    segment_auto,
)

__all__ = ["RULES", "DEFAULT_RULE", "MERGE_TAU", "SCAN_MIN_K", "scan_overseg", "scan_options", "DEFAULT_K_RANGE",
           "KScan", "KChoice", "AutoSegmentation", "scan_k", "choose_k", "segment_auto", "pick_k", "check_k_range"]
