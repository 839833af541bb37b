"""Residual error indicator for one Rothe step of elastodynamics (Altmann 2015, (3.4)).

A step of the scheme is the stationary problem (strong form, w := u + b v the field whose
stress enters, b the Kelvin-Voigt coefficient of the damping)

    rho a + c_M v + N(v) - div sigma(w) = f   in Omega,
    sigma(w) n = g                             on Gamma_N,       u = G on Gamma_D (multiplier),

with a and v the scheme's acceleration and velocity *as finite element fields on the step's
mesh* (Euler: a = D^2 u^j = (u^j - 2u^{j-1} + u^{j-2})/tau^2, v = D u^j; BDF2 likewise, with
the history transferred to this mesh), c_M the mass-proportional damping (Rayleigh a, or -d0 of
the nonlinear damping), N a pointwise damping force (d_nl v/sqrt(1 + |v|^2/v_ref^2)) and
sigma(w) = lam tr eps(w) I + 2 mu eps(w). The indicator of a cell K is the residual estimator

    eta_K^2 = alpha_K^2 ||R_K||_K^2 + 1/2 sum_{F in F_int(K)} mu^{-1/2} alpha_F ||J_F||_F^2
              + sum_{F in F_N(K)} mu^{-1/2} alpha_F ||g - sigma(w_h) n||_F^2,

    R_K = f - rho a_h - c_M v_h - N(v_h) + div sigma(w_h)   (div sigma = 0 in P1 cells),
    J_F = [sigma(w_h) n]_F - h_F  (jump of the normal stress across the interior facet F,
          less the interface load h_F of a body of several materials: its weak form puts
          int_F h . phi on F, so the exact solution has [sigma n]_F = h_F there),
    alpha_S = min(h_S / (p sqrt(mu)), 1 / sqrt(kappa)),

h_K the longest edge of K, h_F that of F, p the polynomial degree (the h/p scaling of
Melenk & Wohlmuth 2001 for P2), kappa >= 0 the reaction coefficient of the step
(``reaction``: rho/tau^2 for an Euler step, 9 rho/(4 tau^2) for BDF2, 0 for statics). With
kappa = 0 this is the classical h_K ||R_K|| + h_F^{1/2} ||J_F|| estimator scaled by mu^{-1/2},
reliable and efficient for the energy norm (a(e, e) + kappa ||e||^2)^{1/2} up to constants that
depend on the shape regularity and on lam/mu (Verfuerth; the kappa-robust weights are his).
Facets on the Dirichlet parts contribute nothing (the multiplier takes up the traction there).
The Dirichlet data error (G not in the trace space) is not estimated.

Why residual and not Zienkiewicz-Zhu recovery: the residual estimator has proven upper and
lower bounds on every mesh, including the graded meshes and boundary layers of a moving front;
ZZ recovery is asymptotically exact on smooth solutions but needs superconvergence, which
graded bisection meshes and P2 do not give. The efficiency band is measured in
``benchmarks/adapt_efficiency.py`` and asserted in ``tests/eld/test_indicator.py``.

Works for vector P1 and P2 on triangles (plane strain) and tetrahedra, with the dofs
interleaved as in :class:`rothe.fem.elasticity.VectorSpace` (component c of scalar dof k is
``d*k + c``). Vectorized: one pass over the cells, one over the interior facets, one over the
Neumann facets.
"""

from __future__ import annotations

import numpy as np

from ..errors import check_nonnegative, check_positive, described, fail
from ..fem.simplex import CellIndicators, SimplexEvaluator, assemble_indicators, robust_weight
from .damping import NonlinearDamping, RayleighDamping, saturating_velocity
from .problem import CellwiseLoad


def _as_field(U, n: int, d: int, name: str) -> np.ndarray:
    arr = np.asarray(U, dtype=float)
    if arr.shape != (n * d,):
        raise fail(
            name,
            described(f"an array of shape {arr.shape}"),
            f"must be an interleaved vector dof array of shape ({n * d},)",
        )
    return arr.reshape(n, d)


