"""Residual error indicator for one step (3.1) of the RIS scheme with P1 elements.

Andreia & Meyer (2022), Example 1.4: I(t, z) = 1/2 int c |grad z|^2 + int g(z) - <l(t), z>,
R(v) = kappa ||v||_{L1}, V = L2. By Lemma 4.1 the step (3.1) from z_{k-1} with radius tau_k is
the existence of lambda_k >= 0 and a subgradient xi in kappa d|.|(z_k - z_{k-1}) with

    -div(c grad z_k) + g'(z_k) - l(t_{k-1}) + lambda_k (z_k - z_{k-1}) + xi = 0   in Omega,
    c d_n z_k = 0 on the natural (Neumann) boundary,  z_k = 0 on the Dirichlet parts,

((4.4) with D_z I = -div(c grad z) + g'(z) - l). The indicator of the P1 solution z_h, with
d_h = z_h - z_{k-1,h} (both on the step's mesh) and the pointwise admissible subgradient

    xi_h(x) = kappa sign(d_h(x))                      where d_h(x) != 0,
    xi_h(x) = clip(l_h(x) - g'(z_h(x)), -kappa, kappa) where d_h(x) = 0 (the cell sticks),

is

    eta_K^2 = alpha_K^2 ||R_K||_K^2
              + 1/2 sum_{F in F_int(K)} c_F^{-1/2} alpha_F ||[c grad z_h . n]||_F^2
              + sum_{F in F_N(K)} c_F^{-1/2} alpha_F ||c grad z_h . n||_F^2,
    R_K = l_h - g'(z_h) - lambda_k d_h - xi_h     (div(c grad z_h) = 0 in P1 cells),
    alpha_S = min(h_S / sqrt(c_S), 1 / sqrt(kappa_r)),

c_S the coefficient on the cell (the larger of the two cells at a facet), kappa_r >= 0 the
reaction of the robust weights (``reaction``; lambda_k is the natural choice, 0 gives the
classical h-weights). In sticking cells R_K = max(|l - g'| - kappa, 0) sign(...), the violation
of the stability condition |l - g'(z)| <= kappa; where the state moves, R_K is the residual of
the viscous equation with xi = kappa sign(d). The load l_h is a density: a callable l(x), or
nodal functionals (as ``FERISProblem.load`` returns) turned into the P1 density with nodal
values l_i / m_i (exact for a constant density). The energy norm it estimates is
(int c |grad e|^2 + kappa_r ||e||^2)^{1/2}.

Vectorized: one pass over cells (quadrature of degree 4), one over interior facets (the jump of
c grad z_h . n is constant on a facet), one over the Neumann facets.
"""

from __future__ import annotations

import numpy as np

from ..errors import check_nonnegative, described, fail
from ..fem.mesh import box_part_nodes
from ..fem.scalar import cell_coefficient
from ..fem.scalar import lumped_mass as nodal_masses
from ..fem.simplex import CellIndicators, SimplexEvaluator, assemble_indicators, robust_weight


