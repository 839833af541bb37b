"""Couplings B u = G(t, q): action = reaction, the constraint's virtual work and power, the
derivatives G', G'' (curvature terms), and the refusals."""

import numpy as np
import pytest
import scipy.sparse as sp
from skfem import MeshTri

from rothe.eld import ELDProblem, Material
from rothe.eld.components import MassSpringDamper, PointMass, RigidBody
from rothe.eld.coupling import CoupledProblem, RigidMotion, Translation, UserCoupling
from rothe.errors import RotheInputError
from rothe.fem.mesh import tag_box_faces

MAT = Material(rho=1.0, lam=1.0, mu=1.0)


def _strip(nx=8, ny=2):
    return tag_box_faces(
        MeshTri.init_tensor(np.linspace(0, 2, nx + 1), np.linspace(0, 0.5, ny + 1))
    )


def _zero(t, x):
    return 0 * x


def _system(degree=2, with_left=True):
    body = RigidBody(2.0, 0.1, [2.2, 0.25], reference=[2.0, 0.25])
    problem = ELDProblem(
        _strip(), MAT, degree=degree, dirichlet={"left": _zero} if with_left else {"bottom": _zero}
    )
    return CoupledProblem(problem, [body], [RigidMotion("right", body)]), body


@pytest.mark.filterwarnings("ignore:G_d")
@pytest.mark.parametrize("degree", [1, 2])
def test_action_equals_reaction_for_a_rigid_body(degree):
    """Gamma^T M_G lambda is the resultant force and moment (about x_ref) of the traction
    lambda on the part, i.e. minus the reaction of the rigid body on the elastic one."""
    system, body = _system(degree)
    c = system.constraint
    rng = np.random.default_rng(0)
    lam = rng.standard_normal(c.m)
    gen = system.generalized_reaction(lam)
    L = lam.reshape(-1, 2)
    space = system.body.space
    Ms = space.boundary_scalar_mass(("right",))[c.scalar_dofs][:, c.scalar_dofs]
    force = np.array([np.sum(Ms @ L[:, 0]), np.sum(Ms @ L[:, 1])])
    r = c.scalar_points - body.reference[:, None]
    moment = r[0] @ (Ms @ L[:, 1]) - r[1] @ (Ms @ L[:, 0])
    assert np.allclose(gen, [*force, moment], rtol=1e-13, atol=1e-13)
    assert np.allclose(gen[:2], -c.reactions(lam)["right"], rtol=1e-13, atol=1e-13)
    # virtual work: for (du, dq) with S du = Gamma dq, lambda . B du = gen . dq (to round-off)
    dq = rng.standard_normal(3)
    du = rng.standard_normal(space.ndofs)
    du[c.dofs] = system.gamma() @ dq
    lhs, rhs = lam @ (c.B @ du), gen @ dq
    assert abs(lhs - rhs) <= 1e-14 * max(abs(lhs), 1.0)
    # the body term B^T lambda and the component term are the two sides of that identity
    assert abs(system.body_reaction(lam) @ du - rhs) <= 1e-14 * max(abs(rhs), 1.0)