#: interior facets per chunk of the jump term: its quadrature temporaries (basis gradients and
#: stresses on both sides, about 5 KB per P2 facet in 3D) were the peak of the estimate phase
#: of an adaptive 3D run (about 50 MB at 15k dofs in one piece)
FACET_CHUNK = 2048
#: cells per chunk of the cell residual: its quadrature values (coordinates, a, v, R: (d, n,
#: nq) each, 24 points per P2 tetrahedron) in one piece were 20 MB of the estimate's
#: temporaries at 6k cells, the peak of an adaptive 3D run once one mesh's system lives at a
#: time (docs/adaptivity.md)
CELL_CHUNK = 1024


def _at(data, x: np.ndarray, *extra) -> np.ndarray:
    """A callable data(x, ...) or an array given at the points, broadcast to x's shape."""
    vals = data(x, *extra) if callable(data) else data
    return np.broadcast_to(np.asarray(vals, dtype=float), x.shape)


def _coefficient(name: str, value, n_cells: int, minimum: str):
    """A material coefficient of the indicator: a float, or one value per cell (an (n_cells,)
    array: a body of several materials); ``minimum`` 'positive', 'nonnegative' or 'real'."""
    if np.ndim(value) == 0:
        check = {"positive": check_positive, "nonnegative": check_nonnegative}.get(minimum)
        return check(name, value) if check else float(value)
    arr = np.asarray(value, dtype=float)
    bad = {
        "positive": ~(arr > 0),
        "nonnegative": ~(arr >= 0),
        "real": ~np.isfinite(arr),
    }[minimum]
    if arr.shape != (n_cells,) or bad.any():
        raise fail(
            name,
            described(f"an array of shape {arr.shape}"),
            f"must be a number or {minimum} values, one per cell ({n_cells},)",
        )
    return arr


def _on(value, cells, trailing: int = 0):
    """A coefficient on ``cells`` (a float stays a float), with ``trailing`` axes appended for
    broadcasting against (..., cells, q) arrays."""
    if np.ndim(value) == 0:
        return value
    return value[cells].reshape((-1,) + (1,) * trailing)


def stress(grad: np.ndarray, lam: float, mu: float) -> np.ndarray:
    """sigma = lam tr(eps) I + 2 mu eps for grad[c, k] = d_k w_c (leading axes (d, d, ...))."""
    d = grad.shape[0]
    eps = 0.5 * (grad + np.swapaxes(grad, 0, 1))
    tr = np.trace(eps, axis1=0, axis2=1)
    eye = np.eye(d).reshape((d, d) + (1,) * (grad.ndim - 2))
    return lam * tr[None, None] * eye + 2.0 * mu * eps


