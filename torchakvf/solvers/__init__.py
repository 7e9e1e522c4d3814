"""Eigensolvers: segmented LOBPCG with a shift-invert (sparse Cholesky) preconditioner."""
from .factor import ShiftedFactor
from .lobpcg import EigenResult, relative_residuals, segmented_lobpcg

__all__ = ["ShiftedFactor", "EigenResult", "relative_residuals", "segmented_lobpcg"]
