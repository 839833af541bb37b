"""Outputs of elastodynamics runs: ParaView (XDMF + HDF5), ``trajectory.npz`` with the mesh, and
figures; :func:`write_eld_result` writes all of them for a result of :func:`rothe.eld.run_eld`
(an :class:`~rothe.eld.run.ELDResult`).

ParaView files (two XDMF time series with HDF5 heavy data, :mod:`rothe.io.xdmf`; meshio's
``TimeSeriesReader`` reads them):

- ``<name>.xdmf``: the body. Point data at the mesh vertices: ``u``, ``v`` (3 components; zero
  z in 2D), ``stress_nodal`` (the Cauchy stress, 9 components, averaged to the vertices by
  volume weights) and ``von_mises_nodal``; cell data ``stress`` (9 components, the cell-mean
  Cauchy stress sigma(u) = lam tr(eps) I + 2 mu eps; in 2D plane strain with sigma_zz =
  lam tr(eps)) and ``von_mises``. See :mod:`rothe.eld.stress`.
- ``<name>_multiplier.xdmf``: the facets of Gamma_D with point data ``lambda`` (the multiplier,
  a traction density) and ``reaction_density = -lambda`` (the traction the support exerts), at
  the same times as the body (the frame at t = 0 holds the consistent lambda(0)).

``trajectory.npz`` (:func:`mesh_arrays` are added to the trajectory's series):

- ``nodes`` (n_vertices, d) and ``cells`` (n_cells, d + 1): the mesh;
- ``doflocs`` (n_scalar, d): the points of the scalar dofs (the vertices first, then for P2 the
  edge midpoints); ``u``, ``v``, ``a`` (n_kept, d n_scalar) are interleaved dof vectors:
  ``u[k].reshape(-1, d)[i]`` is the displacement at ``doflocs[i]`` at time ``kept_t[k]``;
- ``lam_dofs`` (m,): the interleaved vector dofs of Gamma_D; ``lam[k]`` (m,) holds the multiplier
  there, ``lam[k].reshape(-1, d)[i]`` at the point ``doflocs[lam_dofs[d i] // d]``;
- the time series of the run (``t``, energies, ``tau``, ``reaction_<part>``, ...; see
  :func:`rothe.eld.run_eld`), ``stats_*`` and ``meta`` (JSON).

Steps are streamed to HDF5 segments in a work directory as they are computed by
:class:`EldXdmfWriter` (nothing is kept in memory) through :class:`rothe.io.xdmf.StreamedSeries`,
which is checkpointable (a resumed run continues the series exactly where its checkpoint was
taken); ``export(directory)`` writes both series, complete and atomically, wherever the results
go. :func:`write_eld_result` writes the states a run kept (``keep_every``).
"""

from __future__ import annotations

import os
import secrets
import shutil
from pathlib import Path

import numpy as np

