"""Space adaptivity of coupled runs (run_coupled(..., adapt=SpaceAdaptivity(...))): the mesh
changes, the whole-system ledger closes with its transfer term, the coupling holds at every
accepted state on its own mesh, action = reaction on the last mesh, a configuration that
never refines is the fixed-mesh run bit for bit, refusals."""

import numpy as np
import pytest

from rothe.eld import BDF2, ImplicitEuler, Original, Regularized
from rothe.eld.bodies import run_bodies
from rothe.eld.coupled_run import CoupledStepper, run_coupled
from rothe.errors import RotheInputError
from rothe.fem.adapt import SpaceAdaptivity
from rothe.stepping.controllers import Adaptive, Uniform

from .test_coupled_step import _shaken_tip

pytestmark = pytest.mark.filterwarnings("ignore:G_d")

SCHEMES = {"euler": ImplicitEuler(), "bdf2": BDF2()}
FORMS = {"regularized": Regularized(), "original": Original()}


def _adapt(tol=1e-3):
    return SpaceAdaptivity(space_tol=tol, adapt_every=1, max_dofs=3000)


def _final_constraint(res):
    """max |S u - g_k(T) - Gamma q| / max(1, max|u|) of the final state on the final mesh."""
    st, s = res.stepper, res.state
    (gk,) = st.system.known_data(s.t, derivatives=False)
    err = s.u[st.c.dofs] - gk - st.kern.Gamma @ s.q
    return np.abs(err).max() / max(1.0, np.abs(s.u).max())


def _check(res):
    tr = res.trajectory
    scale = max(np.abs(tr["energy"]).max(), np.abs(tr["work_prescribed"]).max())
    assert len(set(tr["mesh_id"].tolist())) >= 3  # the mesh does change
    assert tr["ndofs"].max() > tr["ndofs"][0]
    assert len(res.meshes.adaptations) >= 2
    assert abs(tr["transfer"][-1]) > 0  # a transfer term that is booked, not zero
    assert np.abs(tr["balance"]).max() <= 1e-10 * scale  # the ledger closes with it
    # the coupling at every accepted state on its own mesh, and after the last transfer
    assert tr["constraint"].max() <= 1e-10
    assert res.state.mesh_id == tr["mesh_id"][-1]
    assert _final_constraint(res) <= 1e-12
    # action = reaction on the last mesh: the generalized force on the tip is minus the
    # reaction of the multiplier on its part, and the component equation with it holds
    st, lam = res.stepper, res.state.lam
    gen = st.system.generalized_reaction(lam)
    reaction = st.c.reactions(lam)["right"]
    assert np.abs(gen[:2] + reaction).max() <= 1e-12 * max(np.abs(reaction).max(), 1e-300)
    assert np.abs(reaction).max() > 0
    assert tr["residual_components"].max() < 1e-9 and tr["residual_body"].max() < 1e-9


@pytest.mark.parametrize("scheme", ["euler", "bdf2"])
@pytest.mark.parametrize("form", ["regularized", "original"])
def test_adaptive_mesh_uniform_steps(scheme, form):
    system = _shaken_tip(degree=1, nx=6, controllers=True, T=0.1)
    res = run_coupled(
        system, scheme=SCHEMES[scheme], form=FORMS[form], control=Uniform(0.01), adapt=_adapt()
    )
    assert res.trajectory["t"][-1] == pytest.approx(0.1)
    _check(res)
    assert np.abs(res.trajectory["work_controllers"]).max() > 0  # the controllers act


def test_adaptive_mesh_adaptive_steps_regularized_harmonic():
    system = _shaken_tip(degree=1, nx=6, T=0.1)
    res = run_coupled(
        system,
        scheme=BDF2(),
        form=Regularized(lifting="harmonic"),
        control=Adaptive(3e-3, tau=0.01),
        adapt=_adapt(),
    )
    assert res.trajectory["t"][-1] == 0.1
    _check(res)
    assert res.trajectory["local_error"].max() <= 3e-3


