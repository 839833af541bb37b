"""The examples of Andreia & Meyer (2022), Sec. 7, and a phase front for space adaptivity.

* **Example 7.1** (:func:`example_7_1`): a one-dimensional RIS with a known BV solution (7.1).
* **Example 7.2** (:func:`example_7_2`): the double well g(z) = 48 (1 - z^2)^2 of (7.2) on the
  unit square with P1 finite elements; :func:`example_7_2_3d` the same energy on the unit cube.
* **A phase front** (:func:`example_front`, not in the paper): the double well of (7.2) under a
  load that grows from a corner, the example for meshes that change between steps.
* **A front with a unique solution** (:func:`example_front_unique`, not in the paper): a strictly
  convex energy under the same kind of load; the benchmark problem of space adaptivity (its
  solution at every t is an obstacle problem, :func:`front_unique_state`).

Example 7.1: Z = V = R, V = 1, R(v) = |v|, T = 5, z_0 = -2 and (note the sign of the load)

    I(t, z) = 1/2 z^2 - (t + 1) z + p(z),
    p(z) = 4z + 8 (z <= -2),   4 - z^2 (|z| < 2),   -4z + 8 (z >= 2).

The paper prints f with a sign convention under which (7.1) is not a solution; with the energy
above, (7.1) is: D_z I(t, -2) = 1 - t, so z = -2 sticks while |1 - t| <= 1, i.e. until t = 2;
for -2 < z < 2, -D_z I(2, z) = z + 3 > 1, so there is no stable state until z >= 6, where
D_z I(2, z) = z - 7 reaches -1 (viscous jump from -2 to 6 at t = 2); then z - (t + 1) - 4 = -1
keeps the state on the slip line z = t + 4.

Exact V-parametrized BV solution (7.1), s in [0, 16]:
    t(s) = s, 2, (s - 6)/2     and     z(s) = -2, s - 4, (s + 2)/2
on [0, 2], (2, 10], (10, 16].
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import check_int, check_positive, check_real
from ..fem.mesh import bad, describe, mesh_dim, unit_cube, unit_square
from .fem_problem import FERISProblem
from .problem import RISProblem

# -- Example 7.1 ---------------------------------------------------------------------------------

S_EXACT = 16.0
BREAKPOINTS = np.array([0.0, 2.0, 10.0, 16.0])


def p(z):
    """p(z) of Example 7.1: 4z + 8 (z <= -2), 4 - z^2 (|z| < 2), -4z + 8 (z >= 2)."""
    z = float(np.asarray(z).reshape(-1)[0])
    if z <= -2:
        return 4 * z + 8
    if z < 2:
        return 4 - z * z
    return -4 * z + 8


def dp(z):
    """p'(z) as a vector of one entry (the derivative F' of the problem)."""
    z = float(np.asarray(z).reshape(-1)[0])
    if z <= -2:
        return np.array([4.0])
    if z < 2:
        return np.array([-2 * z])
    return np.array([-4.0])


def d2p(z):
    """Generalized second derivative: one-sided value at the kinks z = -2 and z = 2."""
    z = float(np.asarray(z).reshape(-1)[0])
    return np.array([-2.0 if -2 < z < 2 else 0.0])


def example_7_1(T: float = 5.0) -> RISProblem:
    """The RIS of Example 7.1 (1 unknown).

    I(t, z) = 1/2 z^2 - (t + 1) z + p(z) with p of :func:`p`, R(v) = |v|, V = R, z0 = -2 (the
    paper prints f with a sign convention under which (7.1) is not a solution; this is the
    energy for which it is): sticking at -2 until t = 2, a viscous jump to 6, then slip along
    z = t + 4 (the exact solution (7.1), :func:`exact_solution`).

    Parameters
    ----------
    T : float
        The end time (default 5).

    Returns
    -------
    RISProblem
    """
    return RISProblem(
        A=np.array([[1.0]]),
        F=p,
        dF=dp,
        d2F=d2p,
        load=lambda t: np.array([t + 1.0]),
        load_rate=lambda t: np.array([1.0]),
        dissipation_weights=1.0,
        metric_weights=1.0,
        z0=np.array([-2.0]),
        T=T,
        name="ris-1d",
    )


def exact_solution(s):
    """(t(s), z(s)) of (7.1), continued constantly beyond S = 16."""
    s = np.asarray(s, dtype=float)
    t = np.where(s <= 2, s, np.where(s <= 10, 2.0, (np.minimum(s, S_EXACT) - 6) / 2))
    z = np.where(s <= 2, -2.0, np.where(s <= 10, s - 4, (np.minimum(s, S_EXACT) + 2) / 2))
    return t, z


def errors_against_exact(s_num, t_num, z_num) -> dict:
    """L2 and L-infinity errors of the affine interpolants (t^, z^) against (7.1), over s.

    Both curves are piecewise linear in s; on [0, max(S_h, 16)] the shorter one is continued
    constantly (as in the paper's convergence proofs). The difference is piecewise linear between
    the union of breakpoints, so the max over those points is the exact L-infinity norm and
    Simpson on each piece is the exact L2 norm. The pointwise error is the Euclidean norm of
    (t^ - t, z^ - z).
    """
    s_num = np.asarray(s_num, float)
    t_num = np.asarray(t_num, float)
    z_num = np.asarray(z_num, float).reshape(len(s_num))
    s_end = max(s_num[-1], S_EXACT)
    nodes = np.union1d(np.union1d(s_num, BREAKPOINTS), [s_end])

    def diff(x):
        te, ze = exact_solution(x)
        tn = np.interp(x, s_num, t_num)
        zn = np.interp(x, s_num, z_num)
        return tn - te, zn - ze

    dt, dz = diff(nodes)
    linf = float(np.max(np.hypot(dt, dz)))
    a, b = nodes[:-1], nodes[1:]
    mid = 0.5 * (a + b)
    # evaluate just inside each piece: both interpolants are continuous, so endpoints are exact
    dta, dza = dt[:-1], dz[:-1]
    dtb, dzb = dt[1:], dz[1:]
    dtm, dzm = diff(mid)
    sq = lambda u, v: u * u + v * v  # noqa: E731
    l2sq = np.sum((b - a) / 6 * (sq(dta, dza) + 4 * sq(dtm, dzm) + sq(dtb, dzb)))
    return {"error_l2": float(np.sqrt(l2sq)), "error_linf": linf}


# -- Example 7.2 and its 3D analogue ----------------------------------------------------------


def g_7_2(z):
    """g(z) = 48 (1 - z^2)^2, the double well of (7.2)."""
    return 48.0 * (1.0 - z * z) ** 2


def dg_7_2(z):
    """g'(z) = -192 z (1 - z^2)."""
    return -192.0 * z * (1.0 - z * z)


def d2g_7_2(z):
    """g''(z) = 576 z^2 - 192 (negative for |z| < 1/sqrt(3): g is not convex)."""
    return 576.0 * z * z - 192.0


def example_7_2(
    n: int = 40, mesh=None, *, pattern: str = "tensor", name: str = "ris-2d", **energy
) -> FERISProblem:
    """Example 7.2 of Andreia & Meyer (2022), Sec. 7.2.

    Omega = (0,1)^2 (an n x n-cell grid, (n+1)^2 nodes; 1681 nodes for the default n = 40) or
    any 2D ``mesh``; g(z) = 48 (1 - z^2)^2; <l(t), z> = amplitude t^3 int z with amplitude
    -200; T = 1; z0 = 0; R = ||.||_{L1}, V = L2, both lumped. g is even, so ``amplitude`` > 0
    (or ``z0`` of the other sign) gives the mirrored branch z -> -z.

    Parameters
    ----------
    n : int
        Cells per side of the built-in grid (at least 2); ignored with ``mesh``.
    mesh : skfem.MeshTri, optional
        Any 2D mesh instead of the grid.
    pattern : str
        The triangulation of the grid (:func:`rothe.fem.mesh.unit_square`), default "tensor".
    name : str
        The problem's name.
    **energy
        ``amplitude`` (default -200), ``z0`` (0), ``kappa`` (1: R = kappa ||.||_{L1}), ``T``
        (1) and ``dirichlet`` (None: the whole boundary; see
        :class:`~rothe.ris.fem_problem.FERISProblem`).

    Returns
    -------
    FERISProblem
    """
    mesh = unit_square(_grid_cells(n), pattern) if mesh is None else mesh
    return _energy_7_2_on(mesh, 2, name, **energy)


def example_7_2_3d(n: int = 12, mesh=None, *, name: str = "ris-3d", **energy) -> FERISProblem:
    """The energy of Example 7.2 on the unit cube (n^3 cubes, 6 tetrahedra each) or a 3D mesh.

    Same g, load, T, z0, R and V as :func:`example_7_2`; only the domain changes. Not in the
    paper: it shows that nothing in the discretization or the solver depends on d.

    Parameters
    ----------
    n : int
        Cubes per side of the built-in grid (at least 2); ignored with ``mesh``.
    mesh : skfem.MeshTet, optional
        Any 3D mesh instead of the grid.
    name : str
        The problem's name.
    **energy
        ``amplitude``, ``z0``, ``kappa``, ``T``, ``dirichlet`` as in :func:`example_7_2`.

    Returns
    -------
    FERISProblem
    """
    mesh = unit_cube(_grid_cells(n)) if mesh is None else mesh
    return _energy_7_2_on(mesh, 3, name, **energy)


def _grid_cells(n) -> int:
    """n cells per side of a built-in grid: at least 2, so that there is an interior node."""
    return check_int("n", n, minimum=2)


def _energy_7_2_on(
    mesh,
    dim,
    name,
    *,
    amplitude=-200.0,
    z0=0.0,
    kappa=1.0,
    T=1.0,
    dirichlet=None,
    quadrature="lumped",
) -> FERISProblem:
    """g of (7.2) and the load amplitude t^3 int z on a ``dim``-dimensional mesh (the defaults
    of Example 7.2)."""
    amplitude = check_real("amplitude", amplitude)
    if mesh_dim(mesh) != dim:
        cells = "triangles" if dim == 2 else "tetrahedra"
        raise bad(
            "mesh",
            f"a {mesh_dim(mesh)}D mesh ({describe(mesh)})",
            f"must be {dim}D ({cells}) for {name}",
        )
    return FERISProblem(
        mesh,
        g_7_2,
        dg_7_2,
        d2g_7_2,
        load=lambda t: amplitude * t**3,
        load_rate=lambda t: 3.0 * amplitude * t**2,
        kappa=kappa,
        z0=z0,
        T=T,
        dirichlet=dirichlet,
        name=name,
        quadrature=quadrature,
    )


# -- a phase front that crosses the domain (space adaptivity) -----------------------------------

#: parameters of :func:`example_front`: load plateau, front speed and width, stiffness c
FRONT_DEFAULTS = {"amplitude": -120.0, "speed": 1.6, "width": 0.04, "coefficient": 0.1}


def front_load_density(amplitude: float, speed: float, width: float, corner=(0.0, 0.0)):
    """l(t, x) = A / 2 (1 + tanh((v t - |x - x_c|) / w)): a load that grows from a corner.

    A plateau of height A behind a circle of radius v t around the corner x_c, falling to 0
    over a width w ahead of it. Returns (density, its t-derivative)."""
    xc = np.asarray(corner, dtype=float)

    def radius(x):
        return np.sqrt(np.sum((x - xc.reshape(-1, *([1] * (x.ndim - 1)))) ** 2, axis=0))

    def density(t, x):
        return 0.5 * amplitude * (1.0 + np.tanh((speed * t - radius(x)) / width))

    def rate(t, x):
        return 0.5 * amplitude * speed / width / np.cosh((speed * t - radius(x)) / width) ** 2

    return density, rate


def example_front(
    n: int = 32,
    mesh=None,
    *,
    amplitude: float = FRONT_DEFAULTS["amplitude"],
    speed: float = FRONT_DEFAULTS["speed"],
    width: float = FRONT_DEFAULTS["width"],
    coefficient: float = FRONT_DEFAULTS["coefficient"],
    kappa: float = 1.0,
    z0: float = 1.0,
    T: float = 1.0,
    dirichlet=("right",),
    pattern: str = "tensor",
    name: str = "ris-front",
    quadrature: str = "lumped",
) -> FERISProblem:
    """A phase front crossing the unit square: the double well of (7.2) under a growing load.

    Not in the paper; built for space adaptivity. Omega = (0,1)^2, g(z) = 48 (1 - z^2)^2,
    R = kappa ||.||_{L1}, V = L2 (lumped), I = 1/2 int c |grad z|^2 + int g(z) - <l, z>, the
    state starts in the well z0 = 1, and the load density of :func:`front_load_density` grows
    from the corner (0, 0) at speed ``speed`` (it covers the far corner at t = sqrt(2)/speed
    < T). Where the load falls below -(max |g'| on [0, 1] + kappa) = -74.9 (A < 0), the state
    leaves the well near z = 1 for the well near z = -1: a phase front, as steep as c is small
    (interface width about sqrt(c / 192) = 0.023 for c = 0.1), sweeps across the domain. z = 0
    on the side ``right`` (natural boundary on the others): a static boundary layer there, the
    front is the only moving steep feature. On a uniform grid the front needs a fine h
    everywhere; an adaptive mesh only along the front, coarsening behind it.

    Parameters
    ----------
    n : int
        Cells per side of the built-in grid; ignored with ``mesh``.
    mesh : skfem.MeshTri, optional
        Any 2D mesh instead of the grid.
    amplitude, speed, width : float
        The load plateau A, front speed v and width w of :func:`front_load_density`.
    coefficient : float
        The stiffness c of 1/2 int c |grad z|^2.
    kappa : float
        R = kappa ||.||_{L1}.
    z0 : float
        The initial state.
    T : float
        The end time.
    dirichlet : sequence of str
        The boundary parts where z = 0.
    pattern : str
        The triangulation of the grid (:func:`rothe.fem.mesh.unit_square`).
    name : str
        The problem's name.

    Returns
    -------
    FERISProblem
    """
    coefficient = check_positive("coefficient", coefficient)
    density, rate = front_load_density(
        check_real("amplitude", amplitude),
        check_positive("speed", speed),
        check_positive("width", width),
    )
    mesh = _mesh_2d(n, mesh, pattern, "ris-front")
    return FERISProblem(
        mesh,
        g_7_2,
        dg_7_2,
        d2g_7_2,
        load=None,
        load_density=density,
        load_density_rate=rate,
        kappa=kappa,
        coefficient=coefficient,
        z0=z0,
        T=T,
        dirichlet=None if dirichlet is None else list(dirichlet),
        name=name,
        quadrature=quadrature,
    )


# -- a front with a unique solution (the benchmark of space adaptivity) -------------------------

#: parameters of :func:`example_front_unique`: load plateau, front speed and width, stiffness c,
#: reaction a (g(z) = a/2 z^2)
FRONT_UNIQUE_DEFAULTS = {
    "amplitude": 3.0,
    "speed": 0.9,
    "width": 0.025,
    "coefficient": 1e-3,
    "reaction": 10.0,
}


def example_front_unique(
    n: int = 16,
    mesh=None,
    *,
    amplitude: float = FRONT_UNIQUE_DEFAULTS["amplitude"],
    speed: float = FRONT_UNIQUE_DEFAULTS["speed"],
    width: float = FRONT_UNIQUE_DEFAULTS["width"],
    coefficient: float = FRONT_UNIQUE_DEFAULTS["coefficient"],
    reaction: float = FRONT_UNIQUE_DEFAULTS["reaction"],
    kappa: float = 1.0,
    z0: float = 0.0,
    T: float = 1.0,
    dirichlet=("right",),
    pattern: str = "tensor",
    name: str = "ris-front-unique",
) -> FERISProblem:
    """A steep front crossing the unit square whose evolution is unique (strictly convex energy).

    Not in the paper; the benchmark problem of space adaptivity (issue 18, item 3). Omega =
    (0,1)^2, z = 0 on the side ``right`` (natural boundary elsewhere), z0 = 0,

        I(t, z) = 1/2 int c |grad z|^2 + int a/2 z^2 - <l(t), z>,   R = kappa ||.||_{L1},
        V = L2 (both lumped),

    with the load density l(t, x) = A/2 (1 + tanh((v t - |x|) / w)) of
    :func:`front_load_density` (a circle of radius v t around the corner (0, 0); with the
    defaults A = 3, v = 0.9, w = 0.025, c = 10^-3, a = 10, kappa = 1, T = 1).

    **Why the solution is unique.** I(t, .) is a quadratic form plus a linear one with
    A + diag(a m) >= a min(m) > 0 (strictly, uniformly convex, a > 0), and R is convex and
    positively homogeneous: a rate-independent system with a uniformly convex energy has exactly
    one solution, Lipschitz in t, and its energetic, BV (viscosity-limit) and differential
    solutions coincide (Mielke & Roubicek, Rate-independent systems, 2015, Thm. 3.4.4 / Sec.
    3.4; no viscous jumps, since a jump needs a second local minimizer). Every step (3.1) of the
    scheme is a strictly convex minimization, so its z_k is unique too: runs on different meshes
    or with different controls approximate the same curve, and errors against a finer
    reference are pure discretization errors (the double well of :func:`example_front` has two
    stable branches, and runs on different meshes followed different ones).

    **What the solution is.** For A >= 0 the load grows in t at every point (dl/dt >= 0), and
    the solution at time t is the obstacle problem

        z(t) = argmin_{z >= 0} I(t, z) + kappa int z

    (:func:`front_unique_state`): it is nondecreasing in t (comparison principle), so
    R(z(t) - z(r)) = kappa int (z(t) - z(r)); where z > 0 its KKT condition is -D_z I = kappa
    (the flow rule of a point that moves), where z = 0 the discrete stiffness is an M-matrix
    (P1 on meshes of right triangles, as the grid and its bisections) so -D_z I = l - (A z)_i
    is in [0, kappa] (stable). Behind the circle z ~ (A - kappa) / a = 0.2, ahead z = 0: the
    front is the ring where l crosses kappa, a layer about w wide (smoothed over sqrt(c / a) =
    0.01) that sweeps from (0, 0) to radius 0.9 at t = 1 (it never reaches the Dirichlet side).
    On a uniform grid it needs a fine h everywhere, on an adaptive mesh only along the ring.
    ||dz/dt||_V stays below 1 (0.27 at t = 0.1, 0.61 at t = 0.5, 0.82 at t = 0.9, measured on
    the 64 x 64 grid), so steps of length tau in s advance t by about tau / (1 + ||dz/dt||_V) and
    the ball constraint is inactive in almost every step (no viscous steps; on coarse grids a few
    catch-up steps, see :func:`rothe.ris.summary.viscous_jumps`).

    The scheme's step with the ball constraint inactive (lambda_k = 0) is the obstacle problem
    at its load time t_{k-1} exactly (same argument on the mesh): tested.

    Parameters
    ----------
    n : int
        Cells per side of the built-in grid (at least 2); ignored with ``mesh``.
    mesh : skfem.MeshTri, optional
        Any 2D mesh instead of the grid.
    amplitude, speed, width : float
        The load plateau A, front speed v > 0 and width w > 0 of :func:`front_load_density`.
    coefficient : float
        The stiffness c > 0 of 1/2 int c |grad z|^2.
    reaction : float
        a > 0 in g(z) = a/2 z^2 (a > 0 makes I strictly convex).
    kappa : float
        R = kappa ||.||_{L1}.
    z0 : float
        The initial state (default 0; the solution is unique for every z0, the obstacle
        problem is the solution for z0 = 0 and A >= 0).
    T : float
        The end time.
    dirichlet : sequence of str
        The boundary parts where z = 0.
    pattern : str
        The triangulation of the grid (:func:`rothe.fem.mesh.unit_square`).
    name : str
        The problem's name.

    Returns
    -------
    FERISProblem
    """
    a = check_positive("reaction", reaction)
    density, rate = front_load_density(
        check_real("amplitude", amplitude),
        check_positive("speed", speed),
        check_positive("width", width),
    )
    mesh = _mesh_2d(n, mesh, pattern, name)
    return FERISProblem(
        mesh,
        lambda z: 0.5 * a * z * z,
        lambda z: a * z,
        lambda z: np.full(np.shape(z), a),
        load=None,
        load_density=density,
        load_density_rate=rate,
        kappa=kappa,
        coefficient=check_positive("coefficient", coefficient),
        z0=z0,
        T=T,
        dirichlet=None if dirichlet is None else list(dirichlet),
        name=name,
    )


def front_unique_state(problem: FERISProblem, t: float, reaction: float, iterations: int = 100):
    """The solution of :func:`example_front_unique` at time t on the problem's mesh (A >= 0).

    z = argmin_{z >= 0} 1/2 <K z, z> - <l(t) - r, z>, K = A + a diag(m), r_i = kappa m_i (the
    obstacle problem of the docstring of :func:`example_front_unique`), by the primal-dual
    active set method: with mu = K z - (l - r) the KKT conditions are z >= 0, mu >= 0,
    z_i mu_i = 0; the active set {mu_i - z_i > 0} is updated until it repeats (finite and
    monotone for an M-matrix K). Returns z on the free nodes.
    """
    K = (problem.A + sp.diags(reaction * problem.m)).tocsr()
    b = problem.load(t) - problem.r
    active = b <= 0
    z = np.zeros(problem.n)
    for _ in range(iterations):
        z = np.zeros(problem.n)
        inactive = ~active
        if inactive.any():
            z[inactive] = spla.spsolve(K[inactive][:, inactive].tocsc(), b[inactive])
        mu = K @ z - b
        new = mu - z > 0
        if np.array_equal(new, active):
            return z
        active = new
    raise RuntimeError(f"front_unique_state: no active set after {iterations} iterations")


def front_unique_error(reference: FERISProblem, t: float, z, points, cells, reaction) -> float:
    """|| z_h - z(t) ||: the L2 norm with the lumped mass of ``reference``'s mesh (the V-norm
    of the scheme there) of the P1 function ``z`` (nodal values at ``points``, shape (n, 2), on
    the triangles ``cells``, shape (m, 3): e.g. a coarser or adapted mesh) minus the exact
    state of :func:`example_front_unique` at time t on the reference mesh
    (:func:`front_unique_state`). z_h is evaluated at the reference's nodes (exact for nested
    meshes)."""
    # matplotlib's trapezoid-map point location: scikit-fem's probes took 29 s and 4 GB for
    # 16 641 points on a 64 x 64 grid
    import matplotlib.tri as mtri

    exact = reference.full_state(front_unique_state(reference, t, reaction))
    points = np.asarray(points, dtype=float)
    tri = mtri.Triangulation(points[:, 0], points[:, 1], np.asarray(cells))
    at = reference.mesh.p
    z_h = mtri.LinearTriInterpolator(tri, np.asarray(z, dtype=float))(at[0], at[1])
    return float(np.sqrt(np.sum(reference.m_all * (z_h.filled(np.nan) - exact) ** 2)))


def _mesh_2d(n, mesh, pattern, name):
    """The n x n grid (``pattern``) or the given 2D ``mesh`` of a front example."""
    mesh = unit_square(_grid_cells(n), pattern) if mesh is None else mesh
    if mesh_dim(mesh) != 2:
        raise bad(
            "mesh",
            f"a {mesh_dim(mesh)}D mesh ({describe(mesh)})",
            f"must be 2D (triangles) for {name}",
        )
    return mesh