from ..errors import described, fail
from ..io.atomic import TMP_PREFIX
from ..io.mesh_series import write_vtu_series
from ..io.xdmf import StreamedSeries
from .stress import StressEvaluator, von_mises


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
    """Streams u, v, stresses (vertices and cells) and lambda (Dirichlet facets) of selected
    steps into HDF5 segments in ``work_dir``; :meth:`export` writes the two XDMF series.

    ``paths`` are the series' file names (relative: they appear where :meth:`export` puts
    them). Checkpointable (``checkpoint_state`` / ``restore_state``: an attachment of the run's
    checkpoint)."""

    def __init__(self, work_dir, problem, name: str = "eld"):
        self.problem = problem
        space = problem.space
        mesh = space.mesh
        d = space.dim
        self.paths = (Path(f"{name}.xdmf"), Path(f"{name}_multiplier.xdmf"))
        self.stresses = StressEvaluator(space, problem.material)
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
        self._bnd = StreamedSeries(
            work_dir, f"{name}_multiplier", points[verts], np.ascontiguousarray(local.T)
        )
        self.steps_written = 0

    def _vec3(self, values: np.ndarray) -> np.ndarray:
        if values.shape[1] == 3:
            return np.ascontiguousarray(values)
        return np.column_stack([values, np.zeros(len(values))])

    def write(self, t: float, u: np.ndarray, v: np.ndarray, lam: np.ndarray) -> None:
        """Stream the state at t: u, v, the stresses into the body's series and lambda into the
        multiplier's (both series on one time axis: every frame has both; the frame at t = 0
        takes the consistent lambda(0), which the run computes with its initial state, see
        :mod:`rothe.eld.start`)."""
        space = self.problem.space
        if lam is None:  # a frame without a multiplier would break the common time axis
            raise fail("lam", None, f"must be the multiplier at t = {float(t):g}")
        L = np.asarray(lam).reshape(-1, space.dim)[self._lam_rows]
        sigma = self.stresses.stress(u)
        vm = von_mises(sigma)
        sigma_nodal = self.stresses.nodal(sigma)
        vm_nodal = self.stresses.nodal(vm)
        self._body.write_step(
            float(t),
            {
                "u": self._vec3(space.vertex_values(u)),
                "v": self._vec3(space.vertex_values(v)),
                "stress_nodal": sigma_nodal.reshape(-1, 9),
                "von_mises_nodal": vm_nodal,
            },
            cell_fields={"stress": sigma.reshape(-1, 9), "von_mises": vm},
        )
        self._bnd.write_step(
            float(t), {"lambda": self._vec3(L), "reaction_density": self._vec3(-L)}
        )
        self.steps_written += 1

    # -- checkpoint protocol (attachment of the run's checkpoint) ---------------------------------
    def checkpoint_state(self) -> dict:
        """Both series' segments so far and the number of steps written."""
        return {
            "body": self._body.checkpoint_state(),
            "boundary": self._bnd.checkpoint_state(),
            "steps_written": self.steps_written,
        }

    def restore_state(self, data: dict) -> None:
        """Continue the series of a checkpoint (the segments it names)."""
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
        """Write the segments held in memory to the work directory."""
        self._body.checkpoint_state()
        self._bnd.checkpoint_state()


