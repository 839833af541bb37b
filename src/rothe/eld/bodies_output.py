"""Outputs of glued-body runs (:mod:`rothe.eld.bodies`): ``trajectory.npz`` with every body's
fields and the interface multipliers, one ParaView series per body.

``trajectory.npz`` (the run's series, :func:`rothe.eld.run_bodies` with ``fields=True``, and):

- per body ``<body>_nodes``, ``<body>_cells``, ``<body>_doflocs`` (its mesh and dof points)
  and ``<body>_u``, ``<body>_v`` (n_states, n_<body>): interleaved dof vectors at every state
  (the attached bodies' zero on their clamped parts);
- per interface k (base part P): ``interface_<P>_points`` (k1, d), the base's interface
  nodes, and ``interface_<P>_lambda`` (n_states, d k1): the multiplier there (a traction
  density; the force on the base is -B^T lambda, on the attached body +(Pi S)^T M_G lambda),
  ``reaction_<P>`` (n_states, d): the resultant on the base, -int lambda ds;
- ``lam`` (n_states, m): the base's multiplier on all its constrained dofs (clamped and
  glued parts), ``q``, ``p``: the attached bodies' coordinates (their free dofs).

ParaView: ``<body>.xdmf`` (u, v, stresses at the vertices and cells) and
``<body>_multiplier.xdmf`` for every body (:class:`~rothe.eld.output.EldXdmfWriter`): the
base's multiplier on its clamped and glued parts; an attached body's on its glued part is
its interface traction lambda_k = -M_{G,k}^{-1} f_k (f_k the multiplier's nodal force on it;
zero on its clamped parts, whose reactions a glued run does not compute).
"""

from __future__ import annotations

import os
import secrets
import shutil
from pathlib import Path

import numpy as np

from ..errors import described, fail
from ..io.atomic import TMP_PREFIX
from .output import EldXdmfWriter


def body_series(glued, traj) -> dict:
    """Every body's u, v over the states of ``traj`` and each interface's multiplier, by the
    names of the module docstring."""
    out = {}
    u, v = np.asarray(traj["u"]), np.asarray(traj["v"])
    q, p = np.asarray(traj["q"]), np.asarray(traj["p"])
    us, vs = glued.fields(u, q), glued.fields(v, p)
    for (name, space), uk, vk in zip(glued.bodies(), us, vs, strict=True):
        mesh = space.mesh
        out[f"{name}_nodes"] = np.ascontiguousarray(mesh.p.T)
        out[f"{name}_cells"] = np.ascontiguousarray(mesh.t.T)
        out[f"{name}_doflocs"] = np.ascontiguousarray(space.doflocs.T)
        out[f"{name}_u"], out[f"{name}_v"] = uk, vk
    lam = np.asarray(traj["lam"])
    for k, itf in enumerate(glued.interfaces):
        out[f"interface_{itf.part1}_points"] = np.ascontiguousarray(
            itf.space1.doflocs[:, itf.dofs1].T
        )
        out[f"interface_{itf.part1}_lambda"] = glued.multiplier(lam, k)
    return out


def attached_multiplier(glued, lam: np.ndarray, k: int) -> np.ndarray:
    """Body k's interface traction in its own trace space (module docstring), on its
    problem's constrained dofs."""
    _, f2 = glued.interface_forces(lam, k)
    c = glued.components[k].problem.constraint
    return -c.multiplier_from_residual(f2[c.dofs])


def write_bodies_result(result, glued, out_dir, *, paraview: bool = True, npz: bool = True):
    """Write ``trajectory.npz`` and the ParaView series of a :func:`rothe.eld.run_bodies`
    result (``fields=True``) into ``out_dir``; returns the written paths by kind."""
    if glued.chains:
        raise fail(
            "glued",
            described(
                f"a chain of bodies ({len(glued.chains)} interface(s) between attached bodies)"
            ),
            "is not written yet: the bodies' series are glued.fields(u, q) of the trajectory",
        )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    traj = result.trajectory
    paths: dict = {}
    if npz:
        paths["npz"] = traj.save_npz(out / "trajectory.npz", extra=body_series(glued, traj))
    if paraview:
        t, u, v, q, p = (np.asarray(traj[k]) for k in ("t", "u", "v", "q", "p"))
        lam = np.asarray(traj["lam"])
        us, vs = glued.fields(u, q), glued.fields(v, p)
        problems = glued.problems()
        paths["xdmf"] = []
        for i, problem in enumerate(problems):
            work = out / f"{TMP_PREFIX}{os.getpid()}-{secrets.token_hex(4)}-{problem.name}.parts"
            try:
                writer = EldXdmfWriter(work, problem, name=problem.name)
                for j in range(len(t)):
                    lam_j = lam[j] if i == 0 else attached_multiplier(glued, lam[j], i - 1)
                    writer.write(t[j], us[i][j], vs[i][j], lam_j)
                paths["xdmf"] += list(writer.export(out))
            finally:
                shutil.rmtree(work, ignore_errors=True)
    return paths
