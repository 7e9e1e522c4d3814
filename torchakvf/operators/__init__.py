"""DEC operators, the Killing operator and Whitney interpolation, block-diagonal over a
:class:`~torchakvf.MeshBatch`."""
from .dec import angle_defect, angle_sum, d0, d1, star0, star1, star2
from .geometry import BatchGeometry, batch_geometry
from .killing import REMEDIES, KillingSystem, killing_operator
from .whitney import whitney_face_vectors

__all__ = ["BatchGeometry", "batch_geometry", "d0", "d1", "star0", "star1", "star2", "angle_defect",
           "angle_sum", "KillingSystem", "killing_operator", "REMEDIES",
           "whitney_face_vectors"]