def write_eld_result(
    result,
    out_dir,
    *,
    name: str = "eld",
    xdmf: bool = True,
    figures: bool = True,
    npz: bool = True,
    title: str = "",
) -> dict:
    """Write the outputs of a :func:`rothe.eld.run_eld` result into ``out_dir``.

    - ``trajectory.npz``: the trajectory with the mesh and dof layout (:func:`mesh_arrays`,
      module docstring);
    - ``<name>.xdmf/.h5`` and ``<name>_multiplier.xdmf/.h5``: u, v, stresses and lambda of every
      kept state (the run needs ``store_fields=True``; ``keep_every`` thins them);
    - ``fig_energy.png`` (the energy identity term by term) and ``fig_reaction.png``.

    A space-adaptive run (``result.meshes``: ``run_eld(..., adapt=...)``, :mod:`rothe.eld.adapt`)
    gets instead:

    - ``trajectory.npz``: the series of the run (with ``mesh_id``, ``ndofs``, ``cells`` per
      state and ``kept_mesh_id`` per kept state), every distinct mesh once
      (``mesh_ids``, ``mesh_points_<id>``, ``mesh_cells_<id>``, ``state_mesh_id`` = the kept
      states' mesh ids; :class:`rothe.io.mesh_series.MeshSeries`) and the kept fields
      ``kept_u``, ``kept_v``, ``kept_a``, ``kept_lam`` concatenated with ``kept_<f>_offsets``
      (state k: ``kept_u[off[k]:off[k + 1]]``, interleaved P``degree`` dofs of its mesh in
      scikit-fem's numbering, vertices first);
    - ``<name>.pvd`` with ``<name>_000000.vtu`` ...: one VTU per kept state on its own mesh
      (point data ``u``, ``v``, ``stress_nodal``, ``von_mises_nodal``, and ``lambda``,
      ``reaction_density`` on the vertices of Gamma_D, zero elsewhere; cell data ``stress``,
      ``von_mises``: the fields of the fixed-mesh XDMF, :func:`adaptive_frame`), the ``.pvd``
      index with the times: ParaView plays the states with their meshes (File > Open the
      .pvd);
    - ``fig_energy.png``, ``fig_reaction.png``, ``fig_dofs.png`` (dofs against t) and, in 2D,
      ``fig_mesh.png`` (four kept states: mesh and |u|).

    There ``xdmf`` switches the ``.pvd``/VTU series.

    Parameters
    ----------
    result : ELDResult
        What :func:`rothe.eld.run_eld` returned (or :meth:`rothe.eld.run.ELDRun.result` of a run
        that stopped).
    out_dir : path
    name : str
        The base name of the ParaView files.
    xdmf, figures, npz : bool
        Which outputs to write (``xdmf``: the ParaView files, XDMF or ``.pvd``/VTU).
    title : str
        The figures' title.

    Returns
    -------
    dict
        The written paths by kind. Example::

            result = run_eld(problem, scheme=BDF2(), control=Uniform(0.01), keep_every=5)
            write_eld_result(result, "my-run")
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if result.meshes is not None:
        return _write_adaptive(result, out, name, xdmf, figures, npz, title)
    traj, problem = result.trajectory, result.problem
    paths: dict = {}
    if npz:
        paths["npz"] = traj.save_npz(out / "trajectory.npz", extra=mesh_arrays(problem))
    if xdmf:
        if "kept_t" not in traj:
            raise fail(
                "result",
                described("a run without stored fields"),
                "must come from run_eld(..., store_fields=True) to write XDMF",
            )
        # segments in a hidden work directory beside the results, then both series atomically
        work = out / f"{TMP_PREFIX}{os.getpid()}-{secrets.token_hex(4)}-{name}.parts"
        try:
            writer = EldXdmfWriter(work, problem, name=name)
            for t, u, v, lam in zip(traj["kept_t"], traj["u"], traj["v"], traj["lam"], strict=True):
                writer.write(t, u, v, lam)
            paths["xdmf"] = list(writer.export(out))
        finally:
            shutil.rmtree(work, ignore_errors=True)
    if figures:
        # matplotlib is imported only for the figures
        from .figures import plot_energy_balance, plot_reactions

        paths["figures"] = [
            plot_energy_balance(traj, out / "fig_energy.png", title=title),
            plot_reactions(traj, out / "fig_reaction.png", title=title),
        ]
    return paths


def nodal_average(points: np.ndarray, cells: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Volume-weighted vertex averages sum_T |T| v_T / sum_T |T| of per-cell ``values``
    (n_cells, ...) on the simplex mesh (``points`` (nv, d), ``cells`` (n_cells, d + 1)), as
    :meth:`rothe.eld.stress.StressEvaluator.nodal`; |T| = |det(x_1 - x_0, ...)| / d!."""
    points, cells = np.asarray(points, dtype=float), np.asarray(cells)
    d = points.shape[1]
    edges = points[cells[:, 1:]] - points[cells[:, :1]]  # (ne, d, d)
    vol = np.abs(np.linalg.det(edges)) / float(np.prod(np.arange(1, d + 1)))
    vals = np.asarray(values, dtype=float)
    flat = vals.reshape(len(cells), -1)
    nv = len(points)
    num = np.zeros((nv, flat.shape[1]))
    den = np.zeros(nv)
    for row in cells.T:
        den += np.bincount(row, weights=vol, minlength=nv)
        for c in range(flat.shape[1]):
            num[:, c] += np.bincount(row, weights=vol * flat[:, c], minlength=nv)
    return (num / np.maximum(den, 1e-300)[:, None]).reshape((nv,) + vals.shape[1:])


def adaptive_frame(meshes, k: int, mesh_id: int) -> tuple[dict, dict]:
    """Point and cell data of kept state ``k`` of a space-adaptive run on its mesh ``mesh_id``
    (:class:`rothe.eld.adapt.ELDMeshes`), the fields of the fixed-mesh XDMF: cell data
    ``stress`` (the cell-mean Cauchy stress, 9 components) and ``von_mises``
    ((3/2 s:s)^(1/2), s the deviator); point data ``stress_nodal`` and ``von_mises_nodal``
    (:func:`nodal_average`), and on the vertices of Gamma_D ``lambda`` (the multiplier, a
    traction density) and ``reaction_density`` = -lambda (zero at the other vertices). A state
    kept without stresses (an older checkpoint) gets no stress fields."""
    points, cells = meshes.series.mesh(mesh_id)
    nv, d = len(points), meshes.components
    point: dict = {}
    cell: dict = {}
    if k < len(meshes.kept["stress"]):
        sigma = np.asarray(meshes.kept["stress"][k]).reshape(-1, 3, 3)
        vm = von_mises(sigma)
        cell = {"stress": sigma.reshape(-1, 9), "von_mises": vm}
        point = {
            "stress_nodal": nodal_average(points, cells, sigma.reshape(-1, 9)),
            "von_mises_nodal": nodal_average(points, cells, vm),
        }
    gamma = meshes.gamma_dofs.get(mesh_id)
    if gamma is not None:
        lam = np.asarray(meshes.kept["lam"][k]).reshape(-1, d)
        on_vertex = gamma < nv  # scikit-fem numbers the vertex dofs first
        field = np.zeros((nv, d))
        field[gamma[on_vertex]] = lam[on_vertex]
        point["lambda"] = field
        point["reaction_density"] = -field
    return point, cell


