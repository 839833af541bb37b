"""One step of the local incremental stationary scheme (Alg. 3.2, Steps 3-6) and a RIS run.

From (s_{k-1}, t_{k-1}, z_{k-1}) and tau_k:

3. z_k from the inner solver: (3.1) with (3.2), multiplier lambda_k (Lemma 4.1);
4. t_k = t_{k-1} + tau_k - ||z_k - z_{k-1}||_V,  s_k = s_{k-1} + tau_k;
5./6. the residuals I_1^k (3.3), I_2^k (3.4) of the affine interpolants (composite Simpson).

The stepper returns the new state, the residuals (as the controller's error measures) and the
solver counters; it never decides acceptance. With meshes that change between steps, the adapt
step after an accepted step (:meth:`RISStepper.adapt`) moves the run to a new mesh
(:mod:`rothe.ris.adapt`). The run driver is :mod:`rothe.ris.run`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import DataError, RunFailed, check_int, check_positive, fail
from ..fem.adapt import SpaceAdaptivity
from ..io.trajectory import Trajectory
from ..timing import PhaseTimes
from .adapt import RISAdaptivity, RISAdaptStep
from .inner import BallStepSolver, InnerOptions, RISCode
from .problem import RISProblem
from .residuals import step_residuals


@dataclass
class RISState:
    """A point of the discrete curve: curve parameter s_k, time t_k, state z_k (on the run's
    current mesh) and the number k of accepted steps.

    Parameters
    ----------
    s : float
        The curve parameter s_k.
    t : float
        The time t_k.
    z : ndarray
        The state z_k.
    k : int
        The number of accepted steps.
    """

    s: float
    t: float
    z: np.ndarray
    k: int = 0  # number of accepted steps so far


@dataclass
class RISStepResult:
    """One attempt of a step: the new state, the residuals I1 (3.3), I2 (3.4) with their
    quadrature error estimates, the multiplier lambda_k (Lemma 4.1), the KKT residual and
    tolerance, J at the start and end of the inner solve, I(t_k, z_k), ||z_k - z_{k-1}||_V, the
    increment, the solver counters and the result code (:class:`~rothe.ris.inner.RISCode`)."""

    state: RISState
    tau: float
    converged: bool
    code: RISCode
    lam: float
    kkt: float
    kkt_tol: float
    I1: float
    I2: float
    I1_err: float
    I2_err: float
    J_start: float
    J_final: float
    energy: float  # I(t_k, z_k)
    step_norm: float = 0.0  # ||z_k - z_{k-1}||_V
    # dist(-D_z I(t, z), dR(0)) at the start (t_{k-1}, z_{k-1}) and the end (t_k, z_k) of the
    # step (the ends of (3.3)'s integrand): the jump rule of the residual controllers reads them
    dist_start: float = math.nan
    dist_end: float = math.nan
    increment: np.ndarray | None = None  # z_k - z_{k-1}
    counters: dict = field(default_factory=dict)
    # the problem (and its mesh) the step was computed on: the record of the step uses it
    # after the adapt step has moved the run to another mesh
    problem: object = field(default=None, repr=False)
    mesh_id: int = 0

    @property
    def errors(self) -> dict:
        """The controller's error measures: {"I1": I1, "I2": I2}."""
        return {"I1": self.I1, "I2": self.I2}


