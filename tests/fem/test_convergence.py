"""Convergence of the FE energy and gradient against a manufactured z (order 2 for P1).

z(x) = prod_k sin(pi x_k) vanishes on the boundary of the unit square / cube. For its nodal
interpolant z_h, the discrete energy I_h(t, z_h) = 1/2 z.Az + sum_i m_i g(z_i) - <l(t), z>
(nodal quadrature of F, exact load functionals) must converge to I(t, z) at order 2: the
interpolation error of the Dirichlet energy is O(h^2) (a(z, I_h z - z) = (-Lap z, I_h z - z)),
and so is the vertex rule for int g(z_h). The directional derivative D I_h(z_h)[v_h] for the
interpolant of a smooth v converges to D I(z)[v] at order 2 as well, on any shape-regular mesh.
On the uniform grid the nodal representer (A z_h)_i / m_i of -Lap z is also O(h^2) (the
five-point stencil). Orders are fitted by least squares over several meshes.
"""

from __future__ import annotations

import numpy as np
import pytest
from skfem import MeshTri

from rothe.fem.mesh import unit_cube, unit_square
from rothe.ris.examples import d2g_7_2, dg_7_2, g_7_2
from rothe.ris.fem_problem import FERISProblem

T_EVAL = 0.8
AMP = -200.0


def _gauss_square(k=40):
    x, w = np.polynomial.legendre.leggauss(k)
    x, w = 0.5 * (x + 1), 0.5 * w
    X, Y = np.meshgrid(x, x, indexing="ij")
    return X.ravel(), Y.ravel(), np.outer(w, w).ravel()


def _z(x, y):
    return np.sin(np.pi * x) * np.sin(np.pi * y)


def _v(x, y):
    return x * (1 - x) * y * (1 - y) * np.exp(x - 0.5 * y)


def _grad(f, x, y, h=1e-6):
    return ((f(x + h, y) - f(x - h, y)) / (2 * h), (f(x, y + h) - f(x, y - h)) / (2 * h))


def exact_energy_2d(t=T_EVAL):
    """1/2 int |grad z|^2 + int 48 (1 - z^2)^2 - AMP t^3 int z for z = sin(pi x) sin(pi y)."""
    return np.pi**2 / 4 + 48 * (1 - 2 / 4 + 9 / 64) - AMP * t**3 * 4 / np.pi**2


def exact_derivative_2d(t=T_EVAL):
    """D I(t, z)[v] = int grad z . grad v + g'(z) v - AMP t^3 v, by 40 x 40 Gauss."""
    X, Y, W = _gauss_square()
    zx = np.pi * np.cos(np.pi * X) * np.sin(np.pi * Y)
    zy = np.pi * np.sin(np.pi * X) * np.cos(np.pi * Y)
    vx, vy = _grad(_v, X, Y)
    z, v = _z(X, Y), _v(X, Y)
    return float(np.sum(W * (zx * vx + zy * vy + dg_7_2(z) * v - AMP * t**3 * v)))


def _problem(mesh):
    return FERISProblem(mesh, g_7_2, dg_7_2, d2g_7_2, load=lambda t: AMP * t**3)


def _fit_order(hs, errs):
    return np.polyfit(np.log(hs), np.log(errs), 1)[0]


def _jiggled(n, seed=1):
    m = unit_square(n, "unionjack")
    rng = np.random.default_rng(seed)
    p = m.p.copy()
    inner = np.ones(p.shape[1], bool)
    inner[m.boundary_nodes()] = False
    p[:, inner] += 0.2 / n * rng.uniform(-1, 1, (2, inner.sum()))
    return MeshTri(p, m.t)


@pytest.mark.parametrize("make", [unit_square, _jiggled], ids=["grid", "jiggled"])
def test_energy_and_derivative_converge_at_order_2(make):
    ns = [8, 16, 32, 64]
    e_energy, e_deriv = [], []
    for n in ns:
        prob = _problem(make(n))
        x, y = prob.mesh.p[:, prob.free]
        z, v = _z(x, y), _v(x, y)
        e_energy.append(abs(prob.energy(T_EVAL, z) - exact_energy_2d()))
        e_deriv.append(abs(prob.gradient(T_EVAL, z) @ v - exact_derivative_2d()))
    hs = 1.0 / np.array(ns)
    p_energy, p_deriv = _fit_order(hs, e_energy), _fit_order(hs, e_deriv)
    assert 1.8 < p_energy < 2.3, (e_energy, p_energy)
    assert 1.8 < p_deriv < 2.3, (e_deriv, p_deriv)
    assert e_energy[-1] < 0.05 and e_deriv[-1] < 0.05


def test_gradient_nodal_representer_order_2_on_grid():
    """max_i |(D I_h(z_h))_i / m_i - (-Lap z + g'(z) - l)(x_i)| = O(h^2) on the uniform grid."""
    ns = [8, 16, 32, 64]
    errs = []
    for n in ns:
        prob = _problem(unit_square(n))
        x, y = prob.mesh.p[:, prob.free]
        z = _z(x, y)
        strong = 2 * np.pi**2 * z + dg_7_2(z) - AMP * T_EVAL**3
        errs.append(np.max(np.abs(prob.gradient(T_EVAL, z) / prob.m - strong)))
    order = _fit_order(1.0 / np.array(ns), errs)
    assert 1.9 < order < 2.1, (errs, order)


def test_energy_converges_at_order_2_in_3d():
    def exact(t=T_EVAL):
        return 3 * np.pi**2 / 16 + 48 * (1 - 2 / 8 + 27 / 512) - AMP * t**3 * 8 / np.pi**3

    ns = [4, 8, 16]
    errs = []
    for n in ns:
        prob = _problem(unit_cube(n))
        x, y, w = prob.mesh.p[:, prob.free]
        z = np.sin(np.pi * x) * np.sin(np.pi * y) * np.sin(np.pi * w)
        errs.append(abs(prob.energy(T_EVAL, z) - exact()))
    order = _fit_order(1.0 / np.array(ns), errs)
    assert 1.8 < order < 2.4, (errs, order)
