"""Outputs of elastodynamics runs: ParaView (XDMF + HDF5), ``trajectory.npz`` with the mesh, and
figures; :func:`write_eld_result` writes all of them for a result of :func:`rothe.eld.run_eld`.

ParaView files (two XDMF time series, HDF5 heavy data, written through meshio):

- ``<name>.xdmf``: the body. Point data at the mesh vertices: ``u``, ``v`` (3 components; zero
  z in 2D), ``stress_nodal`` (the Cauchy stress, 9 components, averaged to the vertices by
  volume weights) and ``von_mises_nodal``; cell data ``stress`` (9 components, the cell-mean
  Cauchy stress sigma(u) = lam tr(eps) I + 2 mu eps; in 2D plane strain with sigma_zz =
  lam tr(eps)) and ``von_mises``. See :mod:`rothe.eld.stress`.
- ``<name>_multiplier.xdmf``: the facets of Gamma_D with point data ``lambda`` (the multiplier,
  a traction density) and ``reaction_density = -lambda`` (the traction the support exerts).

``trajectory.npz`` (:func:`mesh_arrays` are added to the trajectory's series):

- ``nodes`` (n_vertices, d) and ``cells`` (n_cells, d + 1): the mesh;
- ``doflocs`` (n_scalar, d): the points of the scalar dofs (the vertices first, then for P2 the
  edge midpoints); ``u``, ``v``, ``a`` (n_kept, d n_scalar) are interleaved dof vectors:
  ``u[k].reshape(-1, d)[i]`` is the displacement at ``doflocs[i]`` at time ``kept_t[k]``;
- ``lam_dofs`` (m,): the interleaved vector dofs of Gamma_D; ``lam[k]`` (m,) holds the multiplier
  there, ``lam[k].reshape(-1, d)[i]`` at the point ``doflocs[lam_dofs[d i] // d]``;
- the time series of the run (``t``, energies, ``tau``, ``reaction_<part>``, ...; see
  :func:`rothe.eld.run_eld`), ``stats_*`` and ``meta`` (JSON).

Steps are streamed to disk as they are computed by :class:`EldXdmfWriter` (nothing is kept in
memory); :func:`write_eld_result` writes the states a run kept (``keep_every``).
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


def mesh_arrays(problem) -> dict:
    """The mesh and the dof layout of a problem, as arrays for ``trajectory.npz``."""
    space = problem.space
    mesh = space.mesh
    return {
        "nodes": np.ascontiguousarray(mesh.p.T),
        "cells": np.ascontiguousarray(mesh.t.T),
        "doflocs": np.ascontiguousarray(space.doflocs.T),
        "lam_dofs": np.asarray(problem.constraint.dofs),
        "degree": np.asarray(space.degree),
        "dim": np.asarray(space.dim),
    }


class EldXdmfWriter:
    """Streams u, v, stresses (vertices and cells) and lambda (Dirichlet facets) to XDMF."""

    def __init__(self, out_dir, problem, name: str = "eld"):
        import meshio

        from ..eld.stress import StressEvaluator

        self.problem = problem
        space = problem.space
        mesh = space.mesh
        d = space.dim
        out_dir = Path(out_dir).resolve()
        out_dir.mkdir(parents=True, exist_ok=True)
        self.paths = (out_dir / f"{name}.xdmf", out_dir / f"{name}_multiplier.xdmf")
        self.stresses = StressEvaluator(space, problem.material)
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
        from ..eld.stress import von_mises

        sigma = self.stresses.stress(u)
        vm = von_mises(sigma)
        sigma_nodal = self.stresses.nodal(sigma)
        vm_nodal = self.stresses.nodal(vm)
        self._body.write_data(
            float(t),
            point_data={"u": self._vec3(space.vertex_values(u)),
                        "v": self._vec3(space.vertex_values(v)),
                        "stress_nodal": sigma_nodal.reshape(-1, 9),
                        "von_mises_nodal": vm_nodal},
            cell_data={"stress": [sigma.reshape(-1, 9)], "von_mises": [vm]})
        if lam is not None:
            L = np.asarray(lam).reshape(-1, space.dim)[self._lam_rows]
            self._bnd.write_data(float(t), point_data={"lambda": self._vec3(L),
                                                       "reaction_density": self._vec3(-L)})
        self.steps_written += 1

    def close(self) -> None:
        for w in (self._body, self._bnd):
            w.__exit__(None, None, None)


def write_eld_result(traj, problem, out_dir, *, name: str = "eld", xdmf: bool = True,
                     figures: bool = True, npz: bool = True, title: str = "") -> dict:
    """Write the outputs of a :func:`rothe.eld.run_eld` result into ``out_dir``.

    - ``trajectory.npz``: the trajectory with the mesh and dof layout (:func:`mesh_arrays`,
      module docstring);
    - ``<name>.xdmf/.h5`` and ``<name>_multiplier.xdmf/.h5``: u, v, stresses and lambda of every
      kept state (the run needs ``store_fields=True``; ``keep_every`` thins them);
    - ``fig_energy.png`` (the energy identity term by term) and ``fig_reaction.png``.

    Returns the written paths by kind. Example::

        traj = run_eld(problem, "regularized", 0.01, scheme="bdf2", keep_every=5)
        write_eld_result(traj, problem, "my-run")
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths: dict = {}
    if npz:
        paths["npz"] = traj.save_npz(out / "trajectory.npz", extra=mesh_arrays(problem))
    if xdmf:
        if "kept_t" not in traj:
            from ..errors import described, fail

            raise fail("traj", described("a run without stored fields"),
                       "must come from run_eld(..., store_fields=True) to write XDMF")
        writer = EldXdmfWriter(out, problem, name=name)
        try:
            for t, u, v, lam in zip(traj["kept_t"], traj["u"], traj["v"], traj["lam"],
                                    strict=True):
                writer.write(t, u, v, lam)
        finally:
            writer.close()
        paths["xdmf"] = list(writer.paths)
    if figures:
        from ..plotting.eld import plot_energy_balance, plot_reactions

        paths["figures"] = [plot_energy_balance(traj, out / "fig_energy.png", title=title),
                            plot_reactions(traj, out / "fig_reaction.png", title=title)]
    return paths
