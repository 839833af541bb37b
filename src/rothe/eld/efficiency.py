"""Efficiency of the ELD residual indicator on a manufactured stationary problem (a Rothe step).

Find u with
    -div sigma(u) + kappa u = f in Omega,  u = u* on ``left``,  sigma(u) n = sigma(u*) n on the
other sides, with u* = a phi(x) (a a fixed vector, phi a scalar profile of
:mod:`rothe.fem.adapt.efficiency`), vector P1/P2 on triangles or tetrahedra;
|||e|||^2 = int sigma(e) : eps(e) + kappa ||e||^2; indicator
:func:`rothe.eld.indicator.eld_indicators` with ``reaction`` = kappa. Rows: dofs, eta, the exact
error and the efficiency eta / |||e||| on uniformly or adaptively refined meshes.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..fem.adapt.efficiency import energy_error, profile_field, refinement_study
from ..fem.elasticity import VectorSpace
from .indicator import eld_indicators, stress


def _elasticity_solve(mesh, degree, lam, mu, kappa, a, phi):

    space = VectorSpace(mesh, degree)
    d = space.dim
    av = np.asarray(a, dtype=float).reshape((d,) + (1, 1))

    def u_exact(x):
        return av.reshape((d,) + (1,) * (x.ndim - 1)) * phi.value(x)[None]

    def grad_exact(x):
        ar = av.reshape((d, 1) + (1,) * (x.ndim - 1))
        return ar * phi.grad(x)[None]

    def body(x):
        ar = av.reshape((d,) + (1,) * (x.ndim - 1))
        H = phi.hess(x)
        lap = np.trace(H, axis1=0, axis2=1)
        Ha = np.einsum("ij...,j->i...", H, np.asarray(a, dtype=float))
        div_sigma = mu * ar * lap[None] + (lam + mu) * Ha
        return -div_sigma + kappa * u_exact(x)

    K = space.stiffness(lam, mu)
    M = space.mass()
    A = (K + kappa * M).tocsr()
    F = space.load_from_quad(body(space.quad_points))
    neumann = [p for p in space.part_names() if p != "left"]
    for part in neumann:
        q = space.facet_quadrature((part,), intorder=2 * degree + 2)
        g = np.einsum("ijfq,jfq->ifq", stress(grad_exact(q.x), lam, mu), q.normals)
        F += q.integrate_against_basis(g, space.n_scalar).ravel()
    fixed = space.vector_dofs(space.scalar_dofs_on(("left",)))
    u = np.zeros(space.ndofs)
    u[fixed] = space.interpolate(u_exact)[fixed]
    free = np.setdiff1d(np.arange(space.ndofs), fixed)
    rhs = F[free] - A[free][:, fixed] @ u[fixed]
    lu = spla.splu(sp.csc_matrix(A[free][:, free]), permc_spec="MMD_AT_PLUS_A")
    u[free] = lu.solve(rhs)
    return space, u, u_exact, grad_exact, body, neumann


def elasticity_study(
    dim: int = 2,
    degree: int = 1,
    profile="bump",
    *,
    n0: int = 2,
    adaptive: bool = True,
    max_dofs: int = 5000,
    theta: float = 0.5,
    lam: float = 2.0,
    mu: float = 1.0,
    kappa: float = 1.0,
    width: float = 0.05,
    max_levels: int = 40,
) -> list[dict]:
    """Rows (dofs, cells, estimate, error, efficiency) of the ELD step study (module doc).

    ``profile``: "bump", "front" (of ``width``) or a :class:`ScalarField`; adaptive: Doerfler
    marking with ``theta`` and one bisection per marked cell; uniform: d bisections of every
    cell per level (every edge halved). Stops after the first mesh with >= ``max_dofs``.
    """

    phi = profile_field(dim, profile, width)
    a = np.array([1.0, 0.5, 0.25][:dim])

    def level(mesh):
        space, u, u_exact, grad_exact, body, neumann = _elasticity_solve(
            mesh, degree, lam, mu, kappa, a, phi
        )

        def traction(x, n, grad_exact=grad_exact):
            return np.einsum("ijfq,jfq->ifq", stress(grad_exact(x), lam, mu), n)

        ind = eld_indicators(
            mesh,
            degree,
            lam,
            mu,
            u,
            rho=kappa,
            accel=u,
            body_force=body,
            traction={p: traction for p in neumann},
            dirichlet_parts=("left",),
            reaction=kappa,
        )

        def energy(e, ge):
            S = stress(ge, lam, mu)
            eps = 0.5 * (ge + np.swapaxes(ge, 0, 1))
            return np.sum(S * eps, axis=(0, 1)) + kappa * np.sum(e * e, axis=0)

        U = u.reshape(-1, dim)
        err = energy_error(mesh, degree, U, u_exact, grad_exact, energy)
        row = {
            "dofs": space.ndofs,
            "cells": mesh.t.shape[1],
            "estimate": ind.estimate,
            "error": err,
            "efficiency": ind.estimate / err,
        }
        return row, ind.eta

    return refinement_study(
        dim,
        n0,
        True,
        level,
        adaptive=adaptive,
        max_dofs=max_dofs,
        theta=theta,
        max_levels=max_levels,
    )
