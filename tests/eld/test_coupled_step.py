"""The coupled step (bordered system, docs/coupling.md Sec. 4) on uniform steps of run_coupled:
the energy ledger of body + components + controllers, BDF2's dissipation, the tip-mass
frequencies, the rigid limit, orders in tau in both forms, Theorem 4.5 for noise in the
component's outputs, the decay rate under feedback, the cost per step, Newton for a nonlinear
component."""

import numpy as np
import pytest
from skfem import MeshTri

from rothe.eld import (
    BDF2,
    DirichletData,
    ELDProblem,
    ImplicitEuler,
    Material,
    NonlinearDamping,
    Original,
    RayleighDamping,
    Regularized,
    run_coupled,
)
from rothe.eld.components import MassSpringDamper, PointMass, UserComponent
from rothe.eld.control import LinearController, PointSensor, ReactionSensor
from rothe.eld.coupled_step import CoupledStepSystem, coupled_modes
from rothe.eld.coupling import CoupledProblem, Translation, UserCoupling
from rothe.eld.frequencies import (
    Attachment,
    bar_frequencies,
    controlled_bar_roots,
    crossing_frequency,
    rigid_limit_frequency,
)
from rothe.errors import RotheInputError
from rothe.fem.mesh import tag_box_faces
from rothe.stepping.controllers import Uniform

pytestmark = pytest.mark.filterwarnings("ignore:G_d")

L, H = 1.0, 0.25
BAR = Material.from_young(100.0, 0.0, 1.0, dim=2, plane="stress")  # nu = 0: an exact 1D bar


def _strip(nx, ny=1):
    return tag_box_faces(MeshTri.init_tensor(np.linspace(0, L, nx + 1), np.linspace(0, H, ny + 1)))


def _zero(t, x):
    return 0 * x


def uniform_run(system, tau, *, scheme="euler", form="regularized", lifting="nodal", **options):
    """run_coupled on uniform steps tau as a dict: the trajectory's series, the final u, v, a,
    lam, the step system's counters (``stats``) and ``n_steps``."""
    res = run_coupled(
        system,
        scheme={"euler": ImplicitEuler(), "bdf2": BDF2()}[scheme],
        form=Original() if form == "original" else Regularized(lifting=lifting),
        control=Uniform(tau),
        **options,
    )
    out = {key: res.trajectory[key] for key in res.trajectory.keys()}
    st = res.state
    out.update(u=st.u, v=st.v, a=st.a, lam=st.lam, stats=dict(res.stepper.kern.stats))
    out["n_steps"] = st.j
    return out


A, OM = 0.01, 2 * np.pi


def _shake(t, x):  # G = A (1 - cos w t)^2 in y on 'left': smooth, at rest at t = 0
    return np.stack([0 * x[0], A * (1 - np.cos(OM * t)) ** 2 + 0 * x[0]])


def _shake_dot(t, x):
    return np.stack([0 * x[0], 2 * A * OM * (1 - np.cos(OM * t)) * np.sin(OM * t) + 0 * x[0]])


def _shake_ddot(t, x):
    c, s = np.cos(OM * t), np.sin(OM * t)
    return np.stack([0 * x[0], 2 * A * OM**2 * (s * s + (1 - c) * c) + 0 * x[0]])


