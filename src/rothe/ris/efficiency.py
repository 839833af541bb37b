"""Efficiency of the RIS residual indicator on a manufactured stationary problem (a step (3.1)).

The step (3.1) of Example 7.2's energy (g = 48(1-z^2)^2, c = 1, kappa_R = 1) from z_{k-1} = 0
with a fixed multiplier lambda_k = 250 (> -min g'' = 192, so the step problem is strongly
monotone and has one solution): with z* > 0 inside,
    -Laplace z + g'(z) + lambda z + kappa_R = l,   z = 0 on the boundary
(the subgradient is kappa_R sign(z - 0) = kappa_R), l computed from z*; P1 with the lumped F and
R of :class:`~rothe.ris.fem_problem.FERISProblem`, solved by Newton;
|||e|||^2 = ||grad e||^2 + lambda ||e||^2; indicator :func:`rothe.ris.indicator.ris_indicators`
with ``reaction`` = lambda. The solution is z* = 16^(d/2) prod x_i(1-x_i) (1.5 + phi) for the
``front`` profile (> 0 inside) and z* = prod sin(pi x_i) for the ``bump``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..fem.adapt.efficiency import (
    ScalarField,
    bump,
    cube_bubble,
    energy_error,
    front,
    refinement_study,
)
from ..fem.scalar import boundary_nodes, lumped_mass, stiffness
from ..fem.simplex import SimplexEvaluator
from ..fem.topology import lagrange_values
from .examples import d2g_7_2, dg_7_2
from .indicator import ris_indicators


def _ris_exact(dim: int, profile, width: float = 0.05) -> ScalarField:
    if isinstance(profile, ScalarField):
        return profile
    if profile == "bump":
        return bump(dim)
    if profile == "front":
        return cube_bubble(dim) * front(dim, width=width).shifted(1.5)
    raise ValueError(f"profile: got {profile!r}, must be bump, front or a ScalarField")


def _ris_solve(mesh, zs: ScalarField, lam: float, kappa: float):

    def load(x):
        H = zs.hess(x)
        z = zs.value(x)
        return -np.trace(H, axis1=0, axis2=1) + dg_7_2(z) + lam * z + kappa

    n = mesh.p.shape[1]
    fixed = boundary_nodes(mesh)
    free = np.setdiff1d(np.arange(n), fixed)
    K = stiffness(mesh)
    A = sp.csr_matrix(K[free][:, free])
    m = lumped_mass(mesh)[free]
    ev = SimplexEvaluator(mesh, 1, cell_order=6)

    phi = lagrange_values(ev.cell_lam, 1)  # (d+1, nq)
    lq = load(ev.cell_points)  # (nc, nq)
    local = np.einsum("cq,kq,cq->kc", lq, phi, ev.cell_dx)
    lfull = np.bincount(ev.t.ravel(), weights=local.ravel(), minlength=n)
    l_free = lfull[free]
    z = np.maximum(zs.value(mesh.p[:, free]), 0.0)
    for _ in range(60):
        r = A @ z + m * (dg_7_2(z) + lam * z + kappa) - l_free
        J = A + sp.diags(m * (d2g_7_2(z) + lam))
        dz = spla.splu(sp.csc_matrix(J), permc_spec="MMD_AT_PLUS_A").solve(-r)
        z = z + dz
        if np.max(np.abs(dz)) <= 1e-12 * max(1.0, np.max(np.abs(z))):
            break
    full = np.zeros(n)
    full[free] = z
    return full, load, bool(np.all(z > 0))


def ris_study(
    dim: int = 2,
    profile="front",
    *,
    n0: int = 4,
    adaptive: bool = True,
    max_dofs: int = 5000,
    theta: float = 0.5,
    lam: float = 250.0,
    kappa: float = 1.0,
    width: float = 0.05,
    max_levels: int = 40,
) -> list[dict]:
    """Rows (dofs, cells, estimate, error, efficiency, positive) of the RIS step study.

    ``positive``: all free nodal values of z_h > 0, i.e. the subgradient kappa sign(z_h - 0)
    of the discrete step is the kappa assumed by the manufactured load.
    """

    zs = _ris_exact(dim, profile, width)

    def level(mesh):
        z, load, positive = _ris_solve(mesh, zs, lam, kappa)
        ind = ris_indicators(
            mesh, z, np.zeros_like(z), dg=dg_7_2, load=load, kappa=kappa, lam=lam, reaction=lam
        )

        def energy(e, ge):
            return np.sum(ge * ge, axis=0) + lam * e * e

        err = energy_error(mesh, 1, z, zs.value, zs.grad, energy)
        row = {
            "dofs": int(np.count_nonzero(z)),
            "cells": mesh.t.shape[1],
            "estimate": ind.estimate,
            "error": err,
            "efficiency": ind.estimate / err,
            "positive": positive,
        }
        return row, ind.eta

    return refinement_study(
        dim,
        n0,
        False,
        level,
        adaptive=adaptive,
        max_dofs=max_dofs,
        theta=theta,
        max_levels=max_levels,
    )
