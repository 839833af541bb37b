"""Hysteresis of coarsening: what keeps a mesh from refining and coarsening the same cells back
and forth.

Doerfler marking with a coarsening budget relative to the tolerance (:mod:`.marking`) looks at
one estimate at a time. Coarsened cells carry larger indicators afterwards (a P1 cell merged
with its sibling: its squared indicator about doubles, more where the state is not smooth), so
repeated every adaptation the coarsening lifts the estimate back above the tolerance, the next
adaptation refines the same cells again, and the mesh cycles. Measured on Example 7.2 with
``--adapt-space`` (16 x 16, regime, tol 1e-5, before this module): 139 mesh changes in 400 steps,
midpoints created and removed up to 15 times each; every change moves the state by a transfer
that is not stationary on the new mesh, and the run stalled.

A bisection creates one vertex (the midpoint of the refinement edge) and coarsening removes it
again: "a cell refined and coarsened again" is "a vertex created, removed and created again".
:class:`VertexHistory` follows every vertex through the changes (by its coordinates, which a
re-created midpoint reproduces bit for bit) and keeps

* ``birth``: the adaptation (a counter of :meth:`MeshAdaptation.cycle` calls) in which each
  vertex of the current mesh was created (-1 for the vertices of the initial mesh);
* the number of times each vertex has been removed so far (also of vertices not in the mesh).

Two rules use them (:meth:`VertexHistory.frozen_cells`), both applied to the coarsening marks:

* **coarsen_delay** = k: a cell with a vertex created in the last k adaptations is not
  coarsened (a freshly refined region is first used before it may go);
* **max_recoarsen** = m: a vertex already removed m times is never removed again: once it is
  back, the cells around it are not coarsened for the rest of the run.

A vertex is removed only when every cell around it is marked for coarsening
(:mod:`.bisection`), so leaving the cells of a vertex unmarked keeps it. Hence the bound this
module exists for: **every vertex is created at most m + 1 times and removed at most m times**,
i.e. no cell is refined and coarsened again more than m times (tested).
"""

from __future__ import annotations

import numpy as np


def _keys(points: np.ndarray) -> np.ndarray:
    """One hashable, sortable key per point: its coordinates' bytes (exact, no rounding)."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    return pts.view(np.dtype((np.void, pts.dtype.itemsize * pts.shape[1]))).ravel()


class VertexHistory:
    """Births and removals of the vertices of an adaptive mesh (module docstring).

    Parameters
    ----------
    n_vertices : int
        Vertices of the initial mesh (born at -1: never removable).
    """

    def __init__(self, n_vertices: int):
        self.birth = np.full(int(n_vertices), -1, dtype=np.int64)
        self._removed_keys = np.zeros(0, dtype=np.dtype((np.void, 1)))
        self._removed_counts = np.zeros(0, dtype=np.int64)
        self.cycles = 0  # adaptations so far (cycle calls)

    # -- bookkeeping ----------------------------------------------------------------------------
    def observe(self, change) -> None:
        """Account for one :class:`~rothe.fem.adapt.bisection.MeshChange` made in adaptation
        number ``self.cycles``.

        Vertex numbering (:mod:`.bisection`): the survivors keep their relative order and come
        first, the vertices created by this change are appended."""
        old, new = change.old_points, change.new_points
        n_surv = len(old) - int(change.removed_vertices)
        k_old, k_surv = _keys(old), _keys(new[:n_surv])
        survived = np.isin(k_old, k_surv)
        if int(np.count_nonzero(~survived)) != int(change.removed_vertices):
            raise RuntimeError("vertex history: the removed vertices do not match the change")
        gone = k_old[~survived]
        if gone.size:
            self._count_removals(gone)
        self.birth = np.concatenate(
            [self.birth[survived], np.full(len(new) - n_surv, self.cycles, dtype=np.int64)]
        )

    def _count_removals(self, keys: np.ndarray) -> None:
        if self._removed_keys.size == 0:
            self._removed_keys = keys[:0].copy()
        allk = np.concatenate([self._removed_keys, keys])
        allc = np.concatenate([self._removed_counts, np.ones(len(keys), dtype=np.int64)])
        uniq, inv = np.unique(allk, return_inverse=True)
        self._removed_keys = uniq
        self._removed_counts = np.bincount(inv.ravel(), weights=allc, minlength=len(uniq)).astype(
            np.int64
        )

    def removals(self, points: np.ndarray) -> np.ndarray:
        """How often each of ``points`` (n, d) has been removed so far (0 if never)."""
        out = np.zeros(len(points), dtype=np.int64)
        if self._removed_keys.size == 0:
            return out
        keys = _keys(points)
        if keys.dtype != self._removed_keys.dtype:
            return out
        pos = np.searchsorted(self._removed_keys, keys)
        pos = np.minimum(pos, len(self._removed_keys) - 1)
        hit = self._removed_keys[pos] == keys
        out[hit] = self._removed_counts[pos[hit]]
        return out

    def max_removals(self) -> int:
        """The largest number of times any vertex has been removed (0 if none ever was)."""
        return int(self._removed_counts.max()) if self._removed_counts.size else 0

    # -- the rules ------------------------------------------------------------------------------
    def frozen_cells(
        self, points: np.ndarray, cells: np.ndarray, coarsen_delay: int, max_recoarsen: int | None
    ) -> np.ndarray:
        """Mask of the cells that must not be marked for coarsening in adaptation
        ``self.cycles`` (module docstring)."""
        frozen_vertex = np.zeros(len(points), dtype=bool)
        if coarsen_delay > 0:
            frozen_vertex |= self.birth > self.cycles - 1 - coarsen_delay
            frozen_vertex &= self.birth >= 0
        if max_recoarsen is not None:
            frozen_vertex |= (self.birth >= 0) & (self.removals(points) >= max_recoarsen)
        return np.any(frozen_vertex[cells], axis=1)

    # -- checkpoint protocol --------------------------------------------------------------------
    def checkpoint_state(self) -> dict:
        """Birth cycles, removal keys and counts and the cycle number, for a checkpoint."""
        width = self._removed_keys.dtype.itemsize
        raw = (
            np.frombuffer(self._removed_keys.tobytes(), dtype=np.uint8).reshape(-1, width)
            if self._removed_keys.size
            else np.zeros((0, 0), dtype=np.uint8)
        )
        return {
            "birth": self.birth.copy(),
            "removed_keys": raw,
            "removed_counts": self._removed_counts.copy(),
            "cycles": int(self.cycles),
        }

    @classmethod
    def restore_state(cls, data: dict) -> VertexHistory:
        """The history rebuilt from :meth:`checkpoint_state`'s data."""
        out = cls(0)
        out.birth = np.asarray(data["birth"], dtype=np.int64).copy()
        raw = np.ascontiguousarray(data["removed_keys"], dtype=np.uint8)
        if raw.size:
            out._removed_keys = raw.view(np.dtype((np.void, raw.shape[1]))).ravel().copy()
        out._removed_counts = np.asarray(data["removed_counts"], dtype=np.int64).copy()
        out.cycles = int(data["cycles"])
        return out
