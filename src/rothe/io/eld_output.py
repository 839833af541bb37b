"""ParaView output of elastodynamics runs: XDMF time series (HDF5 heavy data).

Two series per run: the body (``<name>.xdmf``, point data ``u`` and ``v`` at the mesh vertices)
and the Dirichlet boundary (``<name>_multiplier.xdmf``, the facets of Gamma_D with point data
``lambda``, the multiplier as a traction density, and ``reaction_density = -lambda``). Steps are
streamed to HDF5 segments in a work directory as they are computed (nothing is kept in memory)
by :class:`rothe.io.xdmf.StreamedSeries`, which is checkpointable (a resumed run continues the
series exactly where its checkpoint was taken); ``export(directory)`` writes both series, complete
and atomically, wherever the results go.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .xdmf import StreamedSeries

_CELL = {2: "triangle", 3: "tetra"}
_FACET = {2: "line", 3: "triangle"}


class EldXdmfWriter:
    """Streams u, v (vertices) and lambda (Dirichlet facets) of selected steps to XDMF."""

    def __init__(self, work_dir, problem, name: str = "eld"):
        self.problem = problem
        space = problem.space
        mesh = space.mesh
        d = space.dim
        self.paths = (Path(f"{name}.xdmf"), Path(f"{name}_multiplier.xdmf"))
        points = np.ascontiguousarray(mesh.p.T)
        if d == 2:  # ParaView wants 3D points and vectors
            points = np.column_stack([points, np.zeros(len(points))])
        self._body = StreamedSeries(work_dir, name, points, np.ascontiguousarray(mesh.t.T))
        # the boundary mesh: vertices of the Dirichlet facets, renumbered
        c = problem.constraint
        facets = space.facets(c.parts, "dirichlet")
        fverts = mesh.facets[:, facets]
        verts = np.unique(fverts)
        local = np.searchsorted(verts, fverts)
        # positions of these vertices among the constrained scalar dofs (vertex dofs = vertex ids)
        self._lam_rows = np.searchsorted(c.scalar_dofs, verts)
        self._bnd = StreamedSeries(work_dir, f"{name}_multiplier", points[verts],
                                   np.ascontiguousarray(local.T))
        self.steps_written = 0

    def _vec3(self, values: np.ndarray) -> np.ndarray:
        if values.shape[1] == 3:
            return np.ascontiguousarray(values)
        return np.column_stack([values, np.zeros(len(values))])

    def write(self, t: float, u: np.ndarray, v: np.ndarray, lam: np.ndarray | None) -> None:
        space = self.problem.space
        self._body.write_step(float(t), {"u": self._vec3(space.vertex_values(u)),
                                         "v": self._vec3(space.vertex_values(v))})
        if lam is not None:
            L = np.asarray(lam).reshape(-1, space.dim)[self._lam_rows]
            self._bnd.write_step(float(t), {"lambda": self._vec3(L),
                                            "reaction_density": self._vec3(-L)})
        self.steps_written += 1

    # -- checkpoint protocol (attachment of the run's checkpoint) ---------------------------------
    def checkpoint_state(self) -> dict:
        return {"body": self._body.checkpoint_state(), "boundary": self._bnd.checkpoint_state(),
                "steps_written": self.steps_written}

    def restore_state(self, data: dict) -> None:
        self._body.restore_state(data["body"])
        self._bnd.restore_state(data["boundary"])
        self.steps_written = int(data["steps_written"])

    def export(self, directory) -> tuple[Path, Path]:
        """Both series, complete, into ``directory`` (XDMF + HDF5 each, atomically)."""
        return self._body.export(directory), self._bnd.export(directory)

    def discard(self) -> None:
        """Remove the streamed segments (after the results were committed)."""
        self._body.discard()
        self._bnd.discard()

    def close(self) -> None:
        self._body.checkpoint_state()
        self._bnd.checkpoint_state()