@pytest.mark.filterwarnings("ignore:G_d")
def test_translation_data_derivatives_and_lifted_modes():
    mass = PointMass(1.0)
    stage = MassSpringDamper(1.0, 4.0, name="stage")
    problem = ELDProblem(
        _strip(), MAT, degree=2, dirichlet={"left": lambda t, x: np.stack([t + 0 * x[0], 0 * x[0]])}
    )
    # 'left' is moved in y by the stage's second coordinate, 'right' by the mass
    system = CoupledProblem.from_body(
        _strip(),
        MAT,
        components=[stage, mass],
        couplings=[
            Translation("left", stage, coordinates=[1], directions=[[0.0], [1.0]]),
            Translation("right", mass),
        ],
    )
    Gam = system.gamma().toarray()
    left = 2 * system.constraint.part_positions["left"]
    assert np.array_equal(Gam[left + 1, 1], np.ones(left.size)) and np.all(Gam[left, :] == 0)
    assert system.offsets == {"stage": 0, "mass": 2} and system.size == 4
    system = CoupledProblem(problem, [mass], [Translation("right", mass)])
    c = system.constraint
    q, p, pd = np.array([0.1, -0.2]), np.array([1.0, 2.0]), np.array([3.0, 4.0])
    right = (2 * c.part_positions["right"][:, None] + np.arange(2)).ravel()
    left = (2 * c.part_positions["left"][:, None] + np.arange(2)).ravel()
    g, gd, gdd = system.g(0.5, q), system.g_dot(0.5, q, p), system.g_ddot(0.5, q, p, pd)
    assert np.allclose(g[right].reshape(-1, 2), q) and np.allclose(gd[right].reshape(-1, 2), p)
    assert np.allclose(gdd[right].reshape(-1, 2), pd)
    assert np.allclose(g[left].reshape(-1, 2), [0.5, 0.0])
    assert np.allclose(gd[left].reshape(-1, 2), [1.0, 0.0])
    Gam = system.gamma().toarray()
    assert np.allclose(Gam @ q, g - system.body.G(0.5))
    from rothe.eld.constraint import HarmonicLifting, NodalLifting

    Phi = system.lifted_modes(NodalLifting(c))
    assert sp.issparse(Phi)  # (n, r) sparse: nothing n x r dense for glued bodies
    Phi = Phi.toarray()
    assert np.allclose(Phi[c.dofs], Gam) and np.abs(Phi[c.free]).max() == 0.0
    # the harmonic lifting of a translation of 'right' with 'left' held: the same trace, and
    # K-orthogonal to ker B (K Phi vanishes on the free dofs)
    PhiH = system.lifted_modes(HarmonicLifting(c, system.body.K))
    assert sp.issparse(PhiH)
    PhiH = PhiH.toarray()
    assert np.allclose(PhiH[c.dofs], Gam)
    assert np.abs((system.body.K @ PhiH)[c.free]).max() < 1e-12
    assert system.check_initial_consistency() == 0.0


def _rotation(theta):
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def _finite_rotation(x0):
    """G = a + (R(theta) - I)(x - x0): a rigid motion with a finite rotation (nonlinear)."""

    def G(t, q, x):
        r = x - x0[:, None]
        return q[:2, None] + (_rotation(q[2]) - np.eye(2)) @ r

    def G_q(t, q, x):
        r = x - x0[:, None]
        dR = np.array([[-np.sin(q[2]), -np.cos(q[2])], [np.cos(q[2]), -np.sin(q[2])]])
        J = np.zeros((2, x.shape[1], 3))
        J[0, :, 0] = J[1, :, 1] = 1.0
        J[:, :, 2] = dR @ r
        return J

    def curvature(t, q, p, x):  # G_qq[p, p] = p_theta^2 R''(theta) r = -p_theta^2 R r
        return -(p[2] ** 2) * (_rotation(q[2]) @ (x - x0[:, None]))

    return G, G_q, curvature


@pytest.mark.filterwarnings("ignore:G_d")
def test_curvature_terms_of_a_nonlinear_coupling_give_the_second_time_derivative():
    """G'' = G_qq[q', q'] + G_q q'' along a path q(t): compared with central differences."""
    x0 = np.array([2.0, 0.25])
    G, G_q, curv = _finite_rotation(x0)
    body = RigidBody(1.0, 0.1, x0)
    system = CoupledProblem(
        ELDProblem(_strip(), MAT, dirichlet={"left": _zero}),
        [body],
        [UserCoupling("right", body, G, G_q, curvature=curv)],
    )
    assert not system.is_linear

    def path(t):  # q(t), q'(t), q''(t)
        return (
            np.array([0.1 * t, -0.05 * t**2, 0.8 * np.sin(2 * t)]),
            np.array([0.1, -0.1 * t, 1.6 * np.cos(2 * t)]),
            np.array([0.0, -0.1, -3.2 * np.sin(2 * t)]),
        )

    t, h = 0.4, 1e-4
    q, p, pd = path(t)
    fd1 = (system.g(t + h, path(t + h)[0]) - system.g(t - h, path(t - h)[0])) / (2 * h)
    fd2 = (
        system.g(t + h, path(t + h)[0]) - 2 * system.g(t, q) + system.g(t - h, path(t - h)[0])
    ) / h**2
    assert np.abs(system.g_dot(t, q, p) - fd1).max() < 1e-8
    assert np.abs(system.g_ddot(t, q, p, pd) - fd2).max() < 1e-5
    # without the curvature term G'' misses p_theta^2 R r
    no_curv = CoupledProblem(
        ELDProblem(_strip(), MAT, dirichlet={"left": _zero}),
        [body],
        [UserCoupling("right", body, G, G_q)],
    )
    assert np.abs(no_curv.g_ddot(t, q, p, pd) - fd2).max() > 0.1