class StagnationMonitor:
    """Stops a run that cannot reach its end: no progress in s over many step attempts.

    Every attempt of a step advances s by its tau when accepted, and s >= t, so reaching T
    needs at least T - t more of s. If ``window`` consecutive attempts (accepted, rejected
    and landing retries) advanced s by less than ``min_rate`` * (T - t), the run would need more
    than window / min_rate = 10^9 attempts at that rate, 1000 times the evolve loop's cap: it
    is stuck (typically on steps of ~1e-10 alternating with failed inner solves). That happens
    when dF or d2F does not belong to F (the line search on J and the Newton model disagree),
    which the construction check misses with ``check_derivatives=False`` or a derivative that
    is wrong only away from its test points, or when the energy is not coercive.

    State (``checkpoint_state``/``restore_state``): the attempt count of the window, s at its
    start and the failed inner solves in it.
    """

    def __init__(self, window: int = 200, min_rate: float = 1e-6):
        self.window = check_int("window", window, minimum=1)
        self.min_rate = check_positive("min_rate", min_rate)
        self.attempts = 0
        self.s_start: float | None = None
        self.failed = 0
        self.codes: dict[str, int] = {}

    def observe(self, state: RISState, result: RISStepResult, T: float, where: dict) -> None:
        """Count one attempt from ``state``; raise RunFailed when a window ends without
        progress."""
        if self.s_start is None:
            self.s_start = state.s
        self.attempts += 1
        if not result.converged:
            self.failed += 1
            self.codes[result.code] = self.codes.get(result.code, 0) + 1
        if self.attempts < self.window:
            return
        gained = state.s - self.s_start
        remaining = T - state.t
        if remaining > 0 and gained < self.min_rate * remaining:
            if self.failed:
                codes = ", ".join(f"{k} {v}" for k, v in sorted(self.codes.items()))
                cause = (
                    f"{self.failed} of them with a failed inner solve ({codes}): dF or d2F "
                    "probably does not belong to F (check_derivatives=True compares them "
                    "with finite differences), or F is not smooth enough for the Newton "
                    "solver"
                )
            else:
                cause = (
                    "all solves converged: the step control keeps the steps tiny; check "
                    "dF against F and the coercivity of the energy"
                )
            raise RunFailed(
                f"no progress: {self.window} step attempts advanced s by {gained:.3g} at "
                f"t = {state.t:.6g} (T = {T:g}; at this rate the run needs more than "
                f"{self.window / self.min_rate:.0e} attempts); {cause}",
                where=dict(
                    where, stagnation_window=self.window, s_gained=gained, failed_solves=self.failed
                ),
            )
        self.attempts, self.s_start, self.failed, self.codes = 0, state.s, 0, {}

    def checkpoint_state(self) -> dict:
        """The window: attempts, s at its start, failed solves and their codes."""
        return {
            "attempts": self.attempts,
            "s_start": self.s_start,
            "failed": self.failed,
            "codes": dict(self.codes),
        }

    def restore_state(self, data: dict) -> None:
        """Put back what :meth:`checkpoint_state` returned."""
        self.attempts = int(data["attempts"])
        self.s_start = None if data["s_start"] is None else float(data["s_start"])
        self.failed = int(data["failed"])
        self.codes = {str(k): int(v) for k, v in data["codes"].items()}