def _watch_accepted_states(monkeypatch) -> list:
    """Action = reaction at every accepted state, on its own mesh: the adapt step is called
    with each accepted state before the mesh changes; returns the list it fills with
    (generalized reaction on the tip + the multiplier's resultant on 'right', resultant)."""
    seen = []
    adapt = CoupledStepper.adapt

    def watched(self, state, result):
        assert state.mesh_id == self.adaptivity.mesh_id  # the stepper is on the state's mesh
        reaction = self.c.reactions(state.lam)["right"]
        seen.append((self.system.generalized_reaction(state.lam)[:2] + reaction, reaction))
        return adapt(self, state, result)

    monkeypatch.setattr(CoupledStepper, "adapt", watched)
    return seen


@pytest.mark.parametrize(
    "scheme,form,control,tol,every",
    [
        ("euler", "regularized", Uniform(0.01), 1e-3, 1),
        # adaptive steps: steps rejected after their mesh was refined go back to their start
        # state's mesh
        ("bdf2", "original", Adaptive(1e-2, tau=0.01), 3e-4, 2),
    ],
)
def test_in_step_refinement_rounds(monkeypatch, scheme, form, control, tol, every):
    """A step whose own estimate exceeds space_tol (1.3 space_tol after the first) is solved
    again on its refined mesh (run_eld's rounds, ELDAdaptivity.refine_in_step): the rounds
    happen, each such step solved more than once (its dofs summed over the solves exceed its
    start mesh's), the ledger closes with the transfers of the start states, the coupling
    and action = reaction hold at every accepted state."""
    seen = _watch_accepted_states(monkeypatch)
    system = _shaken_tip(degree=1, nx=6, controllers=True, T=0.1)
    adapt = SpaceAdaptivity(space_tol=tol, adapt_every=every, max_dofs=3000)
    res = run_coupled(
        system, scheme=SCHEMES[scheme], form=FORMS[form], control=control, adapt=adapt
    )
    tr = res.trajectory
    assert tr["t"][-1] == pytest.approx(0.1)
    rounds = np.asarray(tr["step_refinements"])
    assert rounds.sum() >= 3
    assert np.all(tr["step_bisections"][rounds > 0] > 0)
    assert np.all(tr["step_bisections"][rounds == 0] == 0)
    assert np.all(tr["step_dofs"][rounds > 0] > tr["ndofs"][:-1][rounds > 0])
    assert np.all(tr["step_dofs"][rounds == 0] == tr["ndofs"][:-1][rounds == 0])
    if isinstance(control, Adaptive):
        assert tr.stats.rejected_steps > 0
    _check(res)
    assert len(seen) == len(tr["t"]) - 1
    worst = max(np.abs(gap).max() / max(np.abs(reaction).max(), 1e-300) for gap, reaction in seen)
    assert worst <= 1e-12


def test_original_form_implicit_euler_adaptive_steps_go_on_after_a_mesh_change():
    """Original form, implicit Euler, adaptive steps and mesh: the first mesh change (after
    step 100, t = 0.111) makes the controller cut tau ~55-fold (the new mesh's modes). Before
    the transfer restarted the boundary velocity from G_dot(t_j) (as at t = 0), the quotient
    of the previous step lagged by tau_{j-1} G''/2 and the estimate stayed at 2.7e-3 > tol for
    every tau down to tau_min (RunFailed). Now the run goes on as the regularized one does:
    the same cut, every step below tol, the final state within 1 % of the regularized run's."""
    runs = {}
    for name in ("original", "regularized"):
        system = _shaken_tip(degree=1, nx=6, controllers=True, T=0.13)
        runs[name] = run_coupled(
            system,
            scheme=ImplicitEuler(),
            form=FORMS[name],
            control=Adaptive(1e-3, tau=0.01),
            adapt=SpaceAdaptivity(space_tol=3e-3, adapt_every=1, max_dofs=3000),
        ).trajectory
    tr, ref = runs["original"], runs["regularized"]
    assert tr["t"][-1] == pytest.approx(0.13)
    changes = np.flatnonzero(np.diff(tr["mesh_id"]))
    assert changes.size >= 1 and tr["t"][changes[0] + 1] > 0.11
    assert tr["local_error"].max() <= 1e-3
    after = tr["tau"][changes[0] + 1 :]
    assert after.min() > 1e-2 * tr["tau"][changes[0]]  # (before: down to tau_min, 1.3e-11)
    assert np.abs(tr["balance"]).max() <= 1e-12 * np.abs(tr["energy"]).max()
    assert tr["constraint"].max() <= 1e-12
    assert abs(tr["energy"][-1] - ref["energy"][-1]) <= 1e-2 * ref["energy"][-1]
    assert np.abs(tr["q"][-1] - ref["q"][-1]).max() <= 1e-2 * np.abs(ref["q"][-1]).max()