@pytest.mark.filterwarnings("ignore:G_d")
def test_power_of_the_constraint_forces_vanishes_for_scleronomic_couplings():
    """lambda . B v - (Gamma^T M_G lambda) . p = 0 when the trace of v is Gamma p."""
    system, body = _system(2)
    c = system.constraint
    rng = np.random.default_rng(1)
    lam, p = rng.standard_normal(c.m), rng.standard_normal(3)
    v = rng.standard_normal(system.body.space.ndofs)
    v[c.dofs] = system.g_dot(0.0, np.zeros(3), p)  # zero on 'left', Gamma p on 'right'
    power_body = -lam @ (c.B @ v)
    power_component = system.generalized_reaction(lam) @ p
    assert abs(power_body + power_component) < 1e-13 * abs(power_component)


@pytest.mark.filterwarnings("ignore:G_d")
def test_a_body_held_only_by_couplings():
    mass = MassSpringDamper(1.0, 1.0)
    system = CoupledProblem.from_body(
        _strip(), MAT, components=[mass], couplings=[Translation("bottom", mass)], T=2.0
    )
    assert system.constraint.parts == ("bottom",) and system.body.T == 2.0
    with pytest.raises(RotheInputError, match=r"^couplings: got \[\], must hold at least one"):
        CoupledProblem.from_body(_strip(), MAT, components=[mass], couplings=[])
    with pytest.raises(RotheInputError, match=r"^lamda: got an unknown keyword, must be one of"):
        CoupledProblem.from_body(
            _strip(), MAT, components=[mass], couplings=[Translation("bottom", mass)], lamda=1.0
        )


