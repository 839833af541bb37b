"""Mesh adaptation shared by the RIS and ELD families: bisection with history, marking, transfer.

* :class:`AdaptiveMesh` (:mod:`.bisection`): refine/coarsen a triangle or tetrahedron mesh by
  bisection, keeping the history, the named boundary parts and subdomains; every operation
  returns a :class:`MeshChange`.
* :class:`SpaceAdaptivity`, :func:`adapt_mesh` (:mod:`.marking`): Doerfler refinement,
  coarsening, ``space_tol``, ``max_dofs``, ``adapt_every``.
* :func:`transfer_matrix` (``MeshChange.transfer``), :func:`free_transfer`,
  :func:`transfer_vectors` (:mod:`.transfer`): sparse maps of P1/P2 scalar and vector fields.

Guide with a worked example: ``docs/adaptivity.md``.
"""

from .bisection import AdaptiveMesh, MeshChange, check_adaptable
from .marking import SpaceAdaptivity, adapt_mesh, coarsen_marking, doerfler_marking
from .transfer import free_transfer, transfer_matrix, transfer_vectors

__all__ = [
    "AdaptiveMesh",
    "MeshChange",
    "SpaceAdaptivity",
    "adapt_mesh",
    "check_adaptable",
    "coarsen_marking",
    "doerfler_marking",
    "free_transfer",
    "transfer_matrix",
    "transfer_vectors",
]
