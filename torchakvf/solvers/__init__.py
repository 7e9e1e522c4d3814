"""Eigensolvers: segmented LOBPCG with a shift-invert (sparse Cholesky) preconditioner."""
from .factor import ShiftedFactor
from .lobpcg import EigenResult, relative_residuals, segmented_lobpcg
from .lanczos import shift_invert_lanczos

__all__ = ["ShiftedFactor", "EigenResult", "relative_residuals", "segmented_lobpcg", "shift_invert_lanczos"]