def _shaken_tip(degree=2, nx=6, controllers=False, T=0.5):
    """A plane-stress strip shaken on 'left', a damped mass-spring tied to 'right', Rayleigh
    damping, a body force; optionally a PD controller on the tip mass fed by the tip velocity
    and the reaction on 'left'."""
    mat = Material.from_young(100.0, 0.3, 1.0, dim=2, plane="stress")
    tip = MassSpringDamper(
        0.3, [30.0, 5.0], 0.2, name="tip", load=lambda t: np.array([0.0, -0.3 * np.sin(t)])
    )
    ctrls = []
    if controllers:
        ctrls = [
            LinearController.pd(
                0.5, 0.1, PointSensor([0.5, H / 2], "velocity"), tip, filter_time=0.02
            ),
            LinearController(
                None, None, None, [[0.05, 0.0]], ReactionSensor("left"), tip, directions=[0.0, 1.0]
            ),
        ]
    problem = ELDProblem(
        _strip(nx),
        mat,
        degree=degree,
        damping=RayleighDamping(0.1, 0.002),
        dirichlet={"left": DirichletData(_shake, _shake_dot, _shake_ddot)},
        body_force=lambda t, x: np.stack([0 * x[0], -0.1 + 0 * x[0]]),
        T=T,
    )
    return CoupledProblem(problem, [tip], [Translation("right", tip)], ctrls)


@pytest.mark.parametrize("scheme", ["euler", "bdf2"])
@pytest.mark.parametrize("form", ["regularized", "original"])
def test_energy_ledger_of_the_whole_system_closes_to_round_off(scheme, form):
    system = _shaken_tip(controllers=True)
    res = uniform_run(system, 0.01, scheme=scheme, form=form)
    scale = max(np.abs(res["energy"]).max(), np.abs(res["work_prescribed"]).max())
    assert np.abs(res["balance"]).max() < 1e-12 * scale
    assert res["residual_body"].max() < 1e-11 and res["residual_components"].max() < 1e-10
    # every term is there and non-trivial: the support's work, the controllers', the loads'
    for key in ("work_prescribed", "work_controllers", "work_components", "work", "dissipated"):
        assert abs(res[key][-1]) > 1e-8 * scale, key
    assert res["stats"]["schur_solves"] == res["n_steps"] + 1


def test_harmonic_lifting_also_closes_the_ledger_and_agrees_to_first_order():
    system = _shaken_tip()
    nodal = uniform_run(system, 0.01, scheme="bdf2")
    harm = uniform_run(system, 0.01, scheme="bdf2", lifting="harmonic")
    assert np.abs(harm["balance"]).max() < 1e-12 * np.abs(harm["energy"]).max()
    # the liftings differ at the order of the scheme (docs/eld.md): close, not equal
    diff = np.abs(harm["q"] - nodal["q"]).max()
    assert 0 < diff < 1e-2 * np.abs(nodal["q"]).max()


@pytest.mark.parametrize("degree,orders", [(1, (1.9, 1.9)), (2, (3.8, 3.8))])
def test_tip_mass_frequencies_converge_to_the_transcendental_equation(degree, orders):
    """Clamped strip (nu = 0: the 1D bar is exact) with a point mass tied to its end: the
    longitudinal frequencies of the coupled system converge to beta L tan(beta L) = rho A L/m
    (eigenvalues: order 2p)."""
    m = 0.25
    exact = bar_frequencies(L, 100.0, 1.0, area=H, right=Attachment.point_mass(m), count=2)
    errors = []
    for nx in (4, 8, 16):
        tip = PointMass(m)
        system = CoupledProblem(
            ELDProblem(_strip(nx), BAR, degree=degree, dirichlet={"left": _zero}),
            [tip],
            [Translation("right", tip)],
        )
        w, _, q = coupled_modes(system, 12)
        axial = w[np.abs(q[0]) > 10 * np.abs(q[1])]  # the tip moves along the bar
        errors.append([np.min(np.abs(axial - e)) / e for e in exact])
    errors = np.array(errors)
    assert errors[-1, 0] < (1e-4 if degree == 1 else 1e-8)
    observed = np.log2(errors[:-1] / errors[1:])
    assert observed[-1, 0] > orders[0] and observed[-1, 1] > orders[1]