class RISStepper:
    """Steps 3-6 of Alg. 3.2 for a :class:`RISProblem`, and the adapt step after an accepted one.

    ``adapt``: a :class:`~rothe.fem.adapt.SpaceAdaptivity` adapts the mesh of a
    :class:`~rothe.ris.fem_problem.FERISProblem` after every ``adapt_every``-th accepted step
    (``adaptivity``, a :class:`~rothe.ris.adapt.RISAdaptivity`); None keeps the problem's mesh.
    ``problem`` is the problem on the current mesh. ``S`` stops the run at s = S (else at T).

    Parameters
    ----------
    problem : RISProblem
        The system in R^n, or a :class:`~rothe.ris.fem_problem.FERISProblem`.
    inner : InnerOptions, optional
        The inner solver's options.
    simpson_subintervals : int
        Subintervals (even) of the composite Simpson rule of the residuals I1 (3.3), I2 (3.4).
    S : float, optional
        Stop at s = S (None: at t = T).
    keep_every : int
        Keep z of every ``keep_every``-th accepted state (and of the last).
    adapt : SpaceAdaptivity, optional
        Adapt the mesh of a FERISProblem (None keeps it).
    """

    def __init__(
        self,
        problem: RISProblem,
        inner: InnerOptions | None = None,
        simpson_subintervals: int = 8,
        S: float | None = None,
        keep_every: int = 1,
        adapt: SpaceAdaptivity | None = None,
    ):
        self.problem = problem
        self.times = PhaseTimes()  # estimate, mark, refine, rebuild, transfer (the adapt step)
        # meshes that change between steps (rothe.ris.adapt): None keeps the mesh of ``problem``
        self.adaptivity: RISAdaptivity | None = None
        if adapt is not None:
            self.adaptivity = RISAdaptivity(problem, adapt, times=self.times, inner=inner)
        self._adapted: RISAdaptStep | None = None  # what the last adapt step did
        self._inner = inner
        self._start: tuple[float, np.ndarray] | None = None  # (t, z) the attempts start from
        # z of every keep_every-th accepted state (and of the last): 8 MB per state at 10^6 nodes
        self.keep_every = check_int("keep_every", keep_every, minimum=1)
        self.solver = BallStepSolver(problem, inner)
        self.n_simpson = check_int("simpson_subintervals", simpson_subintervals, minimum=2)
        if self.n_simpson % 2:
            raise fail("simpson_subintervals", self.n_simpson, "must be even")
        self.S = None if S is None else check_positive("S", S)
        self.t_tol = 1e-10 * max(1.0, problem.T)
        self._last_tau = 0.0
        # the last accepted step (its end state, increment and tau): a warm-start candidate
        self._previous: tuple[np.ndarray, np.ndarray, float] | None = None
        self.monitor = StagnationMonitor()
        self._undo: dict | None = None  # what begin_attempt saw (for abandon)

    # -- evolve-loop interface ----------------------------------------------------------------
    def finished(self, state: RISState) -> bool:
        """t reached T (within ``t_tol``), or s reached S."""
        if state.t >= self.problem.T - self.t_tol:
            return True
        return self.S is not None and state.s >= self.S * (1 - 1e-14)

    def limit(self, state: RISState, tau: float) -> float:
        """The step shortened so that s does not pass S."""
        if self.S is not None:
            return min(tau, self.S - state.s)
        return tau

    def overshoot(self, state: RISState, attempts: list[RISStepResult]):
        """A shorter tau that lands on T when the step overshoots it, or None.

        t(tau) = t_{k-1} + tau - ||d(tau)||_V is a hinge: while the ball constraint is active
        (lambda > 0, z_k still catching up with the equilibrium at t_{k-1}) ||d|| = tau and t
        stays at t_{k-1}; once z_k reaches a stationary point of the step's functional inside
        the ball (lambda = 0), ||d|| no longer depends on tau and t grows with slope exactly 1.
        So from an attempt that made progress in t the step that lands on T is
        tau - (t(tau) - T) (one Newton step on the hinge, exact when the same stationary point
        is reached). If that does not land (a different stationary point), the next guess is
        regula falsi (Illinois) between the nearest progress-making attempts on both sides of
        T, or bisection between the largest tau that stayed in the flat part and the
        smallest that overshot. The result lands within ``t_tol`` = 1e-10 max(1, T).
        """
        T = self.problem.T
        last = attempts[-1]
        if not last.converged or abs(last.state.t - T) <= self.t_tol:
            return None
        if len(attempts) == 1 and last.state.t <= T:
            return None
        ok = [a for a in attempts if a.converged]
        over = [a for a in ok if a.state.t > T]
        if not over:
            return None
        hi = min(over, key=lambda a: a.tau)
        below = [a.tau for a in ok if a.state.t < T and a.tau < hi.tau]
        lo_tau = max(below, default=0.0)
        progress = [a for a in ok if a.state.t > state.t + self.t_tol]
        under = [a for a in progress if a.state.t < T and a.tau < hi.tau]
        tried = {a.tau for a in attempts}
        candidates = []
        if under:  # both sides made progress: regula falsi on the affine part of t(tau)
            lo = max(under, key=lambda a: a.tau)
            f_lo, f_hi = lo.state.t - T, hi.state.t - T
            if len(attempts) >= 3 and (attempts[-1].state.t - T) * (attempts[-2].state.t - T) > 0:
                if attempts[-1].state.t > T:  # Illinois: halve the weight of the kept end
                    f_lo *= 0.5
                else:
                    f_hi *= 0.5
            candidates.append(lo.tau - f_lo * (hi.tau - lo.tau) / (f_hi - f_lo))
        nearest = min(progress, key=lambda a: abs(a.state.t - T))
        candidates.append(nearest.tau - (nearest.state.t - T))  # slope one past the hinge
        for tau in candidates:
            if lo_tau < tau < hi.tau and tau not in tried:
                return tau
        return 0.5 * (lo_tau + hi.tau)

    def pick_landing(self, state: RISState, attempts: list[RISStepResult]) -> RISStepResult:
        """The attempt to hand to the controller after shortening.

        One that ends within t_tol of T if any; otherwise the one closest to T among those that
        made progress in t (an undershoot that stayed in the flat part of t(tau) would only burn
        a step), so a small overshoot of T is preferred to no progress.
        """
        T = self.problem.T
        ok = [a for a in attempts if a.converged]
        if not ok:
            return attempts[-1]
        landed = [a for a in ok if abs(a.state.t - T) <= self.t_tol]
        if landed:
            return landed[0]
        useful = [a for a in ok if a.state.t > state.t + self.t_tol] or ok
        return min(useful, key=lambda a: abs(a.state.t - T))

    def begin_attempt(self, state: RISState) -> None:
        """(The evolve loop, before each attempt.) Note what an attempt changes in the stepper
        -- the reused factorization of the Newton systems and its counters, the stagnation
        monitor's window, the last tau, the problem and solver of the current mesh -- so that
        :meth:`abandon` can put it back. Cheap: references and a few numbers."""
        self._undo = {
            "problem": self.problem,
            "solver": self.solver,
            "linear": self.solver.linear.snapshot(),
            "monitor": self.monitor.checkpoint_state(),
            "last_tau": self._last_tau,
            "start": self._start,
        }

    def abandon(self, state: RISState) -> None:
        """(The evolve loop, when a stop signal abandoned the attempt from ``state``.) Put back
        what :meth:`begin_attempt` noted, so that a checkpoint of ``state`` resumes like the
        uninterrupted run. A mesh refined in the attempt's adapt step needs nothing here: the
        adapt cycle rolls the hierarchy back (:meth:`MeshAdaptation.cycle`), and the stepper
        takes the new mesh over only after the cycle returned."""
        undo = self._undo
        if undo is None:
            return
        self.problem, self.solver = undo["problem"], undo["solver"]
        self.solver.linear.rollback(undo["linear"])
        self.monitor.restore_state(undo["monitor"])
        self._last_tau, self._start = undo["last_tau"], undo["start"]
        self._adapted = None
        self._undo = None

    def step(self, state: RISState, tau: float, s_end: float | None = None) -> RISStepResult:
        """One attempt from ``state`` with step ``tau``.

        Data that cannot be evaluated (:class:`~rothe.errors.DataError`, e.g. a load that is
        NaN at some t) stops the run with :class:`RunFailed` (the evolve loop attaches the
        trajectory so far), except beyond T: an attempt that overshoots T into times where
        the load is not defined is a failed attempt, which the controller shortens.
        """
        try:
            result = self._step(state, tau, s_end)
        except DataError as exc:
            t_reached = state.t + tau
            if t_reached > self.problem.T + self.t_tol and state.t < self.problem.T:
                result = self._failed_attempt(state, tau, s_end, RISCode.DATA_BEYOND_T)
            else:
                where = self.where(state, None)
                where.update(tau=tau, data_error=str(exc))
                raise RunFailed(
                    f"{exc} (at step {where['step']}, s = {state.s:.6g}, t = {state.t:.6g}, "
                    f"tau = {tau:.3g})",
                    where=where,
                ) from None
        self.monitor.observe(state, result, self.problem.T, self.where(state, result))
        return result

    def _failed_attempt(self, state: RISState, tau: float, s_end, code: RISCode) -> RISStepResult:
        nan = math.nan
        return RISStepResult(
            state=RISState(
                s=s_end if s_end is not None else state.s + tau, t=nan, z=state.z, k=state.k + 1
            ),
            tau=tau,
            converged=False,
            code=code,
            lam=nan,
            kkt=nan,
            kkt_tol=nan,
            I1=nan,
            I2=nan,
            I1_err=nan,
            I2_err=nan,
            J_start=nan,
            J_final=nan,
            energy=nan,
            increment=np.zeros_like(state.z),
        )

    def _step(self, state: RISState, tau: float, s_end: float | None) -> RISStepResult:
        p = self.problem
        self._last_tau = tau
        self._start = (state.t, state.z)
        lin = self.solver.linear.stats
        before = (lin.factorizations, lin.solves, lin.krylov_iterations)
        hint = None
        if self._previous is not None and self._previous[0] is state.z:
            _, d_prev, tau_prev = self._previous
            hint = d_prev * (tau / tau_prev)  # same velocity dz/ds as the previous step
        res = self.solver.solve(state.t, state.z, tau, hint=hint)
        counters = {
            "newton_iterations": res.iterations,
            "fb_steps": res.fb_steps,
            "linear_factorizations": lin.factorizations - before[0],
            "linear_solves": lin.solves - before[1],
            "krylov_iterations": lin.krylov_iterations - before[2],
        }
        nd = p.norm_V(res.d)
        t_new = state.t + max(tau - nd, 0.0)  # Step 4; ||d|| <= tau up to round-off
        s_new = s_end if s_end is not None else state.s + tau
        new_state = RISState(s=s_new, t=t_new, z=res.z, k=state.k + 1)
        if res.converged:
            r = step_residuals(p, state.t, state.z, t_new, res.z, res.gradient, self.n_simpson)
            energy = p.energy(t_new, res.z)
        else:
            r = None
            energy = math.nan
        nan = math.nan
        return RISStepResult(
            state=new_state,
            tau=tau,
            converged=res.converged,
            code=res.code,
            lam=res.lam,
            kkt=res.kkt_residual,
            kkt_tol=res.tolerance,
            I1=r.I1 if r else nan,
            I2=r.I2 if r else nan,
            I1_err=r.I1_err if r else nan,
            I2_err=r.I2_err if r else nan,
            J_start=res.J_start,
            J_final=res.J_final,
            energy=energy,
            step_norm=nd,
            dist_start=r.dist_start if r else nan,
            dist_end=r.dist_end if r else nan,
            increment=res.d,
            counters=counters,
            problem=p,
            mesh_id=self.adaptivity.mesh_id if self.adaptivity is not None else 0,
        )

    def adapt(self, state: RISState, result: RISStepResult) -> RISState:
        """The adapt step after the accepted ``result`` (:mod:`rothe.ris.adapt`): with space
        adaptivity, when due and the run goes on, the problem and z_k on a new mesh (a new
        state; the accepted one is never changed); otherwise ``state`` itself."""
        self._adapted = None
        adaptivity = self.adaptivity
        if adaptivity is None or self.finished(state):  # due or not: RISAdaptivity.adapt
            return state
        t_prev, z_prev = self._start
        out = adaptivity.adapt(
            self.problem,
            t_prev,
            z_prev,
            state.z,
            result.lam,
            result.increment,
            state.t,
            result.energy,
            step=state.k,
            tau=result.tau,
        )
        self._adapted = out
        if not out.changed:
            return state
        self.problem = out.problem
        self.solver = BallStepSolver(out.problem, self._inner)
        return RISState(s=state.s, t=state.t, z=out.z, k=state.k)

    def record(self, traj: Trajectory, result: RISStepResult, state: RISState) -> None:
        """The accepted step ``result`` (on its own mesh) and, with space adaptivity, what the
        adapt step did (``transfer_energy``, ``relax_energy``, ...); ``state`` is the state the
        run goes on from."""
        st = result.state
        adapted = self._adapted
        increment = adapted.increment if adapted is not None else result.increment
        self._previous = (state.z, increment, result.tau)
        adaptive = self.adaptivity is not None
        if st.k % self.keep_every == 0:
            traj.append(z=result.problem.full_state(st.z), z_step=st.k)
            if adaptive:
                traj.append(z_mesh_id=result.mesh_id)
        traj.append(
            s=st.s,
            t=st.t,
            energy=result.energy,
            tau=result.tau,
            I1=result.I1,
            I2=result.I2,
            I1_err=result.I1_err,
            I2_err=result.I2_err,
            lam=result.lam,
            kkt=result.kkt,
            kkt_tol=result.kkt_tol,
            descent=result.J_start - result.J_final,
            step_norm=result.step_norm,
            newton_iterations=result.counters.get("newton_iterations", 0),
        )
        if adaptive:
            traj.append(mesh_id=result.mesh_id, n_dofs=result.problem.n)
            traj.append(**self.adaptivity.ledger(adapted, result))  # transfer_energy, relax_...

    def where(self, state: RISState, result: RISStepResult | None) -> dict:
        """Where the run is (step, s, t, the mesh) and what the attempt ``result`` gave."""
        info = {"step": state.k + 1, "s": state.s, "t": state.t}
        if self.adaptivity is not None:
            info.update(mesh_id=self.adaptivity.mesh_id, dofs=int(self.problem.n))
        if result is not None:
            info.update(
                tau=result.tau, I1=result.I1, I2=result.I2, code=result.code, kkt=result.kkt
            )
        return info

    def progress_fields(self, state: RISState) -> dict:
        """s, t, the last tau (and the unknowns with changing meshes) for the progress line."""
        fields = {"s": f"{state.s:.5g}", "t": f"{state.t:.5g}", "tau": f"{self._last_tau:.2g}"}
        if self.adaptivity is not None:
            fields["dofs"] = str(self.problem.n)
        return fields

    def progress_position(self, state: RISState) -> tuple[str, float, float]:
        """How far the run is: s/S when it stops at a given S, t/T otherwise."""
        if self.S is not None:
            return "s", float(state.s), float(self.S)
        return "t", float(state.t), float(self.problem.T)

    # -- checkpoint protocol (rothe.io.checkpoint) -------------------------------------------
    def checkpoint_state(self, state: RISState) -> dict:
        """The state (s, t, z, k), the warm-start hint of the next step (the previous accepted
        increment and its tau), the linear solver's stored preconditioner and the stagnation
        monitor's window."""
        previous = None
        if self._previous is not None:
            z_prev, d_prev, tau_prev = self._previous
            previous = {
                "increment": d_prev,
                "tau": float(tau_prev),
                "of_this_state": z_prev is state.z,
            }
        data = {
            "stepper": "ris",
            "s": float(state.s),
            "t": float(state.t),
            "z": state.z,
            "k": int(state.k),
            "last_tau": float(self._last_tau),
            "previous": previous,
            "linear": self.solver.linear.checkpoint_state(),
            "monitor": self.monitor.checkpoint_state(),
        }
        if self.adaptivity is not None:  # the mesh hierarchy and the series of meshes so far
            data["adapt"] = self.adaptivity.checkpoint_state()
        return data

    def restore_state(self, data: dict) -> RISState:
        """The state of :meth:`checkpoint_state`, with the stepper's own parts put back."""
        if data.get("stepper") != "ris":
            raise ValueError(
                f"restore_state: a {data.get('stepper')!r} stepper's state given to a RIS stepper"
            )
        if self.adaptivity is not None:
            if data.get("adapt") is None:
                raise ValueError(
                    "restore_state: a fixed-mesh state given to a RIS stepper with "
                    "meshes that change between steps"
                )
            self.problem = self.adaptivity.restore_state(data["adapt"])
            self.solver = BallStepSolver(self.problem, self._inner)
        state = RISState(
            s=float(data["s"]),
            t=float(data["t"]),
            z=np.array(data["z"], dtype=float),
            k=int(data["k"]),
        )
        self._last_tau = float(data["last_tau"])
        prev = data["previous"]
        if prev is None:
            self._previous = None
        else:  # the hint applies only to the state it was recorded with (see step)
            self._previous = (
                state.z if prev["of_this_state"] else None,
                np.array(prev["increment"], dtype=float),
                float(prev["tau"]),
            )
        self.solver.linear.restore_state(data["linear"])
        if data.get("monitor") is not None:  # absent in checkpoints of earlier versions
            self.monitor.restore_state(data["monitor"])
        return state