def test_a_mesh_that_never_changes_is_the_fixed_mesh_run():
    system = _shaken_tip(degree=1, nx=6, controllers=True, T=0.1)
    fixed = run_coupled(system, scheme=BDF2(), control=Uniform(0.01)).trajectory
    system = _shaken_tip(degree=1, nx=6, controllers=True, T=0.1)
    res = run_coupled(
        system,
        scheme=BDF2(),
        control=Uniform(0.01),
        adapt=SpaceAdaptivity(space_tol=1e9, adapt_every=1),
    )
    tr = res.trajectory
    assert set(tr["mesh_id"].tolist()) == {0} and res.meshes.adaptations == []
    assert np.all(np.isfinite(tr["space_estimate"][:-1]))  # estimated, and nothing changed
    for key in ("q", "p", "z", "energy", "balance", "constraint", "lam_norm", "reaction_right"):
        np.testing.assert_array_equal(tr[key], fixed[key], err_msg=key)
    assert np.all(tr["transfer"] == 0.0)


def test_refusals_with_space_adaptivity():
    system = _shaken_tip(degree=1, nx=6, T=0.1)
    ok = SpaceAdaptivity(space_tol=1e-2)
    with pytest.raises(RotheInputError, match="^adapt: got dict, must be a rothe.fem.adapt"):
        run_coupled(system, control=Uniform(0.01), adapt={"space_tol": 1e-2})
    watch = np.zeros((1, system.body.space.ndofs))
    with pytest.raises(RotheInputError, match="^watch: got given, is not supported with"):
        run_coupled(system, control=Uniform(0.01), adapt=ok, watch=watch)
    with pytest.raises(RotheInputError, match="^noise: .* not supported with space adaptivity"):
        run_coupled(system, control=Uniform(0.01), adapt=ok, noise=lambda j: (None, None, None))


def test_glued_bodies_with_an_adaptive_base():
    """Two P1 strips glued with matching nodes, the base (clamped, soft) adaptive: the run
    reaches T on several meshes, the glue turns mortar once the base's interface facets are
    refined, the interface holds at every accepted state and on the last mesh (S u_1 =
    Pi S u_2 by the last glue), the multiplier's resultants on the two bodies cancel and the
    whole-system ledger closes."""
    from .test_bodies import SOFT, STIFF, two_bodies

    glued = two_bodies(SOFT, STIFF, n=2, ny=(1, 1))
    assert glued.interfaces[0].method == "matching"
    res = run_bodies(
        glued,
        fields=False,
        scheme=BDF2(),
        control=Uniform(0.01),
        adapt=SpaceAdaptivity(space_tol=2e-3, adapt_every=2, max_dofs=4000),
    )
    tr = res.trajectory
    assert tr["t"][-1] == pytest.approx(0.5)
    assert len(set(tr["mesh_id"].tolist())) >= 3
    assert np.abs(tr["balance"]).max() <= 1e-10 * np.abs(tr["energy"]).max()
    assert tr["constraint"].max() <= 1e-10
    st, s = res.stepper, res.state
    glue = st.system.couplings[0]
    assert glue.interface.method == "mortar" and glue.interface.requested == "auto"
    comp = glued.components[0]
    d = 2
    pos = st.c.part_positions["right"]
    rows = (d * pos[:, None] + np.arange(d)).ravel()
    u1 = s.u[st.c.dofs][rows]
    u2 = glue.interface.project(comp.field(s.q))
    assert np.abs(u1 - u2).max() <= 1e-12 * np.abs(u2).max()
    # action = reaction through the last glue: -B^T lambda on the base, +Gamma^T M_G lambda on
    # body 2, lambda restricted to the interface
    lam = np.zeros_like(s.lam)
    lam[rows] = s.lam[rows]
    f1 = -(st.c.B.T @ lam)
    f2 = comp.E @ st.system.generalized_reaction(lam)
    s1, s2 = f1.reshape(-1, 2).sum(axis=0), f2.reshape(-1, 2).sum(axis=0)
    assert np.abs(s1).max() > 1e-3
    assert np.abs(s1 + s2).max() <= 1e-12 * np.abs(s1).max()
