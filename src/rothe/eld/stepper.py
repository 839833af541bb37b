"""One step of implicit Euler (3.4) or variable-step BDF2 for the elastodynamic operator DAE.

:class:`ELDStepper` does one step at a time for the shared evolve loop
(:func:`rothe.stepping.evolve.evolve`): the scheme (:mod:`rothe.eld.scheme`) in either form
(:mod:`rothe.eld.form`) on the linear system of the current mesh (:mod:`rothe.eld.system`), with
the data of the step (:mod:`rothe.eld.data`), Newton's method for nonlinear damping, the new
state with its energy ledger (:mod:`rothe.eld.state`) and its local error estimate; the adapt
step after an accepted step (space adaptivity, :mod:`rothe.eld.adapt`); the record of an
accepted step; checkpoints. It never decides acceptance (the controller does).

A step in the scheme's unknown x^j (u_1 regularized, u original): with the history terms
h_x = alpha_1 x^{j-1} + alpha_2 x^{j-2} and h_y, y^j = (alpha_0 x^j + h_x)/tau_j and
b^j = (alpha_0 y^j + h_y)/tau_j, so the step operator is A(tau_eff) with tau_eff =
tau_j/alpha_0 (:mod:`rothe.eld.system`). With linear damping a step is one linear solve; with
nonlinear damping Newton's method with backtracking (:class:`NewtonOptions`).

**Local error estimate** (``result.errors['local_error']``, for adaptive steps). The
trapezoidal residuals of the step, r_x = x^j - x^{j-1} - tau/2 (y^j + y^{j-1}) and
r_y = y^j - y^{j-1} - tau/2 (b^j + b^{j-1}), times c(omega) (:meth:`Scheme.estimate_factor`),
measured in the energy norm relative to the largest energy norm seen so far,

    local_error = c(omega) (r_x.K r_x + rho r_y.M r_y)^{1/2} / S_j,
    S_j = max(error_scale, max_{k<=j} (u^k.K u^k + rho v^k.M v^k)^{1/2})

(x, y, b are the scheme's unknowns: u_1, its velocity and acceleration in the regularized form;
u, v, a in the original form; with differenced data and the harmonic lifting u, v, a with their
Gamma_D values set to zero, since the lifted difference quotients of G jump after a step cut by
an amount no smaller step removes). The floor ``error_scale`` (:func:`rothe.eld.start.data_scale`
by default) keeps a run that starts at rest from resolving exponentially small signals
relatively. It needs only the current and the previous step, so it is exact for variable steps
and after rejections.

Steps: :class:`~rothe.stepping.controllers.Uniform` (n = T/tau equal steps; tau must divide T),
:class:`~rothe.stepping.controllers.Given` (a sequence summing to T; BDF2 ratios below
1 + sqrt(2)), :class:`~rothe.stepping.controllers.Adaptive` (the first step ``tau``, default
0.01); uniform steps and given sequences are checked against Lemma 3.2 before the first step,
the adaptive controller keeps tau_j/alpha_0 below :data:`~rothe.eld.scheme.BOUND_SAFETY`
rho/d0 (:class:`StepGrid`, shared with the PETSc backend :mod:`rothe.eld.distributed`, as are
:func:`history_terms` and :func:`kinematics`).

**Checkpoints.** :meth:`ELDStepper.checkpoint_state` returns a dict of arrays and plain values
(the state with its products, the ledger, the error scale, the solver's counters and the key of
the stored factorization: the effective step and, for nonlinear damping, the velocity of the
Jacobian it factors; with space adaptivity the mesh hierarchy, the series of meshes, the kept
fields and the log of adaptations); :meth:`ELDStepper.restore_state` rebuilds the state and
refactors from that key, so a resumed run continues bit for bit (single-threaded BLAS).

A step whose solve fails, or whose state or data is not finite, is never accepted.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np
import scipy.sparse.linalg as spla

from ..errors import (
    RotheInputError,
    RunFailed,
    check_instance,
    check_int,
    check_positive,
    described,
    fail,
)
from ..io.trajectory import Trajectory
from ..stepping import interrupt
from ..stepping.controllers import Adaptive, Given, Uniform
from ..stepping.evolve import single_threaded_blas
from ..timing import PhaseTimes
from .adapt import ELDAdaptivity, check_adapt
from .constraint import HarmonicLifting
from .data import DEFAULT_DATA, DataMode, Differenced, as_data_mode
from .form import DEFAULT_FORM, Form, Regularized, as_form
from .problem import ELDProblem
from .scheme import BOUND_SAFETY, DEFAULT_SCHEME, Scheme, as_scheme
from .solvers import SolveFailed, SolverStats
from .start import data_scale, initial_state, with_prehistory
from .state import ELDCode, ELDState, ELDStepResult, EnergyLedger
from .system import ELDSystem

#: the step of a run that names no control (equal steps), and the first step of adaptive
#: control when ``Adaptive(tol)`` gives none
DEFAULT_FIRST_STEP = 0.01
#: the step control of a run that names none
DEFAULT_CONTROL = Uniform(DEFAULT_FIRST_STEP)
#: the checkpoint format of :meth:`ELDStepper.checkpoint_state`
CHECKPOINT_FORMAT = "rothe-eld-state-2"


@dataclass
class NewtonOptions:
    """Newton's method for nonlinear damping.

    Stop when the (estimated) error of the iterate is below ``tol`` times the size of the
    unknown, after at most ``max_iter`` iterations. The Newton corrections are solved to the
    relative residual ``krylov_rtol`` (inexact Newton: the iteration then contracts by about
    that factor, and the stopping test still asks for ``tol``).

    Parameters
    ----------
    tol : float > 0
    max_iter : int >= 1
    krylov_rtol : float > 0
    """

    tol: float = 1e-10
    max_iter: int = 25
    krylov_rtol: float = 1e-4

    def __post_init__(self):
        self.tol = check_positive("newton tol", self.tol)
        self.krylov_rtol = check_positive("newton krylov_rtol", self.krylov_rtol)
        if int(self.max_iter) < 1:
            raise fail("newton max_iter", self.max_iter, "must be >= 1")


class NewtonFailed(Exception):
    """Newton's method stopped without converging (``iterations`` done, residual ``rnorm``)."""

    def __init__(self, iterations: int, rnorm: float):
        super().__init__(f"{iterations} iterations, |R| = {rnorm:.3g}")
        self.iterations = iterations
        self.rnorm = rnorm


def newton(residual, correction, z0, z_prev, options: NewtonOptions, norm=np.linalg.norm):
    """Newton's method with backtracking on |R|; returns ``(z, aux, iterations)`` or raises
    :class:`NewtonFailed`. The one copy both steppers use (the PETSc backend passes a global
    ``norm``).

    ``residual(z)`` returns ``(R, aux)`` and ``correction(R, aux)`` the Newton correction dz
    (J dz = -R, J the Jacobian at the iterate ``aux`` describes). A correction is damped,
    alpha = 1, 1/2, ..., until |R(z + alpha dz)| <= (1 - 1e-4 alpha) |R(z)| (or alpha < 1/64).
    Stops when the estimated error of the iterate, |dz| theta / (1 - theta) with the
    contraction theta = |dz_k| / |dz_{k-1}| (or |dz| itself in the first iteration and after
    a damped one), is below ``options.tol`` * max(|z|, |z - z_prev|).
    """
    z = z0.copy()
    R, aux = residual(z)
    rnorm = norm(R)
    prev_step = None
    for it in range(1, options.max_iter + 1):
        if rnorm == 0.0:
            return z, aux, it - 1
        if not math.isfinite(rnorm):
            raise NewtonFailed(it - 1, rnorm)
        dz = correction(R, aux)
        alpha = 1.0
        while True:
            z_new = z + alpha * dz
            R_new, aux_new = residual(z_new)
            r_new = norm(R_new)
            if r_new <= (1.0 - 1e-4 * alpha) * rnorm or alpha < 1.0 / 64:
                break
            alpha *= 0.5
        step = alpha * norm(dz)
        z, R, aux, rnorm = z_new, R_new, aux_new, r_new
        scale = max(norm(z), norm(z - z_prev), 1e-300)
        if prev_step is not None and prev_step > 0 and alpha == 1.0:
            theta = step / prev_step
            estimate = step * theta / (1.0 - theta) if theta < 1.0 else math.inf
        else:
            estimate = step
        if estimate <= options.tol * scale or step == 0.0:
            return z, aux, it
        prev_step = step
    raise NewtonFailed(options.max_iter, float(rnorm))