def ris_indicators(
    mesh,
    z: np.ndarray,
    z_prev: np.ndarray,
    *,
    dg,
    load,
    kappa: float = 1.0,
    lam: float = 0.0,
    coefficient=1.0,
    dirichlet_parts=None,
    reaction: float = 0.0,
    lumped_mass: np.ndarray | None = None,
    evaluator: SimplexEvaluator | None = None,
) -> CellIndicators:
    """Cell indicators of one RIS step (formula in the module docstring).

    Parameters
    ----------
    mesh : skfem.MeshTri | skfem.MeshTet (the step's mesh)
    z, z_prev : (n_nodes,) nodal values of z_k and z_{k-1} at all nodes (zero on Dirichlet
        nodes), e.g. ``problem.full_state(z)``.
    dg : vectorized g'
    load : callable l(x) (x (d, ...) -> density), or (n_nodes,) nodal functionals <l, phi_i>
        (needs ``lumped_mass``, or it is computed), or a number (constant density).
    kappa : dissipation R(v) = kappa ||v||_{L1}
    lam : the step's multiplier lambda_k >= 0 (Lemma 4.1)
    coefficient : c of the energy (number, per-cell array or callable of the barycentres)
    dirichlet_parts : None (z = 0 on the whole boundary: no boundary term) or the names of the
        Dirichlet parts (the rest of the boundary is natural: c d_n z = 0 is its residual).
    reaction : kappa_r >= 0 of the robust weights.
    """
    kappa = check_nonnegative("kappa", kappa)
    lam = check_nonnegative("lam", lam)
    reaction = check_nonnegative("reaction", reaction)
    ev = (
        evaluator
        if evaluator is not None
        else SimplexEvaluator(mesh, 1, cell_order=4, facet_order=1)
    )
    n = ev.ndofs
    z = np.asarray(z, dtype=float)
    z_prev = np.asarray(z_prev, dtype=float)
    for name, arr in (("z", z), ("z_prev", z_prev)):
        if arr.shape != (n,):
            raise fail(
                name,
                described(f"an array of shape {arr.shape}"),
                f"must hold the values at all {n} nodes",
            )
    c = cell_coefficient(mesh, coefficient)

    zq = ev.values(z)
    dq = ev.values(z - z_prev)
    x = ev.cell_points
    if callable(load):
        lq = np.broadcast_to(np.asarray(load(x), dtype=float), zq.shape)
    else:
        arr = np.asarray(load, dtype=float)
        if arr.ndim == 0:
            lq = np.full(zq.shape, float(arr))
        else:
            if arr.shape != (n,):
                raise fail(
                    "load",
                    described(f"an array of shape {arr.shape}"),
                    f"must be a callable, a number or {n} nodal functionals",
                )
            if lumped_mass is None:
                lumped_mass = nodal_masses(mesh)
            lq = ev.values(arr / lumped_mass)
    force = lq - np.asarray(dg(zq), dtype=float)
    stick = dq == 0.0
    xi = np.where(stick, np.clip(force, -kappa, kappa), kappa * np.sign(dq))
    R = force - lam * dq - xi
    alpha_K = robust_weight(ev.h, c, reaction)
    cell_sq = alpha_K**2 * np.sum(R * R * ev.cell_dx, axis=1)

    topo = ev.topology
    grad = ev.gradients(z)[:, :, 0]  # P1: constant per cell, (d, nc)
    flux = c[None, :] * grad
    ic, il = topo.inner_cells, topo.inner_local
    meas, normal, diam = ev.facet_geometry(ic[0], il[0])
    J = np.sum((flux[:, ic[0]] - flux[:, ic[1]]) * normal, axis=0)
    cF = np.maximum(c[ic[0]], c[ic[1]])
    inner_sq = robust_weight(diam, cF, reaction) / np.sqrt(cF) * J * J * meas

    bc, bl = topo.boundary_cells, topo.boundary_local
    if dirichlet_parts is None:
        neu = np.zeros(len(bc), dtype=bool)
    else:
        parts = [dirichlet_parts] if isinstance(dirichlet_parts, str) else list(dirichlet_parts)
        neu = (
            ~ev.boundary_part_mask(parts)
            if (mesh.boundaries or {})
            else ~_box_part_mask(mesh, ev, parts)
        )
    bc, bl = bc[neu], bl[neu]
    meas_b, normal_b, diam_b = ev.facet_geometry(bc, bl)
    Jb = np.sum(flux[:, bc] * normal_b, axis=0)
    cb = c[bc]
    bnd_sq = robust_weight(diam_b, cb, reaction) / np.sqrt(cb) * Jb * Jb * meas_b
    return assemble_indicators(ev, cell_sq, inner_sq, ic, bnd_sq, bc)


def _box_part_mask(mesh, ev, parts) -> np.ndarray:
    """Boundary facets on the named sides of the bounding box (meshes without named parts)."""
    topo = ev.topology
    fverts = topo.facets[:, topo.boundary].T
    nodes = np.zeros(mesh.p.shape[1], dtype=bool)
    for part in parts:
        nodes[box_part_nodes(mesh, part, fverts)] = True
    return np.all(nodes[fverts], axis=1)


def ris_indicators_for(
    problem,
    t_prev: float,
    z: np.ndarray,
    z_prev: np.ndarray,
    lam: float = 0.0,
    *,
    coefficient=1.0,
    reaction: float = 0.0,
    evaluator: SimplexEvaluator | None = None,
) -> CellIndicators:
    """:func:`ris_indicators` for a :class:`~rothe.ris.fem_problem.FERISProblem` step.

    ``z``, ``z_prev`` on the free nodes (the problem's unknowns); the load is the problem's
    load at t_{k-1} (nodal functionals -> P1 density by the lumped mass). ``coefficient``
    must be the one the problem was built with (the problem keeps only its matrix).
    """
    full = problem.full_state
    user = getattr(problem, "_user_load", None)
    raw = np.asarray(user(float(t_prev)), dtype=float) if user is not None else None
    if raw is not None and (raw.ndim == 0 or raw.shape == (problem.n_nodes,)):
        load = float(raw) if raw.ndim == 0 else raw
    else:
        load = np.zeros(problem.n_nodes)
        load[problem.free] = problem.load(float(t_prev))
    return ris_indicators(
        problem.mesh,
        full(z),
        full(z_prev),
        dg=problem.dg,
        load=load,
        kappa=problem.kappa,
        lam=lam,
        coefficient=coefficient,
        dirichlet_parts=problem.dirichlet,
        reaction=reaction,
        lumped_mass=problem.m_all,
        evaluator=evaluator,
    )
