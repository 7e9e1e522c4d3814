"""Eigensolvers on one sparse Cholesky (CHOLMOD) shift-invert factor per mesh (for the batched
LOBPCG on CUDA, one block-diagonal factor per batch): block Krylov (the CPU default), segmented
LOBPCG (the default elsewhere) and ARPACK Lanczos."""
from .factor import BlockDiagonalFactor, ShiftedFactor
from .krylov import block_krylov
from .lobpcg import EigenResult, relative_residuals, segmented_lobpcg
from .lanczos import shift_invert_lanczos

__all__ = ["BlockDiagonalFactor", "ShiftedFactor", "EigenResult", "block_krylov", "relative_residuals",
           "segmented_lobpcg", "shift_invert_lanczos"]