def as_control(control):
    """``control`` if it is a step-control object of elastodynamics, else a one-line error."""
    return check_instance(
        "control",
        control,
        (Uniform, Given, Adaptive),
        "Uniform(tau), Given(steps) or Adaptive(tol, tau=...) (rothe.stepping.controllers)",
    )


def uniform_steps(tau: float, T: float, scheme: Scheme, bound: float) -> int:
    """The number of equal steps tau in [0, T]; refuses (naming ``tau``) a tau that the
    ``scheme`` cannot take under Lemma 3.2's ``bound`` (:meth:`ELDProblem.step_bound`) or that
    does not divide T. Also a check before runs start (:func:`rothe.eld.studies`): tau/2^k
    divides T when tau does, and the bound is hardest for the largest step."""
    scheme.check_step(tau, bound)
    ratio = T / tau
    n = round(ratio) if math.isfinite(ratio) and ratio < 2**62 else -1
    if n < 1 or abs(ratio - n) > 1e-9 * max(1.0, ratio):
        raise fail("tau", tau, f"must divide T = {T:g} into equal steps (T/tau = {ratio:.6g})")
    return int(n)


def history_terms(state: ELDState, coeffs) -> dict:
    """h_x = alpha_1 x^{j-1} + alpha_2 x^{j-2} and h_y, with their M and K products (module
    docstring), from the fields and products of ``state`` and the scheme's (alpha_0, alpha_1,
    alpha_2). The same on every process of the distributed backend (owned parts)."""
    _, a1, a2 = coeffs
    f, pr = state.fields, state.products
    h = {
        "x": a1 * f["x"],
        "Mx": a1 * pr["Mx"],
        "Kx": a1 * pr["Kx"],
        "y": a1 * f["y"],
        "My": a1 * pr["My"],
        "Ky": a1 * pr["Ky"],
    }
    if a2:
        for key, name in (("x", "x_1"), ("y", "y_1")):
            h[key] = h[key] + a2 * f[name]
        for key in ("Mx", "Kx", "My", "Ky"):
            h[key] = h[key] + a2 * pr[key + "_1"]
    return h


def kinematics(h, coeffs, tau, x, Mx, Kx, lifted, damping, with_nonlinear=True) -> dict:
    """y = (alpha_0 x + h_x)/tau, b = (alpha_0 y + h_y)/tau, u, v, a and their M and K products
    from the step's unknown ``x`` (with ``Mx``, ``Kx``) and the lifted data ``lifted`` =
    ((u2, -, K u2), (v2, M v2, K v2), (w2, M w2, -)) (u2 None: the original form, u = x), and
    the damping force D(v) of ``damping`` (its linear part, and N(v) unless
    ``with_nonlinear`` is False). Module docstring."""
    a0 = coeffs[0]
    (u2, _, Ku2), (v2, Mv2, Kv2), (w2, Mw2, _) = lifted
    k = {"x": x, "Mx": Mx, "Kx": Kx}
    k["y"] = (a0 * x + h["x"]) / tau
    k["My"] = (a0 * Mx + h["Mx"]) / tau
    k["Ky"] = (a0 * Kx + h["Kx"]) / tau
    k["b"] = (a0 * k["y"] + h["y"]) / tau
    k["Mb"] = (a0 * k["My"] + h["My"]) / tau
    if u2 is None:
        k["u"], k["Ku"], k["v"], k["Mv"], k["a"], k["Ma"] = (
            x,
            Kx,
            k["y"],
            k["My"],
            k["b"],
            k["Mb"],
        )
        Kv = k["Ky"]
    else:
        k["u"], k["Ku"] = x + u2, Kx + Ku2
        k["v"], k["Mv"] = k["y"] + v2, k["My"] + Mv2
        k["a"], k["Ma"] = k["b"] + w2, k["Mb"] + Mw2
        Kv = k["Ky"] + Kv2
    D = damping
    Dv = D.mass_coef * k["Mv"] + D.stiffness_coef * Kv
    if D.matrix is not None:
        Dv = Dv + D.matrix @ k["v"]
    if with_nonlinear and not D.is_linear:
        Dv = Dv + D.nonlinear_apply(k["v"])
    k["Dv"] = Dv
    return k


def accepted_fields(k: dict, f: dict, pr: dict, u, v, Ku, Mv) -> tuple[dict, dict]:
    """The fields and products an accepted step keeps: the step's kinematics ``k``
    (:func:`kinematics`) with u, v, K u, M v as the step defines them, and the previous
    state's fields ``f`` and products ``pr`` as the ``_1`` history of BDF2 (module docstring).
    The same on every process of the distributed backend (owned parts)."""
    fields = {
        "x": k["x"],
        "x_1": f["x"],
        "y": k["y"],
        "y_1": f["y"],
        "b": k["b"],
        "u": u,
        "u_1": f["u"],
        "v": v,
        "v_1": f["v"],
        "a": k["a"],
    }
    products = {
        "Mx": k["Mx"],
        "Kx": k["Kx"],
        "Mx_1": pr["Mx"],
        "Kx_1": pr["Kx"],
        "My": k["My"],
        "Ky": k["Ky"],
        "My_1": pr["My"],
        "Ky_1": pr["Ky"],
        "Mb": k["Mb"],
        "Ku": Ku,
        "Mv": Mv,
    }
    return fields, products


