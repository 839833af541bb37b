"""Efficiency of residual error indicators on manufactured stationary problems: the shared parts.

Each family measures its indicator on a stationary model problem with a known exact solution (a
Rothe step with a fixed reaction coefficient) on sequences of uniformly and adaptively refined
meshes, and reports per mesh the dofs, the estimate eta = (sum eta_K^2)^(1/2), the exact error in
the energy norm and the *efficiency* eta / |||e|||: :func:`rothe.eld.efficiency.elasticity_study`
and :func:`rothe.ris.efficiency.ris_study`. Here: the exact solutions' scalar profiles phi --
``bump`` (prod sin(pi x_i), smooth) and ``front`` (tanh((|x - x_c| - r0)/w), a steep circular
front, w = 0.05 by default) --, the initial meshes, the refinement loop :func:`refinement_study`
and :func:`dofs_for_error`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..mesh import box, unit_cube, unit_square
from ..simplex import SimplexEvaluator
from .bisection import AdaptiveMesh
from .marking import doerfler_marking


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
            return (
                a.hess(x) * b.value(x)
                + b.hess(x) * a.value(x)
                + ga[:, None] * gb[None, :]
                + gb[:, None] * ga[None, :]
            )

        return ScalarField(value, grad, hess)

    def shifted(self, c: float) -> ScalarField:
        """phi + c (same gradient and Hessian)."""
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
                    out[i, j] = -(np.pi**2) * np.prod(s, axis=0)
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


def profile_field(d: int, name, width: float = 0.05) -> ScalarField:
    """The profile phi by name: ``'bump'`` (:func:`bump`), ``'front'`` (:func:`front` of
    ``width``), or a :class:`ScalarField` itself.
    """
    if isinstance(name, ScalarField):
        return name
    if name == "bump":
        return bump(d)
    if name == "front":
        return front(d, width=width)
    raise ValueError(f"profile: got {name!r}, must be bump, front or a ScalarField")


def initial_mesh(d: int, n0: int, tagged: bool):
    """The unit square (d = 2) or cube (d = 3) with ``n0`` cells per side; ``tagged``: with
    named boundary parts (left, right, ...; the cube as :func:`~rothe.fem.mesh.box`).
    """
    if tagged:
        return unit_square(n0, named=True) if d == 2 else box(n0, n0, n0)
    return unit_square(n0) if d == 2 else unit_cube(n0)


def refinement_study(
    dim: int,
    n0: int,
    tagged: bool,
    level,
    *,
    adaptive: bool,
    max_dofs: int,
    theta: float,
    max_levels: int,
) -> list[dict]:
    """The loop of an efficiency study: solve and estimate on a mesh, then refine it.

    Parameters
    ----------
    dim : int
        2 (unit square) or 3 (unit cube), see :func:`initial_mesh`.
    n0 : int
        Cells per side of the initial mesh.
    tagged : bool
        Whether the initial mesh has named boundary parts (:func:`initial_mesh`).
    level : callable(mesh) -> (dict, ndarray)
        The family's step on one mesh: its row (with ``"dofs"``) and the indicators eta_K.
    adaptive : bool
        Doerfler marking of eta with ``theta`` and one bisection per marked cell; otherwise
        ``dim`` bisections of every cell per level (every edge halved).
    max_dofs : int
        Stop after the first mesh whose row has ``dofs`` >= ``max_dofs``.
    theta : float
        Doerfler's bulk parameter.
    max_levels : int
        At most this many meshes.

    Returns
    -------
    list of dict
        The rows, one per mesh.
    """
    amesh = AdaptiveMesh(initial_mesh(dim, n0, tagged=tagged))
    rows = []
    for _ in range(max_levels):
        row, eta = level(amesh.mesh)
        rows.append(row)
        if row["dofs"] >= max_dofs:
            break
        if adaptive:
            amesh.refine(doerfler_marking(eta, theta))
        else:
            amesh.uniform(dim)
    return rows


def energy_error(mesh, degree, U, u_exact, grad_exact, energy):
    """|||u - u_h||| with a quadrature of degree 2p + 4 on every cell."""

    ev = SimplexEvaluator(mesh, degree, cell_order=2 * degree + 4)
    x = ev.cell_points
    e = u_exact(x) - ev.values(U)
    ge = grad_exact(x) - ev.gradients(U)
    return float(np.sqrt(np.sum(energy(e, ge) * ev.cell_dx)))


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