def test_frequency_measured_from_a_run_converges_in_tau():
    """Starting in the first axial mode (P2, 8 cells), the tip mass oscillates at the
    discrete frequency up to BDF2's phase error O(tau^2); the energy is kept to O(tau^2)."""
    m = 0.25
    tip0 = PointMass(m)
    base = CoupledProblem(
        ELDProblem(_strip(8), BAR, degree=2, dirichlet={"left": _zero}),
        [tip0],
        [Translation("right", tip0)],
    )
    w, U, Q = coupled_modes(base, 12)
    k = int(np.argmax(np.abs(Q[0]) > 10 * np.abs(Q[1])))
    exact = bar_frequencies(L, 100.0, 1.0, area=H, right=Attachment.point_mass(m), count=1)[0]
    assert w[k] == pytest.approx(exact, rel=1e-6)
    scale = 0.01 / np.abs(Q[:, k]).max()
    tip = PointMass(m, q0=Q[:, k] * scale)
    system = CoupledProblem(
        ELDProblem(_strip(8), BAR, degree=2, dirichlet={"left": _zero}, u0=U[:, k] * scale, T=2.0),
        [tip],
        [Translation("right", tip)],
    )
    freq, energy = [], []
    for tau in (0.01, 0.005):
        res = uniform_run(system, tau, scheme="bdf2")
        freq.append(abs(crossing_frequency(res["t"], res["q"][:, 0]) / w[k] - 1))
        energy.append(abs(res["energy"][-1] / res["energy"][0] - 1))
    assert freq[0] < 3e-3 and freq[0] / freq[1] == pytest.approx(4.0, rel=0.05)
    assert energy[0] < 1e-2 and energy[0] / energy[1] > 2**1.8  # dissipation O(tau^2)
    euler = uniform_run(system, 0.005, scheme="euler")
    assert abs(euler["energy"][-1] / euler["energy"][0] - 1) > 100 * energy[1]


def test_rigid_limit_a_stiff_body_on_a_mass_spring():
    """A stiff strip held only by its tie to a mass on a spring, both moving at unit speed at
    t = 0: the frequency is (k/(m + m_body))^{1/2} (up to the body's compliance, O(1/E), and
    BDF2's O(tau^2))."""
    k, m = 50.0, 2.0
    stiff = Material.from_young(1e5, 0.0, 1.0, dim=2, plane="stress")
    base = MassSpringDamper(m, [k, 1e4], p0=[1.0, 0.0], name="base")
    system = CoupledProblem.from_body(
        _strip(4),
        stiff,
        components=[base],
        couplings=[Translation("left", base)],
        v0=lambda x: np.stack([1 + 0 * x[0], 0 * x[0]]),
        T=3.0,
    )
    res = uniform_run(system, 0.005, scheme="bdf2")
    w = crossing_frequency(res["t"], res["q"][:, 0])
    assert w == pytest.approx(rigid_limit_frequency(k, m, H * L), rel=5e-4)
    assert w == pytest.approx(
        bar_frequencies(
            L, 1e5, 1.0, area=H, left=Attachment.mass_spring(m, k), right="free", count=1
        )[0],
        rel=5e-4,
    )
    assert np.abs(res["balance"]).max() < 1e-10 * res["energy"][0]


@pytest.mark.parametrize("form", ["regularized", "original"])
def test_orders_in_tau_for_u_q_and_lambda(form):
    """BDF2: order >= 1.8 at T in u, q and lambda; Euler: about 1 (reference: BDF2 with
    tau = T/640)."""
    system = _shaken_tip()
    ref = uniform_run(system, 0.5 / 640, scheme="bdf2", form=form)
    for scheme, low in (("bdf2", 1.8), ("euler", 0.8)):
        errors = []
        for n in (20, 40, 80):
            res = uniform_run(system, 0.5 / n, scheme=scheme, form=form)
            errors.append(
                [
                    np.abs(res["u"] - ref["u"]).max(),
                    np.abs(res["q"][-1] - ref["q"][-1]).max(),
                    system.constraint.l2_norm(res["lam"] - ref["lam"]),
                ]
            )
        errors = np.array(errors)
        orders = np.log2(errors[:-1] / errors[1:])
        assert orders[-1].min() > low, (scheme, orders)
        if scheme == "euler":
            assert orders[-1].max() < 1.2


