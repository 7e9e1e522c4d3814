"""DEC operators and the Killing operator, block-diagonal over a :class:`~torchakvf.MeshBatch`."""
from .geometry import BatchGeometry, batch_geometry
from .dec import d0, d1, star0, star1, star2, angle_defect, angle_sum
from .killing import KillingSystem, killing_operator, REMEDIES

__all__ = ["BatchGeometry", "batch_geometry", "d0", "d1", "star0", "star1", "star2", "angle_defect",
           "angle_sum", "KillingSystem", "killing_operator", "REMEDIES"]
