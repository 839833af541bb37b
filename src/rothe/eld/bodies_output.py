"""Outputs of glued-body runs (:mod:`rothe.eld.bodies`): ``trajectory.npz`` with every body's
fields and the interface multipliers, one ParaView series per body -- on fixed meshes, with an
adaptive base (``run_bodies(..., adapt=...)``: its mesh changes between states) and for chains.

``trajectory.npz`` (the run's series, :func:`rothe.eld.run_bodies` with ``fields=True``, and):

- per attached body ``<body>_nodes``, ``<body>_cells``, ``<body>_doflocs`` (its mesh and dof
  points), ``<body>_u``, ``<body>_v`` (n_states, n_<body>): interleaved dof vectors at every
  state (zero on its clamped parts), and ``<body>_lambda`` (n_states, m_<body>): its traction
  on its constrained dofs ``<body>_lam_dofs`` -- the part glued to the body before it and
  its clamped parts -- from its residual (:meth:`GluedBodies.interface_tractions`:
  lambda_b = -M_{G,b}^{-1} (rho_b M_b a_b + C_b v_b + K_b u_b - F_b(t)) there; the only
  traction a chain interface has, since its glue is substituted and carries no multiplier);
- the base on a fixed mesh: ``<base>_nodes``, ``_cells``, ``_doflocs``, ``_u``, ``_v`` as
  above, and per interface k (base part P) ``interface_<P>_points`` (k1, d), the base's
  interface nodes, and ``interface_<P>_lambda`` (n_states, d k1): the multiplier there (a
  traction density; the force on the base is -B^T lambda, on the attached body
  +(Pi S)^T M_G lambda), ``reaction_<P>`` (n_states, d): the resultant on the base,
  -int lambda ds; ``lam`` (n_states, m): the base's multiplier on all its constrained dofs;
- the base adaptive: its states kept on their own meshes as run_eld keeps them (every mesh
  once: ``mesh_ids``, ``mesh_points_<k>``, ``mesh_cells_<k>``; ``kept_u``, ``kept_v``,
  ``kept_a``, ``kept_lam``, ``kept_stress`` with ``kept_<f>_offsets``, ``kept_mesh_id``:
  :meth:`rothe.eld.adapt.ELDMeshes.npz_arrays`), ``state_mesh_id`` the mesh of every
  recorded state (after the adapt step);
- ``q``, ``p``, ``pdot``: the attached bodies' coordinates and their derivatives.

ParaView, one series per body: the base on a fixed mesh ``<base>.xdmf`` (u, v, stresses at the
vertices and cells) and ``<base>_multiplier.xdmf`` (lambda on its clamped and glued parts,
:class:`~rothe.eld.output.EldXdmfWriter`); an adaptive base ``<base>.pvd`` with one VTU per
state on the mesh it was computed on (the same fields, lambda on the vertices of its
constrained parts: :func:`~rothe.eld.output.write_adaptive_series`); every attached body
(fixed mesh) ``<body>.xdmf`` and ``<body>_multiplier.xdmf`` with ``<body>_lambda`` above.
"""

from __future__ import annotations

import os
import secrets
import shutil
from pathlib import Path

import numpy as np

from ..io.atomic import TMP_PREFIX
from .output import EldXdmfWriter, write_adaptive_series


def _attached_series(glued, traj) -> list:
    """(problem, u, v, lambda) over the states of ``traj`` of every attached body."""
    t, q, p, pdot = (np.asarray(traj[k]) for k in ("t", "q", "p", "pdot"))
    # (glued.fields gives the base's u first: not recorded with an adaptive base, not needed)
    us, vs = glued.fields(np.zeros(0), q)[1:], glued.fields(np.zeros(0), p)[1:]
    lams = glued.interface_tractions(t, q, p, pdot)
    return list(zip(glued.problems()[1:], us, vs, lams, strict=True))


def body_series(glued, traj, meshes=None) -> dict:
    """Every body's fields over the states of ``traj`` and the interfaces' multipliers, by
    the names of the module docstring; ``meshes``: the adaptive base's series of meshes with
    its kept states (:class:`rothe.eld.adapt.ELDMeshes`), None on a fixed mesh."""
    out = {}
    for problem, u, v, lam in _attached_series(glued, traj):
        space, name = problem.space, problem.name
        out.update(_mesh_of(name, space))
        out[f"{name}_u"], out[f"{name}_v"] = u, v
        out[f"{name}_lambda"] = lam
        out[f"{name}_lam_dofs"] = np.asarray(problem.constraint.dofs)
    if meshes is not None:
        return {**out, **meshes.npz_arrays(traj)}
    base = glued.base
    out.update(_mesh_of(base.name, base.space))
    out[f"{base.name}_u"], out[f"{base.name}_v"] = np.asarray(traj["u"]), np.asarray(traj["v"])
    lam = np.asarray(traj["lam"])
    for k, itf in enumerate(glued.interfaces):
        out[f"interface_{itf.part1}_points"] = np.ascontiguousarray(
            itf.space1.doflocs[:, itf.dofs1].T
        )
        out[f"interface_{itf.part1}_lambda"] = glued.multiplier(lam, k)
    return out


