"""Eigensolvers on one sparse Cholesky (CHOLMOD) shift-invert factor per mesh (for the batched
LOBPCG on CUDA, one block-diagonal factor per batch): block Krylov (the CPU default), segmented
LOBPCG (the default elsewhere) and ARPACK Lanczos; :class:`AKVFSolver` holds a batch's operator,
factors, solver choice and fallbacks."""
from .akvf_result import AKVFResult
from .akvf_solver import AKVFSolver
from .factor import BlockDiagonalFactor, ShiftedFactor
from .krylov import KrylovBasis, block_krylov
from .lanczos import shift_invert_lanczos
from .lobpcg import EigenResult, relative_residuals, segmented_lobpcg
from .remedy import killing_system

__all__ = ["AKVFResult", "AKVFSolver", "BlockDiagonalFactor", "ShiftedFactor", "EigenResult", "block_krylov",
           "KrylovBasis", "killing_system", "relative_residuals", "segmented_lobpcg", "shift_invert_lanczos"]