class StepGrid:
    """The time grid of a run: the steps of ``control`` on [0, T] checked against Lemma 3.2
    and, for BDF2, zero-stability (module docstring); the times t_j, the test for the last
    step and the landing on T of adaptive steps. Shared by every stepper of elastodynamics
    (the serial one and :mod:`rothe.eld.distributed`).

    Parameters
    ----------
    control : Uniform, Given or Adaptive
    scheme : ImplicitEuler or BDF2
    T : float
        End time.
    bound : float
        The solvability bound rho/d0 (inf: none).

    Attributes
    ----------
    tau : float
        The (first) step.
    steps : ndarray or None
        A given sequence.
    n_steps : int or None
        The number of steps of a fixed grid (None: adaptive).
    """

    def __init__(self, control, scheme: Scheme, T: float, bound: float):
        self.control = control
        self.scheme = scheme
        self.T = T
        self.bound = bound
        self.steps = None
        self.tau_uniform = None
        if isinstance(control, Given):
            self.steps = self._check_steps(control.steps)
            self.tau = float(self.steps[0])
            self.n_steps = int(self.steps.size)
            times = np.cumsum(self.steps)
            times[-1] = T
            self._times = np.concatenate([[0.0], times])
            return
        if isinstance(control, Uniform):
            self.tau = tau = control.tau
            self.n_steps = uniform_steps(tau, T, self.scheme, self.bound)
            self.tau_uniform = tau
            return
        self.tau = tau = DEFAULT_FIRST_STEP if control.tau is None else control.tau
        if tau > T:
            raise fail("tau", tau, f"(the first step) must be <= T = {T:g}")
        self.n_steps = None
        self.scheme.check_step(tau, self.bound)  # the first step

    def _check_steps(self, steps) -> np.ndarray:
        """A given sequence (positive and finite: :class:`Given`) against T, the zero-stability
        of BDF2 and Lemma 3.2."""
        arr = np.asarray(steps, dtype=float).ravel()
        total = float(arr.sum())
        if abs(total - self.T) > 1e-10 * self.T:
            raise fail(
                "steps", described(f"steps summing to {total:.12g}"), f"must sum to T = {self.T:g}"
            )
        tau_prev = None
        limit = self.scheme.zero_stability
        for k, tau in enumerate(arr):
            if tau_prev is not None and math.isfinite(limit):
                ratio = tau / tau_prev
                if not ratio < limit:
                    raise fail(
                        "steps",
                        described(f"tau_{k + 1}/tau_{k} = {ratio:.6g}"),
                        f"must be < 1 + sqrt(2) = {limit:.6g} (zero-stability "
                        "of variable-step BDF2)",
                    )
            a0 = self.scheme.coefficients(tau, tau_prev)[0]
            if not tau / a0 < self.bound:
                raise fail(
                    "steps",
                    described(f"tau_{k + 1} = {tau:g}"),
                    f"must satisfy tau_j/alpha_j < rho/d0 = {self.bound:g} (alpha_j = "
                    f"{a0:.6g}; Lemma 3.2)",
                )
            tau_prev = tau
        return arr

    def time_after(self, state: ELDState, tau: float) -> float:
        """t_{j+1} after ``state`` with step ``tau``: on a fixed grid its j+1-st time (no
        accumulated round-off), else t_j + tau, snapped to T within a few ulps."""
        j = state.j + 1
        if self.tau_uniform is not None:
            return j * self.tau_uniform
        if self.steps is not None:
            return float(self._times[j])
        t = state.t + tau
        if abs(t - self.T) <= 4.0 * np.finfo(float).eps * max(1.0, self.T):
            t = self.T
        return t

    def finished(self, state: ELDState) -> bool:
        """The last step is done: n steps of a fixed grid, or t = T."""
        if self.n_steps is not None:
            return state.j >= self.n_steps
        return state.t >= self.T

    def max_step(self, tau_prev: float | None) -> float:
        """The adaptive controller's limit for the step after ``tau_prev``: the step whose
        effective step tau/alpha_0 is BOUND_SAFETY times the solvability bound
        (:meth:`Scheme.max_step`)."""
        return self.scheme.max_step(BOUND_SAFETY * self.bound, tau_prev)

    def limit(self, state: ELDState, tau: float) -> float:
        """Adaptive control: land on T (the last two steps split the rest evenly instead of
        leaving a sliver)."""
        if self.n_steps is not None:
            return tau
        rest = self.T - state.t
        if tau >= rest * (1.0 - 1e-12):
            return rest
        if tau < rest < 2.0 * tau:
            return 0.5 * rest
        return tau


class GridLoop:
    """The evolve-loop methods of a stepper on a :class:`StepGrid` (``self.grid``) that lands
    on T exactly: the last step, the controller's largest step, the landing. Used by every
    elastodynamics stepper (:class:`StepperBase`, the coupled one of
    :mod:`rothe.eld.coupled_run`)."""

    def finished(self, state: ELDState) -> bool:
        """The last step is done: n steps of a fixed grid, or t = T (:meth:`StepGrid.finished`)."""
        return self.grid.finished(state)

    def max_step(self, tau_prev: float | None) -> float:
        """The controller's limit for the step after ``tau_prev``: the step whose effective
        step tau/alpha_0 is BOUND_SAFETY times the solvability bound
        (:meth:`StepGrid.max_step`)."""
        return self.grid.max_step(tau_prev)

    def limit(self, state: ELDState, tau: float) -> float:
        """Adaptive control: land on T (:meth:`StepGrid.limit`)."""
        return self.grid.limit(state, tau)

    def overshoot(self, state, attempts):
        """Never: the grid (or :meth:`limit`) lands on T exactly."""
        return None

    def pick_landing(self, state, attempts):
        """The last attempt (no landing retries)."""
        return attempts[-1]


