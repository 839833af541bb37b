"""Mesh adaptation shared by the RIS and ELD families: bisection with history, marking, transfer.

See :mod:`rothe.fem.adapt.bisection` (the adaptive mesh), :mod:`rothe.fem.adapt.marking`
(Doerfler marking and the :class:`SpaceAdaptivity` options) and :mod:`rothe.fem.adapt.transfer`
(sparse transfer matrices of P1/P2 scalar and vector fields), and ``docs/adaptivity.md``.
"""

from .bisection import AdaptiveMesh, MeshChange, check_adaptable
from .transfer import free_transfer, transfer_matrix, transfer_vectors

__all__ = ["AdaptiveMesh", "MeshChange", "check_adaptable", "free_transfer", "transfer_matrix",
           "transfer_vectors"]
