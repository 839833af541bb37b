"""ParaView output of elastodynamics runs: XDMF time series (HDF5 heavy data) through meshio.

Two series per run: the body (``<name>.xdmf``, point data ``u`` and ``v`` at the mesh vertices)
and the Dirichlet boundary (``<name>_multiplier.xdmf``, the facets of Gamma_D with point data
``lambda``, the multiplier as a traction density, and ``reaction_density = -lambda``). Steps are
streamed to disk as they are computed; nothing is kept in memory.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

_CELL = {2: "triangle", 3: "tetra"}
_FACET = {2: "line", 3: "triangle"}


def _open(meshio, path: Path):
    """A meshio XDMF time-series writer whose HDF5 file sits next to ``path``."""
    writer = meshio.xdmf.TimeSeriesWriter(str(path))
    cwd = os.getcwd()
    try:
        os.chdir(path.parent)  # meshio opens Path(filename).stem + ".h5" relative to the cwd
        writer.__enter__()
    finally:
        os.chdir(cwd)
    return writer


class EldXdmfWriter:
    """Streams u, v (vertices) and lambda (Dirichlet facets) of selected steps to XDMF."""

    def __init__(self, out_dir, problem, name: str = "eld"):
        import meshio

        self.problem = problem
        space = problem.space
        mesh = space.mesh
        d = space.dim
        out_dir = Path(out_dir).resolve()
        self.paths = (out_dir / f"{name}.xdmf", out_dir / f"{name}_multiplier.xdmf")
        points = np.ascontiguousarray(mesh.p.T)
        if d == 2:  # ParaView wants 3D points and vectors
            points = np.column_stack([points, np.zeros(len(points))])
        self._body = _open(meshio, self.paths[0])
        self._body.write_points_cells(points, [(_CELL[d], np.ascontiguousarray(mesh.t.T))])
        # the boundary mesh: vertices of the Dirichlet facets, renumbered
        c = problem.constraint
        facets = space.facets(c.parts, "dirichlet")
        fverts = mesh.facets[:, facets]
        verts = np.unique(fverts)
        local = np.searchsorted(verts, fverts)
        # positions of these vertices among the constrained scalar dofs (vertex dofs = vertex ids)
        self._lam_rows = np.searchsorted(c.scalar_dofs, verts)
        self._bnd = _open(meshio, self.paths[1])
        self._bnd.write_points_cells(points[verts], [(_FACET[d], np.ascontiguousarray(local.T))])
        self.steps_written = 0

    def _vec3(self, values: np.ndarray) -> np.ndarray:
        if values.shape[1] == 3:
            return np.ascontiguousarray(values)
        return np.column_stack([values, np.zeros(len(values))])

    def write(self, t: float, u: np.ndarray, v: np.ndarray, lam: np.ndarray | None) -> None:
        space = self.problem.space
        self._body.write_data(float(t), point_data={"u": self._vec3(space.vertex_values(u)),
                                                    "v": self._vec3(space.vertex_values(v))})
        if lam is not None:
            L = np.asarray(lam).reshape(-1, space.dim)[self._lam_rows]
            self._bnd.write_data(float(t), point_data={"lambda": self._vec3(L),
                                                       "reaction_density": self._vec3(-L)})
        self.steps_written += 1

    def close(self) -> None:
        for w in (self._body, self._bnd):
            w.__exit__(None, None, None)