class StepperBase(GridLoop):
    """What every elastodynamics stepper shares: the serial :class:`ELDStepper` and the PETSc
    one (:mod:`rothe.eld.distributed`). The options and the time grid (:meth:`_set_common`),
    the evolve-loop methods of a :class:`StepGrid` that lands on T exactly, where a run is, and
    one step (:meth:`_try_step`): the step's checks (Lemma 3.2, BDF2's zero-stability), its
    data, the solve, a failed step's result, and the new state with its energy ledger and local
    error estimate (:meth:`_complete`, module docstring); the record of an accepted step
    (:meth:`_step_record`).

    The linear algebra is the backend's, through these methods:

    - ``_dots(pairs)``: the inner products a.b of ``pairs`` (on many processes: global sums);
    - ``_any(flag)``: whether ``flag`` holds on any process;
    - ``_mult(A, w)``: the product A w;
    - ``_start_data(tau, cubic)``, ``_split(w)``, ``_fill_products(state)``: what BDF2's start
      history needs (:func:`rothe.eld.start.with_prehistory`): the Gamma_D values of G_dot(0)
      and of (G_ddot(tau) - G_ddot(0))/tau, the scheme's unknown of a field, the cached
      products;
    - ``_values(j, state, t_new, coeffs)``: the data of step j (:class:`rothe.eld.data.StepValues`);
    - ``_nonfinite(vals)``: the name of the first datum with NaN or inf entries, or None;
    - ``_solve_step(state, vals, coeffs, tau)``: the step's kinematics (:func:`kinematics`,
      with ``lam`` in the original form's bordered solve) and its Newton iterations; raises
      :class:`~rothe.eld.solvers.SolveFailed` or :class:`NewtonFailed`;
    - ``_multiplier(k, vals)``: lambda and v on Gamma_D (in the constraint's order);
    - ``_linear_stats()``: the linear solver's counters (:class:`~rothe.eld.solvers.SolverStats`);
    - ``_result_system()``: the system a step result carries (None on many processes).

    and the attributes ``problem``, ``rho``, ``C`` (this process's constrained dofs), ``bpos``
    (their positions in the constraint's order), ``data_mode`` and ``_estimate_on_fields``.
    """

    _estimate_on_fields = False

    def _set_common(self, problem, newton, store_fields, keep_every, observer, error_scale) -> None:
        """The options both backends validate alike, the time grid and the bound of Lemma 3.2
        (after ``scheme``, ``form``, ``control`` and ``data_mode`` are set)."""
        if newton is not None and not isinstance(newton, NewtonOptions):
            raise fail(
                "newton", described(type(newton).__name__), "must be a rothe.eld.NewtonOptions"
            )
        self.newton = newton or NewtonOptions()
        self.store_fields = bool(store_fields)
        self.keep_every = check_int("keep_every", keep_every, minimum=1)
        self.observer = observer
        self.T = problem.T
        self.bound = problem.step_bound()
        self.order = self.scheme.order
        self.max_ratio = self.scheme.ratio_cap
        self.grid = StepGrid(self.control, self.scheme, self.T, self.bound)
        self.tau, self.steps, self.n_steps = self.grid.tau, self.grid.steps, self.grid.n_steps
        problem.check_initial_consistency()
        self.error_scale = (
            None if error_scale is None else check_positive("error_scale", error_scale)
        )
        self._last_newton = 0

    # -- evolve-loop interface ------------------------------------------------------------------
    def where(self, state: ELDState, result=None) -> dict:
        """Step, s, t, tau, form, scheme (and the Newton iterations of ``result``): where the
        run is, for messages and checkpoints."""
        info = {
            "step": state.j + 1,
            "s": state.t,
            "t": state.t,
            "tau": result.tau if result is not None else self.tau,
            "form": self.form.name,
            "scheme": self.scheme.name,
        }
        if result is not None:
            info["newton_iterations"] = result.newton_iterations
        return info

    # -- one step -------------------------------------------------------------------------------
    def _prehistory(self, state: ELDState, tau: float) -> ELDState:
        """The first state with BDF2's start history (:func:`rothe.eld.start.with_prehistory`
        on this stepper's linear algebra)."""
        return with_prehistory(self, state, tau)

    def _attempt(self, state: ELDState, tau: float) -> ELDStepResult:
        # overflow and NaN are detected in the result (a failed step), not reported as warnings
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return self._try_step(state, tau)

    def _failed(self, state, tau, code: ELDCode, message, its=0, counters=None) -> ELDStepResult:
        where = self.where(state)
        where.update(tau=tau, newton_iterations=its)
        return ELDStepResult(
            state=None,
            tau=tau,
            newton_iterations=its,
            converged=False,
            code=code,
            message=message,
            where=where,
            counters=counters or {},
            system=self._result_system(),
        )

    def _try_step(self, state: ELDState, tau: float) -> ELDStepResult:
        """One step of size ``tau`` from ``state``: a result with the new state, or a failed
        result (a solve failed, Newton did not converge, a field is not finite). Raises
        RunFailed for a step Lemma 3.2 or BDF2's zero-stability forbids, or non-finite data."""
        j = state.j + 1
        t_new = self.grid.time_after(state, tau)
        scheme = self.scheme
        if state.j == 0:
            scheme = self.scheme.first_step()
            if self.scheme.prehistory:
                state = self._prehistory(state, tau)
        coeffs = scheme.coefficients(tau, state.tau_prev)
        a0 = coeffs[0]
        limit = self.scheme.zero_stability
        if math.isfinite(limit) and state.j > 0 and not tau / state.tau_prev < limit:
            raise RunFailed(
                f"step {j}: tau/tau_prev = {tau / state.tau_prev:.6g} is beyond the "
                f"zero-stability limit 1 + sqrt(2) of variable-step BDF2",
                where=self.where(state),
            )
        if not tau / a0 < self.bound:
            raise RunFailed(
                f"step {j}: tau = {tau:g} violates tau/alpha_0 < rho/d0 = "
                f"{self.bound:g} (Lemma 3.2)",
                where=self.where(state),
            )
        vals = self._values(j, state, t_new, coeffs)
        bad = self._nonfinite(vals)
        if bad is not None:
            what = {
                "F": "the load F (body force, tractions)",
                "G": "the Dirichlet data G",
                "G_dot": "G_dot",
                "G_ddot": "G_ddot",
            }[bad]
            raise RunFailed(
                f"non-finite data at step {j} (t = {t_new:.6g}): {what} has NaN or inf entries",
                where=self.where(state),
            )
        st = self._linear_stats()
        before = (st.factorizations, st.backsolves, st.krylov_iterations)

        def counters():
            return {
                "newton_iterations": its,
                "linear_factorizations": st.factorizations - before[0],
                "linear_solves": st.backsolves - before[1],
                "krylov_iterations": st.krylov_iterations - before[2],
            }

        its = 0
        try:
            k, its = self._solve_step(state, vals, coeffs, tau)
        except SolveFailed as exc:
            return self._failed(
                state,
                tau,
                ELDCode.LINEAR_SOLVE,
                f"{ELDCode.LINEAR_SOLVE.message} at step {j} (t = {t_new:.6g}, "
                f"tau = {tau:g}): {exc}; the step is not accepted",
                its,
                counters(),
            )
        except NewtonFailed as exc:
            its = exc.iterations
            return self._failed(
                state,
                tau,
                ELDCode.NEWTON,
                f"{ELDCode.NEWTON.message} in {exc.iterations} "
                f"iterations at step {j} (t = {t_new:.6g}, tau = {tau:g}, |R| = "
                f"{exc.rnorm:.3g}); the step is not accepted",
                its,
                counters(),
            )
        self._last_newton = its
        new, result_extra = self._complete(state, k, vals, coeffs, tau, t_new, scheme)
        if new is None:
            return self._failed(
                state,
                tau,
                ELDCode.NON_FINITE,
                f"{ELDCode.NON_FINITE.message} at step {j} (t = {t_new:.6g}, "
                f"tau = {tau:g}): {result_extra} has NaN or inf entries; the "
                "step is not accepted",
                its,
                counters(),
            )
        return ELDStepResult(
            state=new,
            tau=tau,
            lam=new.lam,
            reactions=self.problem.constraint.reactions(new.lam),
            newton_iterations=its,
            estimate=result_extra,
            counters=counters(),
            system=self._result_system(),
        )

    def _guess(self, state: ELDState, tau: float) -> np.ndarray:
        """The first guess of the step's unknown (a new array): the Taylor polynomial of x at
        t_{j-1} from the scheme's derivatives y ~ x' and b ~ x'' of the state,

            x + tau y + c b,   c = tau^2/2                      (y exact or second order:
                                                                 the initial state, BDF2)
                               c = tau (tau + tau_{j-1})/2      (after an implicit Euler step,
                                                                 y = x' - tau_{j-1}/2 x'' + ...),

        off by O(tau^3) where the linear extrapolation x + tau/tau_{j-1} (x - x^{j-2}) is off by
        O(tau^2). Only the iterative solvers' start depends on it (and Newton's): on the P1 beam
        CG + AMG needs about 9 % fewer iterations per step (docs/scaling.md)."""
        f = state.fields
        after_euler = state.tau_prev is not None and self.scheme.order == 1
        c = 0.5 * tau * (tau + state.tau_prev) if after_euler else 0.5 * tau * tau
        guess = tau * f["y"]
        guess += f["x"]
        guess += c * f["b"]
        return guess

    # -- the new state: multiplier, ledger, estimate ---------------------------------------------
    def _complete(self, state: ELDState, k: dict, vals, coeffs, tau: float, t_new: float, scheme):
        """The state after the step, or (None, name) if a field is not finite.

        lambda from the Gamma_D rows of (3.4a) (or the bordered solve); the ledger's terms
        (rothe.eld.state) and the local error estimate (module docstring), every inner product
        through ``_dots`` (one global sum per step on many processes)."""
        p = self.problem
        c = p.constraint
        rho = self.rho
        a0, _, a2 = coeffs
        C = self.C
        lam, v_C = self._multiplier(k, vals)
        bad = next(
            (
                name
                for name, w in (("u", k["u"]), ("v", k["v"]), ("a", k["a"]))
                if not np.all(np.isfinite(w))
            ),
            None,
        )
        if self._any(bad is not None) or not np.all(np.isfinite(lam)):
            return None, bad or "lambda"
        f, pr = state.fields, state.products
        u, v, Ku, Mv, Ma, Dv = k["u"], k["v"], k["Ku"], k["Mv"], k["Ma"], k["Dv"]
        L = state.ledger
        # numerical dissipation N^j and its G-form pieces (rothe.eld.state)
        du, dv = u - f["u"], v - f["v"]
        dKu, dMv = Ku - pr["Ku"], Mv - pr["Mv"]
        tdu, tdv = a0 * du, a0 * dv  # tau delta z = alpha_0 Delta z^j - alpha_2 Delta z^{j-1}
        pairs = [(dMv, dv), (dKu, du), (Mv, dv), (Ku, du)]
        if a2:
            du1, dv1 = f["u"] - f["u_1"], f["v"] - f["v_1"]
            tdu, tdv = tdu - a2 * du1, tdv - a2 * dv1
            pairs += [(Mv, dv1), (Ku, du1), (dMv, dv1), (dKu, du1)]
        # the work of the algebraic residual R
        R = rho * Ma + Dv + Ku - vals.F
        R[C] += (c.boundary_mass @ lam)[self.bpos]
        Bv = c.boundary_mass @ v_C
        # local error estimate (trapezoidal residuals, module docstring)
        Kr = k["Kx"] - pr["Kx"] - 0.5 * tau * (k["Ky"] + pr["Ky"])
        rx = k["x"] - f["x"] - 0.5 * tau * (k["y"] + f["y"])
        Mr = k["My"] - pr["My"] - 0.5 * tau * (k["Mb"] + pr["Mb"])
        ry = k["y"] - f["y"] - 0.5 * tau * (k["b"] + f["b"])
        if self._estimate_on_fields:
            # With differenced data G_dot^j is a difference quotient of G, not integrated by the
            # step: after a step cut (omega -> 0) it jumps by the previous quotient's O(tau_prev^2)
            # error, and the harmonic lifting spreads that jump over the interior, where no
            # smaller step can remove it (the run failed below tau_min). Both liftings give the
            # same u, v, a with differenced data, so the estimate is taken from them on the free
            # dofs: the nodal lifting's estimate, which contains the solution's error only.
            rx = u - f["u"] - 0.5 * tau * (v + f["v"])
            ry = v - f["v"] - 0.5 * tau * (k["a"] + f["a"])
            rx[C] = 0.0
            ry[C] = 0.0
            Kr = self._mult(p.K, rx)
            Mr = self._mult(p.M, ry)
        pairs += [
            (Ma, v),
            (Mv, tdv),
            (Ku, v),
            (Ku, tdu),
            (vals.F, v),
            (Dv, v),
            (R, v),
            (v, Mv),
            (u, Ku),
            (rx, Kr),
            (ry, Mr),
        ]
        s = self._dots(pairs)
        sq_kin, sq_el, zd_kin, zd_el = rho * s[0], s[1], rho * s[2], s[3]
        N = 0.5 * (sq_kin + sq_el) + (a0 - 1.0) * (zd_kin + zd_el)
        cross = 0.0
        rest = s[4:]
        if a2:
            N -= a2 * (rho * rest[0] + rest[1])
            cross = rho * rest[2] + rest[3]
            rest = rest[4:]
        Ma_v, Mv_tdv, Ku_v, Ku_tdu, F_v, Dv_v, R_v, v_Mv, u_Ku, rxKr, ryMr = rest
        nu = scheme.g_weight
        mu = a0 - 1.0
        N_G = (0.5 - nu) * (sq_kin + sq_el) + nu * (L.g_sq_kin + L.g_sq_el) - a2 * cross
        S = (L.g_mu - a2) * (L.g_zd_kin + L.g_zd_el)
        C_new = mu * (zd_kin + zd_el) + nu * (sq_kin + sq_el)
        # data/start mismatch X
        X = rho * (tau * Ma_v - Mv_tdv) + (tau * Ku_v - Ku_tdu)
        kin, el = 0.5 * rho * v_Mv, 0.5 * u_Ku
        if not math.isfinite(kin + el):
            return None, "the energy E = 1/2 rho v.M v + 1/2 u.K u"
        ledger = replace(
            L,
            kinetic=kin,
            elastic=el,
            work=L.work + tau * F_v,
            work_reaction=L.work_reaction - tau * float(lam @ Bv),
            dissipated=L.dissipated + tau * Dv_v,
            numerical=L.numerical + N,
            mismatch=L.mismatch + X,
            residual_work=L.residual_work + tau * R_v,
            numerical_G=L.numerical_G + N_G,
            step_change=L.step_change + S,
            boundary_C=C_new,
            g_zd_kin=zd_kin,
            g_sq_kin=sq_kin,
            g_zd_el=zd_el,
            g_sq_el=sq_el,
            g_mu=mu,
        )
        omega = 1.0 if state.tau_prev is None else tau / state.tau_prev
        norm_new = math.sqrt(max(2.0 * (kin + el), 0.0))
        scale = max(state.energy_norm_max, norm_new, 1e-300)
        est = scheme.estimate_factor(omega) * math.sqrt(max(rxKr + rho * ryMr, 0.0)) / scale
        fields, products = accepted_fields(k, f, pr, u, v, Ku, Mv)
        boundary = {"lam": lam}
        boundary.update(self.data_mode.next_history(state.boundary, vals))
        new = ELDState(
            t=t_new,
            j=state.j + 1,
            tau_prev=tau,
            fields=fields,
            boundary=boundary,
            products=products,
            ledger=ledger,
            energy_norm_max=max(state.energy_norm_max, norm_new),
            mesh_id=state.mesh_id,
        )
        return new, est

    # -- recording ------------------------------------------------------------------------------
    def _step_record(self, result: ELDStepResult, constraint) -> dict:
        """The point and step series of an accepted step: t, the ledger (EnergyLedger.record),
        tau, the estimate, the multiplier's norm on ``constraint``, the Newton iterations and
        the reactions ``reaction_<part>``."""
        st = result.state
        rec = dict(
            t=st.t,
            **st.ledger.record(),
            tau=result.tau,
            local_error=result.estimate,
            lam_norm=constraint.l2_norm(result.lam),
            newton_iterations=result.newton_iterations,
        )
        for part, force in result.reactions.items():
            rec[f"reaction_{part}"] = force
        return rec