def test_noise_in_the_components_outputs_theorem_4_5():
    """Noise of size delta in the coordinates that enter the coupling data: amplified like
    tau^-2 in lambda (and tau^-1 in the component's velocity) by the original form, bounded in
    the regularized one, where q, q', q'' enter G, G', G'' as separate data."""
    system = _shaken_tip(degree=1, nx=4, T=0.1)
    delta = 1e-6
    amp = {}
    for form in ("regularized", "original"):
        rows = []
        for n in (4, 40, 400):
            rng = np.random.default_rng(5)
            vals = {
                j: tuple(delta * rng.uniform(-1, 1, 2) for _ in range(3)) for j in range(1, n + 1)
            }
            clean = uniform_run(system, 0.1 / n, scheme="bdf2", form=form)
            noisy = uniform_run(system, 0.1 / n, scheme="bdf2", form=form, noise=vals.__getitem__)
            rows.append(
                [
                    np.abs(noisy["lam_norm"] - clean["lam_norm"]).max() / delta,
                    np.abs(noisy["p"] - clean["p"]).max() / delta,
                ]
            )
        amp[form] = np.array(rows)
    slope = np.log10(amp["original"][1:] / amp["original"][:-1])  # per decade of 1/tau
    assert slope[-1, 0] > 1.8 and slope[-1, 1] > 0.8
    reg = amp["regularized"]
    assert reg[-1, 0] < 3 * reg[-2, 0] and reg[-1, 1] <= reg[-2, 1]
    assert amp["original"][-1, 0] > 100 * reg[-1, 0]


def test_velocity_feedback_decay_rate_matches_the_controlled_bar():
    """A bar (Kelvin-Voigt b K) on a base (mass, spring) pushed by -k_v times the tip
    velocity, started in its first mode: the run's decay rate and frequency against the root
    of the characteristic equation."""
    mb, kb, kv, b = 1.0, 50.0, 1.0, 0.005

    def system(gain, q0=None, u0=None):
        base = MassSpringDamper(mb, [kb, 1e4], q0=q0, name="base")
        ctrl = LinearController.pd(
            gain,
            0.0,
            PointSensor([L, H / 2], "velocity", axes=[0]),
            base,
            directions=[[1.0], [0.0]],
        )
        return CoupledProblem.from_body(
            _strip(8),
            BAR,
            degree=2,
            damping=RayleighDamping(0.0, b),
            components=[base],
            couplings=[Translation("left", base)],
            controllers=[ctrl],
            u0=u0,
            T=6.0,
        )

    w, U, Q = coupled_modes(_uncontrolled(mb, kb), 6)
    k = int(np.argmax(np.abs(Q[0]) > 10 * np.abs(Q[1])))
    scale = 0.01 / np.abs(Q[:, k]).max()
    res = uniform_run(system(kv, Q[:, k] * scale, U[:, k] * scale), 0.005, scheme="bdf2")
    t, y = res["t"], res["q"][:, 0]
    peaks = np.flatnonzero((y[1:-1] > y[:-2]) & (y[1:-1] > y[2:])) + 1
    rate = -np.polyfit(t[peaks], np.log(y[peaks]), 1)[0]
    root = controlled_bar_roots(
        L,
        100.0,
        1.0,
        area=H,
        base_mass=mb,
        base_stiffness=kb,
        H=lambda s: kv * s,
        kelvin_voigt=b,
        count=1,
    )[0]
    assert rate == pytest.approx(-root.real, rel=0.01)
    assert crossing_frequency(t, y) == pytest.approx(root.imag, rel=2e-3)
    assert res["work_controllers"][-1] < 0  # the controller takes energy out
    assert np.abs(res["balance"]).max() < 1e-12 * res["energy"][0]


def _uncontrolled(mb, kb):
    base = MassSpringDamper(mb, [kb, 1e4], name="base")
    return CoupledProblem.from_body(
        _strip(8), BAR, degree=2, components=[base], couplings=[Translation("left", base)]
    )


