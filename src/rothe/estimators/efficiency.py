"""Efficiency of the residual indicators on manufactured stationary problems.

Two stationary model problems with known exact solutions, each a Rothe step with a fixed
reaction coefficient, solved on sequences of uniformly and adaptively refined meshes; each row
reports the dofs, the estimate eta = (sum eta_K^2)^(1/2), the exact error in the energy norm
and the *efficiency* eta / |||e|||.

* **ELD step** (:func:`elasticity_study`): find u with
      -div sigma(u) + kappa u = f in Omega,  u = u* on ``left``,  sigma(u) n = sigma(u*) n on
  the other sides, with u* = a phi(x) (a a fixed vector, phi a scalar profile), vector P1/P2
  on triangles or tetrahedra; |||e|||^2 = int sigma(e) : eps(e) + kappa ||e||^2; indicator
  :func:`rothe.estimators.eld_indicator.eld_indicators` with ``reaction`` = kappa.
* **RIS step** (:func:`ris_study`): the step (3.1) of Example 7.2's energy (g = 48(1-z^2)^2,
  c = 1, kappa_R = 1) from z_{k-1} = 0 with a fixed multiplier lambda_k = 250 (> -min g'' = 192,
  so the step problem is strongly monotone and has one solution): with z* > 0 inside,
      -Laplace z + g'(z) + lambda z + kappa_R = l,   z = 0 on the boundary
  (the subgradient is kappa_R sign(z - 0) = kappa_R), l computed from z*; P1 with the lumped
  F and R of :class:`~rothe.problems.ris_fem.FERISProblem`, solved by Newton;
  |||e|||^2 = ||grad e||^2 + lambda ||e||^2; indicator
  :func:`rothe.estimators.ris_indicator.ris_indicators` with ``reaction`` = lambda.

Profiles phi: ``bump`` (prod sin(pi x_i), smooth) and ``front`` (tanh((|x - x_c| - r0)/w), a
steep circular front, w = 0.05 by default). The RIS solution is z* = 16^(d/2) prod x_i(1-x_i)
(1.5 + phi) for the front (> 0 inside) and z* = prod sin(pi x_i) for the bump.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


@dataclass
class ScalarField:
    """A scalar function with its gradient and Hessian, vectorized over x (d, ...)."""

    value: object
    grad: object
    hess: object

    def __mul__(self, other: ScalarField) -> ScalarField:
        a, b = self, other

        def value(x):
            return a.value(x) * b.value(x)

        def grad(x):
            return a.grad(x) * b.value(x) + a.value(x) * b.grad(x)

        def hess(x):
            ga, gb = a.grad(x), b.grad(x)
            return (a.hess(x) * b.value(x) + b.hess(x) * a.value(x)
                    + ga[:, None] * gb[None, :] + gb[:, None] * ga[None, :])

        return ScalarField(value, grad, hess)

    def shifted(self, c: float) -> ScalarField:
        return ScalarField(lambda x: self.value(x) + c, self.grad, self.hess)


def bump(d: int) -> ScalarField:
    """phi = prod_i sin(pi x_i)."""
    def value(x):
        return np.prod(np.sin(np.pi * x), axis=0)

    def grad(x):
        s, c = np.sin(np.pi * x), np.cos(np.pi * x)
        out = np.empty_like(x)
        for i in range(d):
            out[i] = np.pi * c[i] * np.prod(np.delete(s, i, axis=0), axis=0)
        return out

    def hess(x):
        s, c = np.sin(np.pi * x), np.cos(np.pi * x)
        out = np.empty((d, d) + x.shape[1:])
        for i in range(d):
            for j in range(d):
                if i == j:
                    out[i, j] = -np.pi**2 * np.prod(s, axis=0)
                else:
                    rest = np.prod(np.delete(s, [i, j], axis=0), axis=0) if d > 2 else 1.0
                    out[i, j] = np.pi**2 * c[i] * c[j] * rest
        return out

    return ScalarField(value, grad, hess)


def front(d: int, center=None, radius: float = 0.3, width: float = 0.05) -> ScalarField:
    """phi = tanh((|x - c| - r0) / w): a steep front on the sphere |x - c| = r0."""
    c = np.full(d, 0.5) if center is None else np.asarray(center, dtype=float)

    def parts(x):
        y = x - c.reshape((d,) + (1,) * (x.ndim - 1))
        r = np.sqrt(np.sum(y * y, axis=0))
        r = np.maximum(r, 1e-14)
        th = np.tanh((r - radius) / width)
        d1 = (1.0 - th**2) / width
        d2 = -2.0 * th * (1.0 - th**2) / width**2
        return y, r, th, d1, d2

    def value(x):
        return parts(x)[2]

    def grad(x):
        y, r, _, d1, _ = parts(x)
        return d1 * y / r

    def hess(x):
        y, r, _, d1, d2 = parts(x)
        e = y / r
        eye = np.eye(d).reshape((d, d) + (1,) * (x.ndim - 1))
        ee = e[:, None] * e[None, :]
        return d2 * ee + (d1 / r) * (eye - ee)

    return ScalarField(value, grad, hess)


def cube_bubble(d: int) -> ScalarField:
    """b = 4^d prod x_i (1 - x_i): zero on the boundary of the unit cube, 1 at its centre."""
    def value(x):
        return 4.0**d * np.prod(x * (1 - x), axis=0)

    def grad(x):
        f = x * (1 - x)
        out = np.empty_like(x)
        for i in range(d):
            out[i] = 4.0**d * (1 - 2 * x[i]) * np.prod(np.delete(f, i, axis=0), axis=0)
        return out

    def hess(x):
        f = x * (1 - x)
        out = np.empty((d, d) + x.shape[1:])
        for i in range(d):
            for j in range(d):
                if i == j:
                    out[i, j] = 4.0**d * (-2.0) * np.prod(np.delete(f, i, axis=0), axis=0)
                else:
                    rest = np.prod(np.delete(f, [i, j], axis=0), axis=0) if d > 2 else 1.0
                    out[i, j] = 4.0**d * (1 - 2 * x[i]) * (1 - 2 * x[j]) * rest
        return out

    return ScalarField(value, grad, hess)


def _profile(d: int, name, width: float = 0.05) -> ScalarField:
    if isinstance(name, ScalarField):
        return name
    if name == "bump":
        return bump(d)
    if name == "front":
        return front(d, width=width)
    raise ValueError(f"profile: got {name!r}, must be bump, front or a ScalarField")


def _initial_mesh(d: int, n0: int, tagged: bool):
    if tagged:
        from ..fem.eld_mesh import box, unit_square

        return unit_square(n0) if d == 2 else box(n0, n0, n0)
    from ..fem.mesh import unit_cube, unit_square

    return unit_square(n0) if d == 2 else unit_cube(n0)


# -- elasticity ---------------------------------------------------------------------------------

def _elasticity_solve(mesh, degree, lam, mu, kappa, a, phi):
    from ..fem.elasticity import VectorSpace
    from .eld_indicator import stress

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


def _energy_error(mesh, degree, U, u_exact, grad_exact, energy):
    """|||u - u_h||| with a quadrature of degree 2p + 4 on every cell."""
    from .simplex import SimplexEvaluator

    ev = SimplexEvaluator(mesh, degree, cell_order=2 * degree + 4)
    x = ev.cell_points
    e = u_exact(x) - ev.values(U)
    ge = grad_exact(x) - ev.gradients(U)
    return float(np.sqrt(np.sum(energy(e, ge) * ev.cell_dx)))


def elasticity_study(dim: int = 2, degree: int = 1, profile="bump", *, n0: int = 2,
                     adaptive: bool = True, max_dofs: int = 5000, theta: float = 0.5,
                     lam: float = 2.0, mu: float = 1.0, kappa: float = 1.0,
                     width: float = 0.05, max_levels: int = 40) -> list[dict]:
    """Rows (dofs, cells, estimate, error, efficiency) of the ELD step study (module doc).

    ``profile``: "bump", "front" (of ``width``) or a :class:`ScalarField`; adaptive: Doerfler
    marking with ``theta`` and one bisection per marked cell; uniform: d bisections of every
    cell per level (every edge halved). Stops after the first mesh with >= ``max_dofs``.
    """
    from ..fem.adapt import AdaptiveMesh
    from ..fem.adapt.marking import doerfler_marking
    from .eld_indicator import eld_indicators, stress

    phi = _profile(dim, profile, width)
    a = np.array([1.0, 0.5, 0.25][:dim])
    amesh = AdaptiveMesh(_initial_mesh(dim, n0, tagged=True))
    rows = []
    for _ in range(max_levels):
        mesh = amesh.mesh
        space, u, u_exact, grad_exact, body, neumann = _elasticity_solve(
            mesh, degree, lam, mu, kappa, a, phi)
        def traction(x, n, grad_exact=grad_exact):
            return np.einsum("ijfq,jfq->ifq", stress(grad_exact(x), lam, mu), n)

        ind = eld_indicators(mesh, degree, lam, mu, u, rho=kappa, accel=u, body_force=body,
                             traction={p: traction for p in neumann},
                             dirichlet_parts=("left",), reaction=kappa)

        def energy(e, ge):
            S = stress(ge, lam, mu)
            eps = 0.5 * (ge + np.swapaxes(ge, 0, 1))
            return np.sum(S * eps, axis=(0, 1)) + kappa * np.sum(e * e, axis=0)

        U = u.reshape(-1, dim)
        err = _energy_error(mesh, degree, U, u_exact, grad_exact, energy)
        rows.append({"dofs": space.ndofs, "cells": mesh.t.shape[1], "estimate": ind.estimate,
                     "error": err, "efficiency": ind.estimate / err})
        if space.ndofs >= max_dofs:
            break
        if adaptive:
            amesh.refine(doerfler_marking(ind.eta, theta))
        else:
            amesh.uniform(dim)
    return rows


# -- RIS step -----------------------------------------------------------------------------------

def _g(z):
    return 48.0 * (1.0 - z * z) ** 2


def _dg(z):
    return -192.0 * z * (1.0 - z * z)


def _d2g(z):
    return 576.0 * z * z - 192.0


def _ris_exact(dim: int, profile, width: float = 0.05) -> ScalarField:
    if isinstance(profile, ScalarField):
        return profile
    if profile == "bump":
        return bump(dim)
    if profile == "front":
        return cube_bubble(dim) * front(dim, width=width).shifted(1.5)
    raise ValueError(f"profile: got {profile!r}, must be bump, front or a ScalarField")


def _ris_solve(mesh, zs: ScalarField, lam: float, kappa: float):
    from ..fem.scalar import boundary_nodes, lumped_mass, stiffness
    from .simplex import SimplexEvaluator

    def load(x):
        H = zs.hess(x)
        z = zs.value(x)
        return -np.trace(H, axis1=0, axis2=1) + _dg(z) + lam * z + kappa

    n = mesh.p.shape[1]
    fixed = boundary_nodes(mesh)
    free = np.setdiff1d(np.arange(n), fixed)
    K = stiffness(mesh)
    A = sp.csr_matrix(K[free][:, free])
    m = lumped_mass(mesh)[free]
    ev = SimplexEvaluator(mesh, 1, cell_order=6)
    from ..fem.adapt.topology import lagrange_values

    phi = lagrange_values(ev.cell_lam, 1)  # (d+1, nq)
    lq = load(ev.cell_points)  # (nc, nq)
    local = np.einsum("cq,kq,cq->kc", lq, phi, ev.cell_dx)
    lfull = np.bincount(ev.t.ravel(), weights=local.ravel(), minlength=n)
    l_free = lfull[free]
    z = np.maximum(zs.value(mesh.p[:, free]), 0.0)
    for _ in range(60):
        r = A @ z + m * (_dg(z) + lam * z + kappa) - l_free
        J = A + sp.diags(m * (_d2g(z) + lam))
        dz = spla.splu(sp.csc_matrix(J), permc_spec="MMD_AT_PLUS_A").solve(-r)
        z = z + dz
        if np.max(np.abs(dz)) <= 1e-12 * max(1.0, np.max(np.abs(z))):
            break
    full = np.zeros(n)
    full[free] = z
    return full, load, bool(np.all(z > 0))


def ris_study(dim: int = 2, profile="front", *, n0: int = 4, adaptive: bool = True,
              max_dofs: int = 5000, theta: float = 0.5, lam: float = 250.0, kappa: float = 1.0,
              width: float = 0.05, max_levels: int = 40) -> list[dict]:
    """Rows (dofs, cells, estimate, error, efficiency, positive) of the RIS step study.

    ``positive``: all free nodal values of z_h > 0, i.e. the subgradient kappa sign(z_h - 0)
    of the discrete step is the kappa assumed by the manufactured load.
    """
    from ..fem.adapt import AdaptiveMesh
    from ..fem.adapt.marking import doerfler_marking
    from .ris_indicator import ris_indicators

    zs = _ris_exact(dim, profile, width)
    amesh = AdaptiveMesh(_initial_mesh(dim, n0, tagged=False))
    rows = []
    for _ in range(max_levels):
        mesh = amesh.mesh
        z, load, positive = _ris_solve(mesh, zs, lam, kappa)
        ind = ris_indicators(mesh, z, np.zeros_like(z), dg=_dg, load=load, kappa=kappa, lam=lam,
                             reaction=lam)

        def energy(e, ge):
            return np.sum(ge * ge, axis=0) + lam * e * e

        err = _energy_error(mesh, 1, z, zs.value, zs.grad, energy)
        n_free = int(np.count_nonzero(z))
        rows.append({"dofs": n_free, "cells": mesh.t.shape[1], "estimate": ind.estimate,
                     "error": err, "efficiency": ind.estimate / err, "positive": positive})
        if n_free >= max_dofs:
            break
        if adaptive:
            amesh.refine(doerfler_marking(ind.eta, theta))
        else:
            amesh.uniform(dim)
    return rows


def dofs_for_error(rows: list[dict], target: float) -> float:
    """Dofs at which the error of a study reaches ``target`` (log-log interpolation)."""
    dofs = np.array([r["dofs"] for r in rows], dtype=float)
    err = np.array([r["error"] for r in rows])
    if err.min() > target:
        return float("nan")
    k = int(np.argmax(err <= target))
    if k == 0:
        return float(dofs[0])
    x0, x1 = np.log(dofs[k - 1]), np.log(dofs[k])
    y0, y1 = np.log(err[k - 1]), np.log(err[k])
    s = (np.log(target) - y0) / (y1 - y0)
    return float(np.exp(x0 + s * (x1 - x0)))