def eld_indicators(
    mesh,
    degree: int,
    lam: float,
    mu: float,
    u: np.ndarray,
    *,
    rho: float = 1.0,
    accel: np.ndarray | None = None,
    velocity: np.ndarray | None = None,
    mass_damping=0.0,
    stiffness_damping: float = 0.0,
    pointwise_damping=None,
    body_force=None,
    traction: dict | None = None,
    dirichlet_parts=(),
    reaction: float = 0.0,
    evaluator: SimplexEvaluator | None = None,
    material_index: np.ndarray | None = None,
    interface_load=None,
) -> CellIndicators:
    """Cell indicators eta_K of one elastodynamics step (formula in the module docstring).

    Parameters
    ----------
    mesh : skfem.MeshTri | skfem.MeshTet with named boundaries (the step's mesh)
    degree : 1 | 2
    lam, mu : Lame constants (mu > 0 also scales the weights); floats, or one value per cell
        ((n_cells,) arrays: a body of several materials -- the stresses of each cell with its
        own constants, the jump across a material interface of the two sides' normal
        stresses, a facet weighted by the smaller mu and reaction of its two cells)
    u : (d * n,) displacement u^j (interleaved dofs)
    rho, accel : density (a float or per cell) and the scheme's acceleration a^j as a field
        (None: 0)
    velocity : the scheme's velocity v^j as a field (None: 0); enters through
        ``mass_damping`` c_M (c_M v; a float or per cell), ``stiffness_damping`` b
        (sigma(u + b v)) and ``pointwise_damping`` (a callable v -> force density, v and the
        result (d, ...)).
    body_force : callable f(x) with x (d, ...) -> (d, ...), or values at the cell quadrature
        points (d, nc, nq), or None.
    traction : dict part -> callable g(x, n) (x, n (d, nf, nq)) on Neumann parts; boundary
        facets on no Dirichlet part and not in ``traction`` are traction free (g = 0).
    dirichlet_parts : names of the Dirichlet parts (excluded from the boundary residual).
    reaction : kappa >= 0 of the robust weights (rho/tau^2 for an implicit Euler step); a float
        or per cell.
    evaluator : a :class:`SimplexEvaluator` of (mesh, degree) to reuse, optional.
    material_index : (n_cells,) integers, optional
        Each cell's material (several materials). Then the callables get it as well:
        ``body_force(x, k)`` with k (n, 1) of the cells, ``g(x, n, k)`` with k (nf, 1) of the
        cell next to each facet, and ``interface_load`` applies.
    interface_load : callable h(x, n, k0, k1), optional
        The load on the facets between two materials (needs ``material_index``; x, n (d, nf,
        nq), n the outward normal of side 0, k0, k1 (nf, 1) the two sides' materials), taken
        off their jump J_F (:class:`~rothe.eld.problem.ELDProblem`'s ``interface_load``).
    """
    ev = evaluator if evaluator is not None else SimplexEvaluator(mesh, degree)
    nc = ev.h.shape[0]
    mu = _coefficient("mu", mu, nc, "positive")
    lam = _coefficient("lam", lam, nc, "real")
    rho = _coefficient("rho", rho, nc, "nonnegative")
    reaction = _coefficient("reaction", reaction, nc, "nonnegative")
    mass_damping = _coefficient("mass_damping", mass_damping, nc, "real")
    kc = None
    if material_index is not None:
        kc = np.asarray(material_index)
        if kc.shape != (nc,) or not np.issubdtype(kc.dtype, np.integer):
            raise fail(
                "material_index",
                described(f"an array of shape {kc.shape} ({kc.dtype})"),
                f"must be integers, one per cell ({nc},)",
            )
    if interface_load is not None and kc is None:
        raise fail("interface_load", "a load without material_index", "needs material_index")
    d, n = ev.dim, ev.ndofs
    U = _as_field(u, n, d, "u")
    W = U.copy()
    V = None
    if velocity is not None:
        V = _as_field(velocity, n, d, "velocity")
        if stiffness_damping:
            W = W + stiffness_damping * V

    # grad w at the cells' vertices, once: its Hessian (P2) and, on the facets, its
    # barycentric combination (affine on each cell: 4 terms per point in 3D instead of 10 P2
    # basis gradients)
    gv = ev.vertex_gradients(W)
    div_sigma = None
    if ev.degree == 2:
        H = ev.hessians(W, gv)  # (c, i, j, nc): d_i d_j w_c
        lap = np.trace(H, axis1=1, axis2=2)  # (c, nc)
        grad_div = np.einsum("kkic->ic", H)  # d_i (div w)
        div_sigma = mu * lap + (lam + mu) * grad_div
        del H
    alpha_K = robust_weight(ev.h / ev.degree, mu, reaction)
    A = None if accel is None or not np.any(rho) else _as_field(accel, n, d, "accel")
    # cell residual R = f - rho a - c_M v - N(v) + div sigma(w), in chunks of CELL_CHUNK cells
    # (each cell's term is its own: the chunks change no value)
    cell_sq = np.empty(nc)
    dx = ev.cell_dx
    for k0 in range(0, nc, CELL_CHUNK):
        c = slice(k0, k0 + CELL_CHUNK)
        R = np.zeros((d, len(range(nc)[c]), len(ev.cell_w)))
        if body_force is not None:
            extra = () if kc is None else (kc[c, None],)
            R += _at(body_force, ev.cell_points_of(c), *extra)
        if A is not None:
            R -= _on(rho, c, 1) * ev.values(A, c)
        if V is not None:
            vq = ev.values(V, c)  # (d, n, nq)
            if np.any(mass_damping):
                R -= _on(mass_damping, c, 1) * vq
            if pointwise_damping is not None:
                R -= np.asarray(pointwise_damping(vq), dtype=float)
            del vq
        if div_sigma is not None:
            R += div_sigma[:, c, None]
        cell_sq[c] = alpha_K[c] ** 2 * np.sum(np.sum(R * R, axis=0) * dx[c], axis=1)

    topo = ev.topology
    # interior facets: J = sigma(w)|_K0 n0 + sigma(w)|_K1 n1 (n1 = -n0), in chunks of
    # FACET_CHUNK facets (each facet's term is its own: the chunks change no value)
    ic, il = topo.inner_cells, topo.inner_local
    fverts = topo.facets[:, topo.interior]
    at = ev.gradients_from_vertices
    inner_sq = np.empty(ic.shape[1])
    for f0 in range(0, ic.shape[1], FACET_CHUNK):
        f = slice(f0, f0 + FACET_CHUNK)
        c0, c1, l0, l1, fv = ic[0, f], ic[1, f], il[0, f], il[1, f], fverts[:, f]
        meas, normal, diam = ev.facet_geometry(c0, l0)
        S0 = stress(at(gv, c0, ev.facet_lambda(c0, l0, fv)), _on(lam, c0, 1), _on(mu, c0, 1))
        S0 -= stress(at(gv, c1, ev.facet_lambda(c1, l1, fv)), _on(lam, c1, 1), _on(mu, c1, 1))
        J = np.einsum("ijfq,jf->ifq", S0, normal)
        del S0
        if interface_load is not None:
            between = kc[c0] != kc[c1]
            if between.any():
                xf = ev.facet_points(fv[:, between])
                nf = np.broadcast_to(normal[:, between, None], xf.shape)
                k0, k1 = kc[c0[between], None], kc[c1[between], None]
                J[:, between] -= _at(interface_load, xf, nf, k0, k1)
        # a facet between two materials: the smaller mu and reaction of its cells (the larger
        # weight)
        mu_F = mu if np.ndim(mu) == 0 else np.minimum(mu[c0], mu[c1])
        kappa_F = reaction if np.ndim(reaction) == 0 else np.minimum(reaction[c0], reaction[c1])
        alpha_F = robust_weight(diam / ev.degree, mu_F, kappa_F)
        w_f = meas[:, None] * ev.facet_w[None, :]
        inner_sq[f] = alpha_F / np.sqrt(mu_F) * np.sum(np.sum(J * J, axis=0) * w_f, axis=1)

    # Neumann facets: g - sigma(w) n
    bc, bl = topo.boundary_cells, topo.boundary_local
    dir_mask = (
        ev.boundary_part_mask(dirichlet_parts) if dirichlet_parts else np.zeros(len(bc), dtype=bool)
    )
    neu = ~dir_mask
    bc, bl = bc[neu], bl[neu]
    bfacets = topo.boundary[neu]
    bverts = topo.facets[:, bfacets]
    meas_b, normal_b, diam_b = ev.facet_geometry(bc, bl)
    Sb = stress(at(gv, bc, ev.facet_lambda(bc, bl, bverts)), _on(lam, bc, 1), _on(mu, bc, 1))
    Jb = -np.einsum("ijfq,jf->ifq", Sb, normal_b)
    if traction:
        xb = ev.facet_points(bverts)
        nb = np.broadcast_to(normal_b[:, :, None], xb.shape)
        known = mesh.boundaries or {}
        for part, g in traction.items():
            if part not in known:
                raise fail("traction", part, "must name a boundary part of the mesh")
            on = np.isin(bfacets, np.asarray(known[part], dtype=np.int64))
            if on.any():
                extra = () if kc is None else (kc[bc[on], None],)
                Jb[:, on] += _at(g, xb[:, on], nb[:, on], *extra)
    w_b = meas_b[:, None] * ev.facet_w[None, :]
    mu_b = _on(mu, bc)
    bnd_sq = (
        robust_weight(diam_b / ev.degree, mu_b, _on(reaction, bc))
        / np.sqrt(mu_b)
        * np.sum(np.sum(Jb * Jb, axis=0) * w_b, axis=1)
    )
    return assemble_indicators(ev, cell_sq, inner_sq, ic, bnd_sq, bc)