class ELDStepper(StepperBase):
    """One step of Euler or BDF2 in either form (module docstring); the evolve loop drives it.

    Parameters
    ----------
    problem : ELDProblem
    scheme : ImplicitEuler or BDF2
    form : Regularized or Original
    control : Uniform, Given or Adaptive
        The steps (the stepper checks them against T and Lemma 3.2; the controller is built
        from the same object, :func:`rothe.eld.run.prepare_eld_run`).
    data : Points, Means or Differenced
    solver : {'auto', 'direct', 'amg'}
    newton : NewtonOptions, optional
    noise : DataNoise, optional
        Perturbation of the data of every step (Sec. 4.3).
    store_fields : bool
    keep_every : int
        Keep u, v, a, lambda of every k-th state (and the last).
    observer : callable(state, result), optional
        Called with the initial state (``result`` None; it holds the consistent lambda(0)) and
        after every accepted step (e.g. to write XDMF). A resumed run does not call it for the
        initial state again.
    linear_rtol : float
        Relative residual of iterative linear solves.
    error_scale : float, optional
        The floor of the error estimate's scale (default: :func:`rothe.eld.start.data_scale`).
    adapt : SpaceAdaptivity, optional
        Adapt the mesh between steps (:mod:`rothe.eld.adapt`).
    """

    def __init__(
        self,
        problem: ELDProblem,
        *,
        scheme: Scheme = DEFAULT_SCHEME,
        form: Form = DEFAULT_FORM,
        control=DEFAULT_CONTROL,
        data: DataMode = DEFAULT_DATA,
        solver: str = "auto",
        newton: NewtonOptions | None = None,
        noise=None,
        store_fields: bool = True,
        keep_every: int = 1,
        observer=None,
        linear_rtol: float = 1e-10,
        error_scale: float | None = None,
        adapt=None,
    ):
        self.scheme = as_scheme(scheme)
        self.form = as_form(form)
        self.control = as_control(control)
        self.data_mode = as_data_mode(data)
        self.data_mode.check(self.scheme)
        if adapt is not None:
            check_adapt(adapt, data=self.data_mode, noise=noise)
        self._set_common(problem, newton, store_fields, keep_every, observer, error_scale)
        self.times = PhaseTimes()  # factor, solve; estimate ... transfer of the adapt step
        # the first step's effective step: the stored factorization's matrix
        self.system = ELDSystem.build(
            problem,
            self.form,
            tau_eff=self.tau / self.scheme.alpha0,
            variable_steps=self.n_steps is None or self.steps is not None,
            solver=solver,
            linear_rtol=linear_rtol,
            data=self.data_mode,
            noise=noise,
            times=self.times,
        )
        self.initial_factorizations = self.system.initial_factorizations
        # with differenced data the harmonic lifting's unknowns see the jumps of the data
        # quotients after a step cut: the estimate is taken from u, v, a instead (_complete)
        self._estimate_on_fields = isinstance(self.data_mode, Differenced) and isinstance(
            self.system.lifting, HarmonicLifting
        )
        self.adaptivity = None
        if adapt is not None:
            self.adaptivity = ELDAdaptivity(problem, adapt, scheme=self.scheme, times=self.times)
        self._base = None  # (state, mesh hierarchy, system) before a step's own refinements
        self._adapted: float | None = None  # eta of the last adapt step (None: none / failed)
        self._undo: dict | None = None  # what begin_attempt saw (for abandon)

    # -- what the system holds ------------------------------------------------------------------
    @property
    def problem(self) -> ELDProblem:
        """The problem on the current mesh."""
        return self.system.problem

    @property
    def meshes(self):
        """The series of meshes of a space-adaptive run (:class:`rothe.eld.adapt.ELDMeshes`),
        None on a fixed mesh."""
        return None if self.adaptivity is None else self.adaptivity.meshes

    @property
    def rho(self) -> float:
        """The density (of the system's material)."""
        return self.system.rho

    @property
    def C(self) -> np.ndarray:
        """The constrained dofs (of the current mesh)."""
        return self.system.problem.constraint.dofs

    #: the constrained dofs' positions in the constraint's order: all of them, in order
    bpos = slice(None)

    # -- the initial state ----------------------------------------------------------------------
    def initial_state(self) -> ELDState:
        """The state at t = 0 (:mod:`rothe.eld.start`; raises RunFailed if the consistent
        acceleration or multiplier at t = 0 is not finite, e.g. after an overflow). With
        adaptive steps and no ``error_scale`` given, sets the error scale."""
        where = {"step": 0, "s": 0.0, "t": 0.0, "form": self.form.name, "scheme": self.scheme.name}
        # BLAS level-1 calls outside the evolve loop: single-threaded as inside it
        # (rothe.stepping.evolve.single_threaded_blas; threaded dots spin on busy cores)
        with single_threaded_blas(), np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            state = initial_state(self.system, where)
            norm0 = state.energy_norm_max
            if self.error_scale is None and isinstance(self.control, Adaptive):
                self.error_scale = max(norm0, data_scale(self.system, self.T)) or 1.0
        state.energy_norm_max = max(norm0, self.error_scale or 0.0)
        return state

    def adopt(self, state: ELDState) -> ELDState:
        """Take over a state mapped from another mesh (:meth:`ELDSystem.adopt` on the current
        mesh)."""
        return self.system.adopt(state)

    def record_initial(self, traj: Trajectory, state: ELDState) -> None:
        """Record the initial state (energies and, if kept, its fields)."""
        L = state.ledger
        traj.append(
            t=0.0,
            kinetic=L.kinetic,
            elastic=L.elastic,
            energy=L.energy,
            work=0.0,
            work_reaction=0.0,
            dissipated=0.0,
            numerical_dissipation=0.0,
            numerical_dissipation_G=0.0,
            step_change=0.0,
            data_mismatch=0.0,
            residual_work=0.0,
            transfer=0.0,
            balance_residual=0.0,
        )
        if self.adaptivity is not None:
            traj.append(**self._mesh_record(state, self.system))
        if self.store_fields:
            self._keep(traj, state, self.system)
        if self.observer is not None:  # lambda(0) is known here: an output starts at t = 0
            self.observer(state, None)

    def _keep(self, traj: Trajectory, state: ELDState, system=None) -> None:
        if self.adaptivity is not None:
            self.adaptivity.meshes.keep(traj, state, system)
            return
        traj.append(
            kept_step=state.j,
            kept_t=state.t,
            u=state.u.copy(),
            v=state.v.copy(),
            a=state.fields["a"].copy(),
            lam=state.lam.copy(),
        )

    @staticmethod
    def _mesh_record(state: ELDState, system) -> dict:
        return {
            "mesh_id": int(state.mesh_id),
            "ndofs": int(system.problem.space.ndofs),
            "cells": int(system.problem.space.mesh.t.shape[1]),
        }

    # -- evolve-loop interface ------------------------------------------------------------------
    def where(self, state: ELDState, result=None) -> dict:
        """Where the run is (for messages and checkpoints): step, t, tau, form, scheme (and the
        mesh id with space adaptivity)."""
        info = super().where(state, result)
        if self.adaptivity is not None:
            info["mesh_id"] = int(state.mesh_id)
        return info

    def progress_fields(self, state: ELDState) -> dict:
        """t and the last step's Newton iterations (and the dofs with space adaptivity)."""
        out = {"t": f"{state.t:.4g}", "newton": self._last_newton}
        if self.adaptivity is not None:
            out["dofs"] = self.problem.space.ndofs
        return out

    # -- an abandoned attempt (rothe.stepping.interrupt) ----------------------------------------
    def begin_attempt(self, state: ELDState) -> None:
        """(The evolve loop, before each attempt.) Note what an attempt changes in the stepper
        -- the system of the current mesh with its stored factorization, the key it was built
        from and the solver's counters, the Newton count, the factorizations of systems built
        for refined meshes -- so that :meth:`abandon` can put it back. References and a few
        numbers: no copy of a matrix or a factorization. With space adaptivity not even a
        reference to the factorization: the adapt cycle releases the system of a mesh it
        leaves (:meth:`ELDSystem.release`), and abandon revives it."""
        if self.adaptivity is not None:
            self._back_to_mesh_of(state)  # as step() does first: the state's own mesh
        self._undo = {
            "system": self.system,
            "solver": self.system.snapshot(stored=self.adaptivity is None),
            "last_newton": self._last_newton,
            "pending": 0 if self.adaptivity is None else self.adaptivity.pending_factorizations,
        }

    def abandon(self, state: ELDState) -> None:
        """(The evolve loop, when a stop signal abandoned the attempt from ``state``: between
        Newton iterations, between the refine-and-resolve rounds of a step with space
        adaptivity, or during a factorization -- of the step, or of the new mesh's system in a
        round or in the adapt step after the accepted step, :func:`rothe.stepping.interrupt.
        call`.) Back to the mesh of ``state`` (the adapt cycle rolled its own refinement back,
        ``_back_to_mesh_of`` undoes the rounds') and to what :meth:`begin_attempt` noted, so
        that a checkpoint of ``state`` resumes like the uninterrupted run. A mesh the attempt
        added to the series stays there: the resumed run makes the same mesh with the same id.
        """
        undo = self._undo
        if undo is None:
            return
        if self.adaptivity is not None:
            self._back_to_mesh_of(state)
            self.adaptivity.pending_factorizations = undo["pending"]
        self.system = undo["system"].revived()  # rebuilt if a rebuild released it
        self.system.rollback(undo["solver"])
        self._last_newton = undo["last_newton"]
        self._undo = None

    # -- the step -------------------------------------------------------------------------------
    def step(self, state: ELDState, tau: float, s_end=None) -> ELDStepResult:
        """One step from ``state`` with step ``tau``. With space adaptivity: while the step's
        estimate on its mesh exceeds space_tol, the mesh is refined (the adapt cycle with
        ``refine_only``) and the step solved again from ``state`` transferred to the refined
        mesh, at most :data:`~rothe.eld.adapt.STEP_ROUNDS` times (a wave that enters a coarse
        region, or the data of a boundary pulse, is resolved in the step that creates it). The
        result is that of the last solve; ``result.counters['dofs']`` sums the dofs of every
        solve, ``result.refinements`` counts the refinements.

        A stop signal abandons the step between the rounds (and between Newton iterations):
        :func:`rothe.stepping.interrupt.check`, :meth:`abandon`."""
        if self.adaptivity is None:
            return self._attempt(state, tau)
        self._back_to_mesh_of(state)
        original = state
        first = self._attempt(state, tau)

        def remember():  # the mesh before the step's own refinements (_back_to_mesh_of)
            base = self._base
            if base is None or base[0] is not original:
                base = (original, self.adaptivity.adaptation.amesh.checkpoint_state(), self.system)
            return base

        def adopt(out, base):
            self._base = base
            self.system = out.problem
            return self.system

        def failed():  # a failed transfer left it released
            self.system = self.system.revived()

        done = self.adaptivity.refine_in_step(
            self.system,
            state,
            first,
            tau,
            self.T,
            attempt=lambda state: self._attempt(state, tau),
            remember=remember,
            adopt=adopt,
            failed=failed,
            ndofs=lambda system: system.ndofs,
            check=interrupt.check,
        )
        result = done.result
        result.refinements, result.bisections = done.refinements, done.bisections
        result.counters["dofs"] = done.dofs
        return result

    def _back_to_mesh_of(self, state: ELDState) -> None:
        """A step retried (rejected by the time controller) from a state whose mesh was refined
        during the rejected attempt: back to that state's mesh and system."""
        base = self._base
        if base is not None and base[0] is state and state.mesh_id != self.adaptivity.mesh_id:
            self.adaptivity.adaptation.restore_state({"amesh": base[1]})
            # the first round's rebuild released it (one mesh's system at a time)
            self.system = base[2].revived()
            self._base = (base[0], base[1], self.system)

    # -- the backend of StepperBase: this process's linear algebra ---------------------------------
    def _dots(self, pairs) -> list[float]:
        return [float(a @ b) for a, b in pairs]

    def _any(self, flag: bool) -> bool:
        return bool(flag)

    @staticmethod
    def _mult(A, w: np.ndarray) -> np.ndarray:
        return A @ w

    def _start_data(self, tau: float, cubic: bool):
        p = self.problem
        g3 = (p.G_ddot(tau) - p.G_ddot(0.0)) / tau if cubic else None
        return self.system.data.initial()[1], g3

    def _split(self, w: np.ndarray) -> np.ndarray:
        return self.system.split(w)

    def _fill_products(self, state: ELDState) -> None:
        self.system.fill_products(state)

    def _values(self, j: int, state: ELDState, t_new: float, coeffs):
        hist = self.data_mode.history(state.boundary, coeffs)
        return self.system.data.at(j, state.t, t_new, coeffs, hist)

    @staticmethod
    def _nonfinite(vals) -> str | None:
        return vals.first_nonfinite()

    def _linear_stats(self) -> SolverStats:
        return self.system.solver.stats

    def _result_system(self):
        return self.system

    def _multiplier(self, k: dict, vals):
        C = self.C
        if "lam" in k:
            lam = k["lam"]
        else:
            # (3.4a) tested with V^c: the residual on the constrained rows is B^T lambda
            lam = self.problem.constraint.multiplier_from_residual(
                vals.F[C] - self.rho * k["Ma"][C] - k["Dv"][C] - k["Ku"][C]
            )
        return lam, k["v"][C]

    # -- the two forms --------------------------------------------------------------------------
    def _solve_step(self, state: ELDState, vals, coeffs, tau):
        if isinstance(self.form, Regularized):
            return self._step_regularized(state, vals, coeffs, tau)
        return self._step_original(state, vals, coeffs, tau)

    def _step_parts(self, state: ELDState, vals, coeffs, tau):
        """What both forms' steps start from: the system, the problem, rho, the dofs, alpha_0,
        tau_eff, the lifted data, the history terms and the damping operator."""
        system = self.system
        a0 = coeffs[0]
        return (
            system,
            system.problem,
            system.rho,
            system.problem.space.ndofs,
            a0,
            tau / a0,
            system.lifted(vals),
            history_terms(state, coeffs),
            system.D,
        )

    def _step_regularized(self, state: ELDState, vals, coeffs, tau):
        system, p, rho, n, a0, te, lifted, h, D = self._step_parts(state, vals, coeffs, tau)
        I = system.I
        (u2, _, Ku2), (v2, Mv2, Kv2), (w2, Mw2, _) = lifted
        guess = self._guess(state, tau)[I]
        if D.is_linear:
            # A(te) x = F - rho M (alpha_0 h_x/tau^2 + h_y/tau + w2) - C (h_x/tau + v2) - K u2
            rhs = (
                vals.F
                - rho * (a0 * h["Mx"] / tau**2 + h["My"] / tau + Mw2)
                - D.mass_coef * (h["Mx"] / tau + Mv2)
                - D.stiffness_coef * (h["Kx"] / tau + Kv2)
                - Ku2
            )
            if D.matrix is not None:
                rhs = rhs - D.matrix @ (h["x"] / tau + v2)
            xI = system.solve_linear(rhs[I], te, guess)
            x = np.zeros(n)
            x[I] = xI
            return kinematics(h, coeffs, tau, x, p.M @ x, p.K @ x, lifted, D), 0

        cache = {}

        def residual(xI):
            x = np.zeros(n)
            x[I] = xI
            k = kinematics(h, coeffs, tau, x, p.M @ x, p.K @ x, lifted, D)
            cache["k"] = k
            R = rho * k["Ma"] + k["Dv"] + k["Ku"] - vals.F
            return R[I], k["v"]

        def jacobian(v):
            # matrix-free J_II w = A_II(te) w + (N'(v) E w)_I / te; assembled only when the
            # stored preconditioner must be rebuilt
            action = D.nonlinear_jacobian_action(v)

            def matvec(w):
                full = np.zeros(n)
                full[I] = w
                return system.apply_A(w, te) + action(full)[I] / te

            op = spla.LinearOperator((I.size, I.size), matvec=matvec, dtype=float)
            return op, system.assembler(te, v)

        _, _, its = newton(
            residual, self._correction(jacobian), guess, state.fields["x"][I], self.newton
        )
        return cache["k"], its

    def _step_original(self, state: ELDState, vals, coeffs, tau):
        system, p, rho, n, a0, te, lifted, h, D = self._step_parts(state, vals, coeffs, tau)
        c = p.constraint
        g_rhs = c.boundary_mass @ vals.G
        if D.is_linear:
            rhs_u = (
                vals.F
                - rho * (a0 * h["Mx"] / tau**2 + h["My"] / tau)
                - D.mass_coef * h["Mx"] / tau
                - D.stiffness_coef * h["Kx"] / tau
            )
            if D.matrix is not None:
                rhs_u = rhs_u - D.matrix @ (h["x"] / tau)
            z = system.solve_linear(np.concatenate([rhs_u, g_rhs]), te)
            u = z[:n]
            k = kinematics(h, coeffs, tau, u, p.M @ u, p.K @ u, lifted, D)
            k["lam"] = z[n:]
            return k, 0

        B = c.B
        lam0 = state.lam if state.lam is not None else np.zeros(c.m)
        cache = {}

        def residual(z):
            u, lam = z[:n], z[n:]
            k = kinematics(h, coeffs, tau, u, p.M @ u, p.K @ u, lifted, D)
            k["lam"] = lam
            cache["k"] = k
            R_u = rho * k["Ma"] + k["Dv"] + k["Ku"] + B.T @ lam - vals.F
            return np.concatenate([R_u, B @ u - g_rhs]), k["v"]

        def jacobian(v):
            action = D.nonlinear_jacobian_action(v)
            m = c.m

            def matvec(z):
                u, lam = z[:n], z[n:]
                return np.concatenate([system.apply_A(u, te) + action(u) / te + B.T @ lam, B @ u])

            op = spla.LinearOperator((n + m, n + m), matvec=matvec, dtype=float)
            return op, system.assembler(te, v)

        x = state.fields["x"]
        z0 = np.concatenate([self._guess(state, tau), lam0])
        _, _, its = newton(
            residual, self._correction(jacobian), z0, np.concatenate([x, lam0]), self.newton
        )
        return cache["k"], its

    def _correction(self, jacobian):
        """The Newton correction of :func:`newton`: J dz = -R with J, and the assembler of the
        stored preconditioner, from ``jacobian(v)`` (v the iterate's velocity)."""

        def correction(R, v):
            J, assemble = jacobian(v)
            dz = self.system.solve(J, -R, assemble=assemble, rtol=self.newton.krylov_rtol)
            interrupt.check()  # after the expensive part of the iteration: a stop abandons it
            return dz

        return correction

    # -- the adapt step -------------------------------------------------------------------------
    def adapt(self, state: ELDState, result: ELDStepResult) -> ELDState:
        """The adapt step after the accepted ``result`` (:mod:`rothe.eld.adapt`): with space
        adaptivity, when due and the run goes on, the state on a new mesh (a new state; the
        accepted one is never changed); otherwise ``state`` itself.

        A failed adaptation (the cycle rolled back) stops the run with
        :class:`~rothe.errors.RunFailed`; the accepted step stands on its own mesh."""
        self._adapted = None
        ad = self.adaptivity
        if ad is None:
            return state
        try:
            # a stop signal during the new mesh's factorization abandons the attempt: the
            # cycle rolls the hierarchy back, and _base (the mesh before the step's own
            # refinements) lets abandon() go back to the previous state's mesh
            out, estimate = ad.after_step(
                self.system,
                state,
                result,
                self.T,
                finished=self.finished(state),
                where=lambda: self.where(state),
                ndofs=lambda out: out.problem.problem.space.ndofs,
                transfer=lambda new: new.ledger.energy - state.ledger.energy,
            )
        except RunFailed:
            self._base = None
            self.system = self.system.revived()  # a failed transfer left it released
            raise
        if out is not None and out.changed:
            self.system = out.problem
            state = out.state
        self._base = None  # accepted: the state's mesh is the current one
        self._adapted = estimate
        return state

    # -- recording ------------------------------------------------------------------------------
    def record(
        self, traj: Trajectory, result: ELDStepResult, state: ELDState | None = None
    ) -> None:
        """Record the accepted step ``result`` on the mesh it was computed on (energies, tau,
        the estimate, the multiplier's norm, the reactions; kept fields every ``keep_every``-th
        step; with space adaptivity its mesh, dofs and what the adapt step did). ``state`` is
        the state the run goes on from."""
        st = result.state
        traj.append(**self._step_record(result, result.system.problem.constraint))
        ad = self.adaptivity
        if ad is not None:
            traj.append(**self._mesh_record(st, result.system))
            traj.append(
                step_dofs=int(result.counters.get("dofs", result.system.ndofs)),
                step_refinements=result.refinements,
                step_bisections=result.bisections,
            )
        if self.store_fields and (st.j % self.keep_every == 0 or self.finished(st)):
            self._keep(traj, st, result.system)
        if self.observer is not None:
            self.observer(st, result)
        if ad is not None and self._adapted is not None:
            traj.append(space_estimate=self._adapted)
            if ad.pending_factorizations:
                traj.stats.linear_factorizations += ad.pending_factorizations
                ad.pending_factorizations = 0
        if ad is not None and result.system is not self.system and self._base is None:
            # the adapt step left this step's mesh: once recorded, nothing needs its system (the
            # run goes on with self.system), but the evolve loop holds the result until the
            # next step is solved, and that mesh's matrices and solver stayed alive next to the
            # new ones (the memory peak of an adaptive 3D run)
            result.system = None

    # -- checkpoints ----------------------------------------------------------------------------
    def checkpoint_state(self, state: ELDState) -> dict:
        """Everything that influences the rest of the run, as arrays and plain values: the state
        (fields, boundary vectors with the data history of differenced data, products, ledger,
        error scale), the key of the stored factorization, the solver's counters (the run's
        ``linear_solver`` statistics continue from them), the Newton count the progress line
        shows, and with space adaptivity the mesh hierarchy, the series of meshes, the kept
        fields and the log. The step data itself keeps no state (:mod:`rothe.eld.data`)."""
        if self.adaptivity is not None:
            self._back_to_mesh_of(state)  # e.g. interrupted after a rejected, refined attempt
        system = self.system
        return {
            "format": CHECKPOINT_FORMAT,
            "scheme": self.scheme.name,
            "form": self.form.name,
            "t": float(state.t),
            "j": int(state.j),
            "tau_prev": state.tau_prev,
            "fields": {k: w.copy() for k, w in state.fields.items()},
            "boundary": {k: w.copy() for k, w in state.boundary.items()},
            "products": {k: w.copy() for k, w in state.products.items()},
            "ledger": {k: float(v) for k, v in asdict(state.ledger).items()},
            "energy_norm_max": float(state.energy_norm_max),
            "mesh_id": int(state.mesh_id),
            "error_scale": None if self.error_scale is None else float(self.error_scale),
            "solver_reference": system.reference,
            "solver_stats": asdict(system.solver.stats),
            "last_newton": int(self._last_newton),
            "adapt": None if self.adaptivity is None else self.adaptivity.checkpoint_state(),
        }

    def restore_state(self, data: dict) -> ELDState:
        """The state of :meth:`checkpoint_state`; rebuilds the mesh and its system (space
        adaptivity), refactors the stored matrix it names and continues the solver's counters
        from the checkpoint's (the refactorization is not counted: the uninterrupted run did not
        do it)."""
        if data.get("format") != CHECKPOINT_FORMAT:
            raise RotheInputError(
                f"checkpoint: got format {data.get('format')!r}, must be {CHECKPOINT_FORMAT!r}"
            )
        for key, mine in (("scheme", self.scheme.name), ("form", self.form.name)):
            if data[key] != mine:
                raise RotheInputError(f"checkpoint: got {key} {data[key]!r}, this run has {mine!r}")
        if (data.get("adapt") is None) != (self.adaptivity is None):
            kind = "a fixed-mesh" if data.get("adapt") is None else "a space-adaptive"
            raise RotheInputError(
                f"checkpoint: got {kind} run's state, this run "
                + ("adapts its mesh" if self.adaptivity is not None else "keeps its mesh")
            )
        if self.adaptivity is not None:
            self.adaptivity.restore_state(data["adapt"])
            if int(data["mesh_id"]) != 0:
                self.system = self.system.rebuilt(
                    self.system.problem.on_mesh(self.adaptivity.adaptation.mesh),
                    symmetric_lu=True,
                    short_lived=True,
                )
                self.system.owns_problem = True
        self.system.restore_reference(data["solver_reference"])
        if data.get("solver_stats") is not None:
            self.system.solver.stats = SolverStats(**data["solver_stats"])
        if data.get("error_scale") is not None:
            self.error_scale = float(data["error_scale"])
        self._last_newton = int(data.get("last_newton", 0))
        tp = data["tau_prev"]
        return ELDState(
            t=float(data["t"]),
            j=int(data["j"]),
            tau_prev=None if tp is None else float(tp),
            fields={k: np.asarray(w, dtype=float).copy() for k, w in data["fields"].items()},
            boundary={k: np.asarray(w, dtype=float).copy() for k, w in data["boundary"].items()},
            products={k: np.asarray(w, dtype=float).copy() for k, w in data["products"].items()},
            ledger=EnergyLedger(**data["ledger"]),
            energy_norm_max=float(data["energy_norm_max"]),
            mesh_id=int(data.get("mesh_id", 0)),
        )