def test_one_back_substitution_per_step_and_r_per_factorization():
    system = _shaken_tip(controllers=True)
    res = uniform_run(system, 0.05, scheme="bdf2")
    st = res["stats"]
    # two factorizations (the initial acceleration with rho M, the step matrix), each with
    # r = 2 border columns; then one back-substitution per step (and one for a_0)
    assert st["factorizations"] == 2
    assert st["back_substitutions"] == 2 * 2 + res["n_steps"] + 1


def test_nonlinear_component_by_newton_on_the_border_alone():
    """A tip mass on a hardening spring k q + k3 q^3: Newton on (q, z) only (no more
    back-substitutions than a linear run), the ledger closes with the spring's work booked."""
    k, k3 = 30.0, 3e5

    def force(t, q, p):
        return k * q + k3 * q**3 + 0.1 * p

    def jac(t, q, p):
        return np.diag(k + 3 * k3 * q**2), 0.1 * np.eye(2)

    tip = UserComponent(0.3 * np.eye(2), force, jac, q0=[0.0, 0.0], p0=[0.0, 0.2], name="tip")
    problem = ELDProblem(_strip(6), BAR, degree=1, dirichlet={"left": _zero}, T=0.5)
    system = CoupledProblem(problem, [tip], [Translation("right", tip)])
    res = uniform_run(system, 0.01, scheme="bdf2")
    assert res["stats"]["newton_iterations"] > res["n_steps"]
    assert res["stats"]["back_substitutions"] == 2 * 2 + res["n_steps"] + 1
    assert res["residual_components"].max() < 1e-9
    assert np.abs(res["balance"]).max() < 1e-12 * res["energy"][0]


def test_refusals_of_the_coupled_step():
    tip = PointMass(1.0)
    nonlinear = CoupledProblem(
        ELDProblem(_strip(4), BAR, damping=NonlinearDamping(), dirichlet={"left": _zero}),
        [tip],
        [Translation("right", tip)],
    )
    with pytest.raises(
        RotheInputError,
        match=r"^damping: got .*, must be linear for the "
        r"coupled step",
    ):
        CoupledStepSystem(nonlinear)
    curved = CoupledProblem(
        ELDProblem(_strip(4), BAR, dirichlet={"left": _zero}),
        [tip],
        [
            UserCoupling(
                "right",
                tip,
                lambda t, q, x: np.broadcast_to((q + q**2)[:, None], x.shape),
                lambda t, q, x: np.broadcast_to(np.diag(1 + 2 * q)[:, None, :], (2, x.shape[1], 2)),
            )
        ],
    )
    with pytest.raises(
        RotheInputError,
        match=r"^couplings: got 'a nonlinear coupling', must "
        r"be linear here",
    ):
        CoupledStepSystem(curved)
    with pytest.raises(RotheInputError, match=r"^tau: got 0\.3, must divide T = 1"):
        uniform_run(
            CoupledProblem(
                ELDProblem(_strip(4), BAR, dirichlet={"left": _zero}),
                [tip],
                [Translation("right", tip)],
            ),
            0.3,
        )


def test_the_example_of_docs_coupling_runs(capsys):
    import re
    from pathlib import Path

    doc = Path(__file__).resolve().parents[2] / "docs" / "coupling.md"
    code = re.search(r"```python\n(.*?)```", doc.read_text(), re.S).group(1)
    namespace: dict = {}
    exec(compile(code, str(doc), "exec"), namespace)  # noqa: S102 - our own documentation
    res, w = namespace["res"], namespace["w"]
    exact = bar_frequencies(1.0, 100.0, 1.0, area=0.25, right=Attachment.point_mass(0.25))
    assert np.min(np.abs(w - exact[0])) < 1e-6 * exact[0]
    assert np.abs(res["balance"]).max() < 1e-12 * res["energy"][0]
    assert "8.6033" in capsys.readouterr().out