def _vertex_values(meshes, w, mesh_id) -> np.ndarray:
    """The vertex values (nv, d) of the interleaved dof vector ``w`` on mesh ``mesh_id``
    (scikit-fem numbers the vertex dofs first)."""
    nv = len(meshes.series.mesh(mesh_id)[0])
    return np.asarray(w).reshape(-1, meshes.components)[:nv]


def write_adaptive_series(out_dir, name: str, meshes, traj, states=None) -> Path:
    """``<name>.pvd`` and one VTU per kept state of a space-adaptive run on its own mesh
    (:class:`rothe.eld.adapt.ELDMeshes` ``meshes``; ``traj`` with ``kept_t``,
    ``kept_mesh_id``): point data ``u``, ``v`` and the fields of :func:`adaptive_frame`.
    run_eld's series and that of the adaptive body of glued bodies
    (:func:`rothe.eld.bodies_output.write_bodies_result`); ``states``: the indices of the kept
    states to write (default all). Returns the ``.pvd``."""
    ids = np.asarray(traj["kept_mesh_id"], dtype=np.int64)
    states = np.arange(ids.size) if states is None else np.asarray(states, dtype=np.int64)
    data, cells = [], []
    for k in states:
        u, v, m = meshes.kept["u"][k], meshes.kept["v"][k], ids[k]
        point, cell = adaptive_frame(meshes, int(k), int(m))
        data.append({"u": _vertex_values(meshes, u, m), "v": _vertex_values(meshes, v, m), **point})
        cells.append(cell)
    times = np.asarray(traj["kept_t"])[states]
    return write_vtu_series(out_dir, name, meshes.series, ids[states], times, data, cell_data=cells)


def _write_adaptive(result, out_dir, name, paraview, figures, npz, title) -> dict:
    """The outputs of a space-adaptive run (:func:`write_eld_result` lists them)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    traj, sp = result.trajectory, result.meshes
    paths: dict = {}
    if npz:
        paths["npz"] = traj.save_npz(out / "trajectory.npz", extra=sp.npz_arrays(traj))
    kept = "kept_t" in traj and len(sp.kept["u"]) > 0
    ids = np.asarray(traj["kept_mesh_id"], dtype=np.int64) if kept else np.zeros(0, np.int64)
    d = sp.components
    if paraview and kept:
        paths["pvd"] = write_adaptive_series(out, name, sp, traj)
    if figures:
        # matplotlib is imported only for the figures
        from ..plotting.adapt import plot_dofs, plot_mesh_snapshots
        from .figures import plot_energy_balance, plot_reactions

        figs = [
            plot_energy_balance(traj, out / "fig_energy.png", title=title),
            plot_reactions(traj, out / "fig_reaction.png", title=title),
        ]
        plot_dofs(out / "fig_dofs.png", traj["t"], traj["ndofs"], title=title)
        figs.append(out / "fig_dofs.png")
        if kept and d == 2:
            k = len(ids)
            picks = sorted({round(i * (k - 1) / 3) for i in range(4)})
            norms = [
                np.linalg.norm(_vertex_values(sp, u, m), axis=1)
                for u, m in zip(sp.kept["u"], ids, strict=True)
            ]
            plot_mesh_snapshots(
                out / "fig_mesh.png",
                sp.series,
                ids,
                traj["kept_t"],
                norms,
                picks,
                title=title,
                label=r"$|u|$ (displacement)",
            )
            figs.append(out / "fig_mesh.png")
        paths["figures"] = figs
    return paths