@pytest.mark.filterwarnings("ignore:G_d")
def test_bad_coupling_input_is_one_line_each():
    mass = PointMass(1.0)
    other = PointMass(2.0, name="other")
    body3 = RigidBody(1.0, 1.0, [0, 0, 0], dim=3)
    loaded = ELDProblem(
        _strip(), MAT, dirichlet={"left": _zero}, traction={"right": lambda t, x, n: 0 * x}
    )
    plain = ELDProblem(_strip(), MAT, dirichlet={"left": _zero})
    x0 = np.array([2.0, 0.25])
    G, G_q, curv = _finite_rotation(x0)
    body = RigidBody(1.0, 0.1, x0)

    def bad_G_q(t, q, x):
        J = G_q(t, q, x)
        J[:, :, 2] *= 2.0
        return J

    cases = [
        (
            lambda: CoupledProblem(plain, [mass], [Translation("tip", mass)]),
            r"^couplings\[0\]\.part: got 'tip', must be one of bottom, left, right, top \(boundary "
            r"parts of the mesh\)$",
        ),
        (
            lambda: CoupledProblem(loaded, [mass], [Translation("right", mass)]),
            r"^couplings\[0\]\.part: got 'right', also carries a traction; a coupled part is held",
        ),
        (
            lambda: CoupledProblem(plain, [mass], [Translation("left", mass)]),
            r"^couplings\[0\]\.part: got 'left', also carries prescribed Dirichlet data; a part is "
            r"either prescribed or coupled$",
        ),
        (
            lambda: CoupledProblem(plain, [mass], [Translation("bottom", mass)]),
            r"^couplings\[0\]\.part: got 'bottom', shares 1 node\(s\) with the constrained part "
            r"'left'; coupled parts must not touch other constrained parts$",
        ),
        (
            lambda: CoupledProblem(plain, [mass], [Translation("right", other)]),
            r"^couplings\[0\]\.component: got 'other', must be one of the system's components: "
            r"mass$",
        ),
        (
            lambda: CoupledProblem(plain, [mass, mass], []),
            r"^components\[1\]\.name: got 'mass', must be unique in the system$",
        ),
        (
            lambda: CoupledProblem(
                plain, [mass], [Translation("right", mass), Translation("right", mass)]
            ),
            r"^couplings\[1\]\.part: got 'right', is already coupled \(couplings\[0\]\)$",
        ),
        (
            lambda: CoupledProblem(plain, [body3], [RigidMotion("right", body3)]),
            r"^body: got a 3D rigid body, must have the mesh's dimension 2$",
        ),
        (
            lambda: CoupledProblem(plain, [body], [UserCoupling("right", body, G, bad_G_q)]),
            r"^G_q: got a Jacobian that disagrees with finite differences of G in q at ",
        ),
        (
            lambda: CoupledProblem(
                plain,
                [body],
                [
                    UserCoupling(
                        "right", body, G, G_q, curvature=lambda t, q, p, x: 2 * curv(t, q, p, x)
                    )
                ],
            ),
            r"^curvature: got a Jacobian that disagrees with finite differences of G_q p along p",
        ),
        (
            lambda: CoupledProblem(
                plain, [PointMass(1.0, q0=[0.01, 0.0])], [Translation("right", PointMass(1.0))]
            ),
            r"^couplings\[0\]\.component: got 'mass', must be one of the system's components",
        ),
        (
            lambda: Translation("right", mass, coordinates=[2]),
            r"^coordinates: got 2, must be an index of the component's 2 coordinates$",
        ),
        (
            lambda: RigidMotion("right", mass),
            r"^body: got 'PointMass', must be a "
            r"rothe.eld.RigidBody$",
        ),
    ]
    for make, message in cases:
        with pytest.raises(RotheInputError, match=message) as info:
            make()
        assert "\n" not in str(info.value)
    moved = PointMass(1.0, q0=[0.01, 0.0])
    system = CoupledProblem(plain, [moved], [Translation("right", moved)])
    with pytest.raises(
        RotheInputError,
        match=r"^u0: got max\|u0 - G\(0, q0\)\| = 0\.01 on the "
        r"part 'right', must equal G\(0, q0\) there",
    ):
        system.check_initial_consistency()
    system.body.u0 = system.consistent_u0()
    assert system.check_initial_consistency() == 0.0


@pytest.mark.parametrize("degree", [1, 2])
def test_known_data_are_the_bodys_data_without_the_coupled_parts(degree):
    """CoupledProblem.known_data (the step's prescribed data, placeholders skipped) equals the
    body's G, G_dot, G_ddot on every constrained dof, for data varying along the part."""
    from rothe.eld import DirichletData

    def f(t, x):
        return np.stack([np.sin(t) * x[1] ** 2, np.cos(t) * x[1] + x[0]])

    def fd(t, x):
        return np.stack([np.cos(t) * x[1] ** 2, -np.sin(t) * x[1] + 0 * x[0]])

    def fdd(t, x):
        return np.stack([-np.sin(t) * x[1] ** 2, -np.cos(t) * x[1] + 0 * x[0]])

    mesh = tag_box_faces(MeshTri.init_tensor(np.linspace(0, 1, 7), np.linspace(0, 0.25, 4)))
    mat = Material.from_young(100.0, 0.3, 1.0, dim=2, plane="stress")
    body = ELDProblem(mesh, mat, degree=degree, dirichlet={"left": DirichletData(f, fd, fdd)})
    tip = PointMass(0.3, dim=2)
    system = CoupledProblem(body, [tip], [Translation("right", tip)])
    known = system.known_data(0.7)
    ref = (system.body.G(0.7), system.body.G_dot(0.7), system.body.G_ddot(0.7))
    assert np.abs(ref[0]).max() > 0.1 and np.abs(ref[1]).max() > 0.01
    for a, b in zip(known, ref, strict=True):
        assert np.array_equal(a, b)
    assert np.array_equal(system.known_data(0.7, derivatives=False)[0], ref[0])