def _mesh_of(name: str, space) -> dict:
    mesh = space.mesh
    return {
        f"{name}_nodes": np.ascontiguousarray(mesh.p.T),
        f"{name}_cells": np.ascontiguousarray(mesh.t.T),
        f"{name}_doflocs": np.ascontiguousarray(space.doflocs.T),
    }


def _xdmf(out: Path, problem, t, us, vs, lams, name: str | None = None) -> list:
    """The XDMF series of one body on its fixed mesh, ``<name>.xdmf`` and
    ``<name>_multiplier.xdmf`` (``name``: the problem's by default; segments in a hidden work
    directory beside the results, then both series atomically)."""
    name = problem.name if name is None else name
    work = out / f"{TMP_PREFIX}{os.getpid()}-{secrets.token_hex(4)}-{name}.parts"
    try:
        writer = EldXdmfWriter(work, problem, name=name)
        for j in range(len(t)):
            writer.write(t[j], us[j], vs[j], lams[j])
        return list(writer.export(out))
    finally:
        shutil.rmtree(work, ignore_errors=True)


def kept_states(n: int, every: int) -> np.ndarray:
    """The states 0, every, 2 every, ... and the last of ``n`` recorded states."""
    return np.union1d(np.arange(0, n, max(int(every), 1)), [n - 1])


def write_body_result(
    result,
    problem,
    out_dir,
    name: str,
    npz: str = "trajectory.npz",
    every: int = 1,
    extra: dict | None = None,
) -> dict:
    """Write ``npz`` and the ParaView series ``<name>`` of a one-body coupled run
    (:func:`rothe.eld.run_coupled` with ``fields=True``; ``problem`` its system's body, whose
    constraint covers the prescribed and the coupled parts): on a fixed mesh ``<name>.xdmf`` (u,
    v, stresses) and ``<name>_multiplier.xdmf`` (lambda on every constrained part), with
    ``adapt=`` ``<name>.pvd`` and one VTU per state on its own mesh -- the series of the base of
    glued bodies (:func:`write_bodies_result`). ``every``: the series, and on a fixed mesh the
    fields ``u``, ``v``, ``lam`` in ``npz``, keep every k-th state, the first and the last
    (:func:`kept_states`; their numbers in ``kept_states``); the other series of the run keep
    every state. ``extra``: more arrays for ``npz`` (a command's own, e.g. eld-tip-mass's modal
    coordinates). Returns the written paths by kind (``npz``, ``xdmf`` or ``pvd``)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    traj, meshes = result.trajectory, result.meshes
    t = np.asarray(traj["t"])
    if meshes is None:
        keep = kept_states(t.size, every)
        u, v, lam = (np.asarray(traj[k])[keep] for k in ("u", "v", "lam"))
        # (save_npz writes extra after the series: the kept rows replace the full ones)
        fields = {"u": u, "v": v, "lam": lam, "kept_states": keep}
        paths: dict = {"xdmf": _xdmf(out, problem, t[keep], u, v, lam, name=name)}
    else:
        keep = kept_states(len(meshes.kept["u"]), every)
        fields = {**meshes.npz_arrays(traj), **result.mesh_arrays(), "kept_states": keep}
        paths = {"pvd": write_adaptive_series(out, name, meshes, traj, states=keep)}
    paths["npz"] = traj.save_npz(out / npz, extra={**fields, **(extra or {})})
    return paths


def write_bodies_result(result, glued, out_dir, *, paraview: bool = True, npz: bool = True):
    """Write ``trajectory.npz`` and the ParaView series of a :func:`rothe.eld.run_bodies`
    result (``fields=True``) into ``out_dir`` (module docstring: fixed meshes, an adaptive
    base, chains); returns the written paths by kind (``npz``; ``xdmf``: every XDMF file,
    ``pvd``: the adaptive base's index)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    traj = result.trajectory
    meshes = result.meshes
    paths: dict = {}
    if npz:
        extra = body_series(glued, traj, meshes)
        if meshes is not None:  # the meshes of the recorded states (after the adapt step)
            extra.update(result.mesh_arrays())
        paths["npz"] = traj.save_npz(out / "trajectory.npz", extra=extra)
    if paraview:
        t = np.asarray(traj["t"])
        paths["xdmf"] = []
        if meshes is None:
            u, v, lam = (np.asarray(traj[k]) for k in ("u", "v", "lam"))
            paths["xdmf"] += _xdmf(out, glued.base, t, u, v, lam)
        else:
            paths["pvd"] = write_adaptive_series(out, glued.base.name, meshes, traj)
        for problem, u, v, lam in _attached_series(glued, traj):
            paths["xdmf"] += _xdmf(out, problem, t, u, v, lam)
    return paths
