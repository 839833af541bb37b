"""run_coupled: the coupled step on the shared evolve loop: uniform steps (all accepted, the
ledger closes), adaptive steps (the error against a fine reference follows
tol, the whole-system ledger closes on variable steps), a nonlinear component whose Newton
fails is a rejected step, refusals."""

import numpy as np
import pytest

from rothe.eld import BDF2, ELDProblem, ImplicitEuler, Original, Regularized
from rothe.eld.components import UserComponent
from rothe.eld.coupled_run import run_coupled
from rothe.eld.coupling import CoupledProblem, Translation
from rothe.errors import RotheInputError, RunFailed
from rothe.stepping.controllers import Adaptive, Given, Uniform

from .test_coupled_step import BAR, _shaken_tip, _strip, _zero, uniform_run

pytestmark = pytest.mark.filterwarnings("ignore:G_d")

SCHEMES = {"euler": ImplicitEuler(), "bdf2": BDF2()}
FORMS = {"regularized": Regularized(), "original": Original()}


@pytest.mark.parametrize("scheme", ["euler", "bdf2"])
@pytest.mark.parametrize("form", ["regularized", "original"])
def test_uniform_steps_are_all_accepted_and_the_ledger_closes(scheme, form):
    system = _shaken_tip(controllers=True, T=0.2)
    res = run_coupled(system, scheme=SCHEMES[scheme], form=FORMS[form], control=Uniform(0.01))
    tr = res.trajectory
    assert tr.stats.accepted_steps == 20 and tr.stats.rejected_steps == 0
    np.testing.assert_allclose(tr["t"], 0.01 * np.arange(21), rtol=0, atol=1e-14)
    assert np.abs(tr["balance"]).max() < 1e-12 * np.abs(tr["energy"]).max()
    assert np.abs(tr["work_controllers"]).max() > 0  # the controllers act
    # the coupling holds at every accepted state (both forms: the trace is lifted from q)
    assert tr["constraint"].shape == (21,) and tr["constraint"].max() < 1e-14
    # the reaction on the tie acts on the tip: its trajectory is recorded too
    assert tr["reaction_right"].shape == (21, 2)
    assert np.abs(tr["reaction_right"]).max() > 0


@pytest.mark.parametrize("scheme", ["euler", "bdf2"])
def test_adaptive_steps_error_follows_tol_and_the_ledger_closes(scheme):
    system = _shaken_tip(T=0.5)
    fine = uniform_run(system, 0.5 / 2560, scheme="bdf2")
    q_ref, u_ref = fine["q"][-1], fine["u"]
    errs, steps = [], []
    for tol in (1e-2, 1e-3):
        res = run_coupled(system, scheme=SCHEMES[scheme], control=Adaptive(tol, tau=0.01))
        tr = res.trajectory
        assert tr["t"][-1] == 0.5
        taus = tr["tau"]
        assert taus.max() / taus.min() > 1.5  # the steps do vary
        scale = max(np.abs(tr["energy"]).max(), np.abs(tr["work_prescribed"]).max())
        assert np.abs(tr["balance"]).max() < 1e-11 * scale  # variable steps: still round-off
        assert tr["local_error"].max() <= tol
        errs.append(
            max(
                np.abs(tr["q"][-1] - q_ref).max() / np.abs(q_ref).max(),
                np.abs(res.state.u - u_ref).max() / np.abs(u_ref).max(),
            )
        )
        steps.append(tr.stats.accepted_steps)
    # local error ~ tau^(p+1) held at tol: tau ~ tol^(1/(p+1)), global error ~ tol^(p/(p+1)),
    # a ten times smaller tol divides it by 10^(p/(p+1)) (3.2 Euler, 4.6 BDF2): 3/4 of that
    p = SCHEMES[scheme].order
    print(scheme, "errors", errs, "steps", steps)
    assert errs[0] / errs[1] > 0.75 * 10 ** (p / (p + 1)) and steps[1] > steps[0]
    assert errs[1] < {"euler": 2e-2, "bdf2": 5e-3}[scheme]


def test_failed_newton_of_a_nonlinear_component_is_a_rejected_step():
    """A stiff cubic spring whose Jacobian is wrong (1e8 I) for a while, so that Newton on
    the border does not converge in 30 iterations: on uniform steps the run stops with
    RunFailed, never accepting that step; the adaptive run rejects it and goes on."""
    k, k3 = 30.0, 3e5

    def force(t, q, p):
        return k * q + k3 * q**3

    calls = {"n": 0}

    def jac(t, q, p):
        calls["n"] += 1
        J = np.diag(k + 3 * k3 * q**2)
        if 4 < calls["n"] < 40:  # a Jacobian gone wrong for a while: Newton crawls
            J = 1e8 * np.eye(2)
        return J, np.zeros((2, 2))

    def make():
        calls["n"] = 0
        tip = UserComponent(
            0.3 * np.eye(2), force, jac, q0=[0.0, 0.0], p0=[0.0, 0.2], name="tip", check=False
        )
        problem = ELDProblem(_strip(4), BAR, degree=1, dirichlet={"left": _zero}, T=0.1)
        return CoupledProblem(problem, [tip], [Translation("right", tip)])

    with pytest.raises(RunFailed, match="component Newton did not converge"):
        run_coupled(make(), scheme=BDF2(), control=Uniform(0.01))
    res = run_coupled(make(), scheme=BDF2(), control=Adaptive(1e-3, tau=0.01))
    assert res.trajectory.stats.rejected_steps >= 1
    assert res.trajectory["t"][-1] == 0.1
    assert np.all(res.trajectory["residual_components"] < 1e-9)


def test_refusals_of_run_coupled():
    system = _shaken_tip(T=0.2)
    with pytest.raises(RotheInputError, match="^tau: got 0.03, must divide T"):
        run_coupled(system, control=Uniform(0.03))
    with pytest.raises(RotheInputError, match="^control: got 'Given', must be Uniform"):
        run_coupled(system, control=Given([0.1, 0.1]))
    with pytest.raises(RotheInputError, match="^scheme: "):
        run_coupled(system, scheme="bdf2", control=Uniform(0.01))
    refused = "^system: got 'ELDProblem', must be a rothe.eld.CoupledProblem"
    with pytest.raises(RotheInputError, match=refused):
        run_coupled(system.body, control=Uniform(0.01))


def test_run_coupled_takes_the_keywords_of_run_coupled_many():
    """One keyword list (run_coupled_many's): run_coupled's signature derives from it, so
    help() and inspect show every keyword of both; one it does not take, or ``results``, is
    a TypeError before anything runs."""
    import inspect

    from rothe.eld.coupled_run import run_coupled_many

    mine = inspect.signature(run_coupled).parameters
    many = inspect.signature(run_coupled_many).parameters
    assert list(mine) == ["system"] + [k for k in many if k not in ("systems", "results")]
    assert all(mine[k].default is many[k].default for k in mine if k != "system")
    assert "adapt" in str(inspect.signature(run_coupled)) and "fields :" in run_coupled.__doc__
    system = _shaken_tip(degree=1, nx=2, T=0.02)
    for bad in ({"results": {}}, {"tol": 1e-3}):
        with pytest.raises(TypeError, match=f"unexpected keyword argument '{next(iter(bad))}'"):
            run_coupled(system, control=Uniform(0.01), **bad)
    res = run_coupled(system=system, control=Uniform(0.01))
    assert res.trajectory["t"][-1] == pytest.approx(0.02)