def eld_indicators_for(
    problem,
    t: float,
    u: np.ndarray,
    velocity: np.ndarray | None = None,
    accel: np.ndarray | None = None,
    *,
    reaction: float = 0.0,
    evaluator: SimplexEvaluator | None = None,
) -> CellIndicators:
    """:func:`eld_indicators` with the data of an :class:`~rothe.eld.problem.ELDProblem` at t.

    Damping: ``NoDamping``; ``RayleighDamping(a, b)`` (c_M = a, Kelvin-Voigt b);
    ``NonlinearDamping(b, d0, d_nl, v_ref)`` (c_M = -d0, b, N = d_nl v/sqrt(1+|v|^2/v_ref^2)).
    A ``UserDamping`` has no pointwise form: its force is left out of the cell residual.

    A body of several materials (``problem.cell_material``): per-cell lam, mu, rho, and the
    ``reaction`` -- given as rho kappa with rho the material's rho, i.e. the reference density
    rho_ref of a PiecewiseMaterial -- scaled to each cell's rho_c kappa (``density_weight``),
    and so is c_M (the damping acts through the mass of density rho_c/rho_ref,
    :mod:`rothe.eld.materials`); the body force, tractions and interface load with each
    cell's material index (``material_index``: a :class:`~rothe.eld.problem.CellwiseLoad`
    takes it).
    """
    space = problem.space
    m = problem.material
    cells = getattr(problem, "cell_material", None)
    if cells is None:
        lam, mu, rho = m.lam_eff, m.mu, m.rho
    else:
        lam, mu, rho = cells.lam, cells.mu, cells.rho
        reaction = reaction * cells.density_weight
    damp = problem.damping
    kw = {}
    if isinstance(damp, RayleighDamping):
        kw = {"mass_damping": damp.a, "stiffness_damping": damp.b}
    elif isinstance(damp, NonlinearDamping):
        kw = {"mass_damping": -damp.d0, "stiffness_damping": damp.b}
        if damp.d_nl:
            kw["pointwise_damping"] = lambda v, s=damp: s.d_nl * saturating_velocity(v, s.v_ref)
    if cells is not None and "mass_damping" in kw:
        kw["mass_damping"] = kw["mass_damping"] * cells.density_weight
    # several materials: the callables get the material index k of their cells; a
    # CellwiseLoad (rothe.eld.problem) uses it, the others do not
    cellwise = cells is not None

    def at_t(g, n_points: int):
        """g at t; with several materials k comes after the n_points point arrays, and only a
        CellwiseLoad takes it."""
        if isinstance(g, CellwiseLoad) or not cellwise:
            return lambda *a: g(float(t), *a)
        return lambda *a: g(float(t), *a[:n_points])

    body = None if problem.body_force is None else at_t(problem.body_force, 1)
    traction = {part: at_t(g, 2) for part, (g, _) in problem._traction.items()}
    interface_load = (
        None
        if problem._interface is None
        else (lambda x, n, k0, k1, h=problem._interface[0]: h(float(t), x, n, k0, k1))
    )
    return eld_indicators(
        space.mesh,
        space.degree,
        lam,
        mu,
        u,
        rho=rho,
        accel=accel,
        velocity=velocity,
        body_force=body,
        traction=traction,
        dirichlet_parts=problem.constraint.parts,
        reaction=reaction,
        evaluator=evaluator,
        material_index=None if cells is None else cells.names,
        interface_load=interface_load,
        **kw,
    )
