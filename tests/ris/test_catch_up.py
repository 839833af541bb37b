"""The catch-up rule of the residual controllers (issue 18, item 0) and the load cache.

On ris-front the scheme alternates steps that advance t (z lags behind the load) with
viscous-jump steps that catch z up; :class:`rothe.ris.controllers.CatchUp` sizes the step
after such a step as the rest of the catch-up plus the wanted advance of t.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from rothe.fem.adapt import SpaceAdaptivity
from rothe.ris import controllers
from rothe.ris.controllers import CatchUp, Order2Controller, RegimeController
from rothe.ris.examples import example_front
from rothe.ris.run import run_ris
from rothe.ris.summary import viscous_jumps

from .conftest import DIRECT
from .test_adapt import checked_steps  # noqa: F401  (the fixture)


def attempt(tau, step_norm, I1, I2, d0, d1, converged=True):
    """A step result as the controllers see it."""
    return SimpleNamespace(
        tau=tau,
        step_norm=step_norm,
        errors={"I1": I1, "I2": I2},
        dist_start=d0,
        dist_end=d1,
        converged=converged,
        code="ok",
    )


# a step that advanced t by 6e-4 and left the state unstable (dist 0.2 at its end), then the
# viscous-jump step that caught most of it up (dist 0.2 -> 0.02 over tau = 2e-3)
SLIP = attempt(1e-3, 4e-4, 7e-5, 2e-5, 0.005, 0.2)
JUMP = attempt(2e-3, 2e-3, 0.0, 8e-5, 0.2, 0.02)


def test_catch_up_sizes_the_step_after_a_jump_as_its_rest_plus_the_advance_of_t():
    rule = CatchUp()
    # after the slip step alone: no decay rate of dist measured yet
    assert rule.propose(SLIP, 1e-4, 0.9) is None
    assert rule.C_t == pytest.approx(7e-5 / 6e-4**2)
    step = rule.propose(JUMP, 1e-4, 0.9)
    kappa = (0.2 - 0.02) / 2e-3  # dist's decay per arclength on the jump step
    dt_star = 0.9 * math.sqrt(1e-4 / (7e-5 / 6e-4**2))  # Lemma 5.3's quotient in dt
    assert step == pytest.approx(0.02 / kappa + dt_star, rel=1e-12)
    assert step == pytest.approx(8.677e-4, rel=1e-3)


def test_catch_up_uses_the_slowest_decay_of_the_last_two_jump_steps():
    rule = CatchUp()
    rule.propose(SLIP, 1e-4, 0.9)
    rule.propose(JUMP, 1e-4, 0.9)  # kappa 90
    tail = attempt(1e-3, 1e-3, 0.0, 1e-6, 0.02, 0.01)  # kappa 10: the flat end of the jump
    dt_star = 0.9 * math.sqrt(1e-4 / rule.C_t)
    assert rule.propose(tail, 1e-4, 0.9) == pytest.approx(0.01 / 10 + dt_star, rel=1e-12)


def test_catch_up_never_proposes_more_than_one_jump_step_can_go_within_tol():
    rule = CatchUp()
    rule.propose(SLIP, 1e-4, 0.9)
    # a jump step whose own residual is large: I2 = 8e-5 at tau 2e-3, so C3 = 1e4 and one jump
    # step within tol is 0.9 (1e-4 / 1e4)^(1/3) = 1.94e-2; a big lag (dist 10 at the end) would
    # ask for 10 / 90 = 0.11
    far = attempt(2e-3, 2e-3, 0.0, 8e-5, 10.2, 10.0)
    assert rule.propose(far, 1e-4, 0.9) == pytest.approx(0.9 * (1e-4 / 1e4) ** (1 / 3))


def test_catch_up_says_nothing_at_a_stable_end_or_without_measures():
    rule = CatchUp()
    rule.propose(SLIP, 1e-4, 0.9)
    rule.propose(JUMP, 1e-4, 0.9)
    stable = attempt(1e-3, 3e-4, 5e-5, 1e-5, 0.01, 0.0)  # the state is stable at its end
    assert rule.propose(stable, 1e-4, 0.9) is None
    assert rule.propose(attempt(1e-3, 3e-4, 5e-5, 1e-5, math.nan, math.nan), 1e-4, 0.9) is None


def test_order2_after_a_jump_step_proposes_the_catch_up_and_its_checkpoint_keeps_it():
    c = Order2Controller(1e-4, 1e-3)
    assert c.decide(SLIP).accept
    d = c.decide(JUMP)
    assert d.accept and d.next_tau == pytest.approx(8.677e-4, rel=1e-3)
    # without the rule: C = max(8e-5 / 4e-6, 7e-5 / 1e-6) = 70, 0.9 sqrt(1e-4 / 70) = 1.08e-3
    plain = Order2Controller(1e-4, 1e-3)
    plain.decide(SLIP)
    plain._catch_up.propose = lambda *a: None
    assert plain.decide(JUMP).next_tau == pytest.approx(0.9 * math.sqrt(1e-4 / 70))
    again = Order2Controller(1e-4, 1e-3)
    again.restore_state(c.checkpoint_state())
    assert again._catch_up.state() == c._catch_up.state()
    nxt = attempt(1e-3, 1e-3, 0.0, 1e-6, 0.02, 0.01)
    assert again.decide(nxt).next_tau == c.decide(nxt).next_tau
    # a checkpoint written before the rule existed restores with the rule unprimed
    old = {k: v for k, v in c.checkpoint_state().items() if k != "catch_up"}
    fresh = Order2Controller(1e-4, 1e-3)
    fresh.restore_state(old)
    assert fresh._catch_up.kappa == [] and fresh._catch_up.C_t == 0.0


def test_regime_after_a_jump_step_aims_the_catch_up_at_theta_tol():
    c = RegimeController(1e-4, 1e-3)
    c.propose(0.0)
    c.decide(SLIP)
    d = c.decide(JUMP)
    dt_star = math.sqrt(0.5e-4 / (7e-5 / 6e-4**2))  # theta tol, no safety factor
    guided = 0.02 / 90 + dt_star
    # the floor behind (5.7) still applies: max(guided, min(4 tau, 1/2 sqrt(theta tol / C2)))
    C2 = max(8e-5 / 2e-3**2, 0.0)
    assert d.next_tau == pytest.approx(max(guided, min(4 * 2e-3, 0.5 * math.sqrt(0.5e-4 / C2))))
    again = RegimeController(1e-4, 1e-3)
    again.restore_state(c.checkpoint_state())
    assert again._catch_up.state() == c._catch_up.state()


def test_the_front_with_a_residual_control_on_changing_meshes_reaches_T_in_bounded_steps(
    checked_steps,  # noqa: F811
):
    """A coarse ris-front (6 x 6, T = 0.25, order2 at tol 1e-3, changing meshes): every accepted
    step is KKT-exact on its mesh, T is reached, and steps, rejections and viscous jumps stay
    bounded: measured 259 accepted, 67 rejected, 8 jumps, 2 mesh changes; without the
    catch-up rule 453, 214 and 80 (25 mesh changes)."""
    options = SpaceAdaptivity(space_tol=3.0, adapt_every=4, refine_band=0.08, max_dofs=400)
    p = example_front(6, T=0.25, quadrature="consistent")
    r = run_ris(p, controllers.Order2(1e-3, tau=0.02), inner=DIRECT, adapt=options)
    st = r.statistics
    assert r.state.t == pytest.approx(0.25, abs=1e-10)
    assert checked_steps["steps"] == st.accepted_steps == len(r.trajectory)
    assert r.trajectory.meta["space_adaptations"] >= 2
    assert len(checked_steps["mesh_ids"]) >= 2  # the steps ran on several meshes
    assert r.trajectory.meta["max_recoarsened"] <= 2
    assert st.accepted_steps <= 320
    assert st.rejected_steps <= 100
    assert len(viscous_jumps(r.trajectory)) <= 20


def test_the_load_is_kept_read_only_and_equals_a_fresh_evaluation():
    p = example_front(4, T=0.2)
    a = p.load(0.1)
    assert p.load(0.1) is a and not a.flags.writeable
    assert np.array_equal(a, p._load_uncached(0.1))
    for t in (0.01, 0.02, 0.03, 0.04):  # the cache keeps the last four
        p.load(t)
    assert p.load(0.1) is not a and np.array_equal(p.load(0.1), a)
    # a load function that hands back its own array: that array stays writable
    from rothe.ris.problem import RISProblem

    l0 = np.ones(3)
    q = RISProblem(
        A=np.eye(3),
        F=lambda z: 0.5 * float(z @ z),
        dF=lambda z: z,
        d2F=lambda z: np.ones(3),
        load=lambda t: l0,
        dissipation_weights=np.ones(3),
        metric_weights=np.ones(3),
        z0=np.zeros(3),
        T=1.0,
    )
    q.load(0.0)
    assert l0.flags.writeable
