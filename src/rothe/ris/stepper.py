"""One step of the local incremental stationary scheme (Alg. 3.2, Steps 3-6) and a RIS run.

From (s_{k-1}, t_{k-1}, z_{k-1}) and tau_k:

3. z_k from the inner solver: (3.1) with (3.2), multiplier lambda_k (Lemma 4.1);
4. t_k = t_{k-1} + tau_k - ||z_k - z_{k-1}||_V,  s_k = s_{k-1} + tau_k;
5./6. the residuals I_1^k (3.3), I_2^k (3.4) of the affine interpolants (composite Simpson).

The stepper returns the new state, the residuals (as the controller's error measures) and the
solver counters; it never decides acceptance.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from ..errors import DataError, RunFailed, RunInterrupted, check_int, check_positive, fail
from ..io.checkpoint import RunCheckpointing, run_arguments
from ..io.trajectory import Trajectory
from ..stepping.evolve import evolve
from ..timing import PhaseTimes
from .adapt import RISAdaptivity, RISAdaptStep
from .controllers import make_controller
from .inner import BallStepSolver, InnerOptions
from .problem import RISProblem
from .residuals import step_residuals


@dataclass
class RISState:
    s: float
    t: float
    z: np.ndarray
    k: int = 0  # number of accepted steps so far


@dataclass
class RISStepResult:
    state: RISState
    tau: float
    converged: bool
    code: str
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
    increment: np.ndarray | None = None  # z_k - z_{k-1}
    counters: dict = field(default_factory=dict)
    # the problem (and its mesh) the step was computed on: the record of the step uses it
    # after the adapt step has moved the run to another mesh
    problem: object = field(default=None, repr=False)
    mesh_id: int = 0

    @property
    def errors(self) -> dict:
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
        return {
            "attempts": self.attempts,
            "s_start": self.s_start,
            "failed": self.failed,
            "codes": dict(self.codes),
        }

    def restore_state(self, data: dict) -> None:
        self.attempts = int(data["attempts"])
        self.s_start = None if data["s_start"] is None else float(data["s_start"])
        self.failed = int(data["failed"])
        self.codes = {str(k): int(v) for k, v in data["codes"].items()}


class RISStepper:
    """Steps 3-6 of Alg. 3.2 for a :class:`RISProblem`."""

    def __init__(
        self,
        problem: RISProblem,
        inner: InnerOptions | None = None,
        simpson_subintervals: int = 8,
        S: float | None = None,
        keep_every: int = 1,
        space=None,
    ):
        self.problem = problem
        self.times = PhaseTimes()  # estimate, mark, refine, rebuild, transfer (the adapt step)
        # space adaptivity (rothe.ris.adapt): None keeps the mesh of ``problem``
        self.space = None
        if space is not None:
            self.space = RISAdaptivity(problem, space, times=self.times, inner=inner)
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

    # -- evolve-loop interface ----------------------------------------------------------------
    def finished(self, state: RISState) -> bool:
        if state.t >= self.problem.T - self.t_tol:
            return True
        return self.S is not None and state.s >= self.S * (1 - 1e-14)

    def limit(self, state: RISState, tau: float) -> float:
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
                result = self._failed_attempt(state, tau, s_end, "data_beyond_T")
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

    def _failed_attempt(self, state: RISState, tau: float, s_end, code: str) -> RISStepResult:
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
            increment=res.d,
            counters=counters,
            problem=p,
            mesh_id=self.space.mesh_id if self.space is not None else 0,
        )

    def adapt(self, state: RISState, result: RISStepResult) -> RISState:
        """The adapt step after the accepted ``result`` (:mod:`rothe.ris.adapt`): with space
        adaptivity, when due and the run goes on, the problem and z_k on a new mesh (a new
        state; the accepted one is never changed); otherwise ``state`` itself."""
        self._adapted = None
        if self.space is None or self.finished(state):
            return state
        t_prev, z_prev = self._start
        out = self.space.adapt(
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
        adapt step did (``transfer_energy``); ``state`` is the state the run goes on from."""
        st = result.state
        adapted = self._adapted
        increment = adapted.increment if adapted is not None else result.increment
        self._previous = (state.z, increment, result.tau)
        space = self.space
        if st.k % self.keep_every == 0:
            traj.append(z=result.problem.full_state(st.z), z_step=st.k)
            if space is not None:
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
        if space is not None:
            traj.append(mesh_id=result.mesh_id, n_dofs=result.problem.n)
            traj.append(**space.ledger(adapted, result))  # transfer_energy, relax_energy, ...

    def where(self, state: RISState, result: RISStepResult | None) -> dict:
        info = {"step": state.k + 1, "s": state.s, "t": state.t}
        if self.space is not None:
            info.update(mesh_id=self.space.mesh_id, dofs=int(self.problem.n))
        if result is not None:
            info.update(
                tau=result.tau, I1=result.I1, I2=result.I2, code=result.code, kkt=result.kkt
            )
        return info

    def progress_fields(self, state: RISState) -> dict:
        fields = {"s": f"{state.s:.5g}", "t": f"{state.t:.5g}", "tau": f"{self._last_tau:.2g}"}
        if self.space is not None:
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
        if self.space is not None:  # the mesh hierarchy and the series of meshes so far
            data["space"] = self.space.checkpoint_state()
        return data

    def restore_state(self, data: dict) -> RISState:
        if data.get("stepper") != "ris":
            raise ValueError(
                f"restore_state: a {data.get('stepper')!r} stepper's state given to a RIS stepper"
            )
        if self.space is not None:
            if data.get("space") is None:
                raise ValueError(
                    "restore_state: a fixed-mesh state given to a space-adaptive RIS stepper"
                )
            self.problem = self.space.restore_state(data["space"])
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


#: the likely cause of a run that stopped after its inner solves kept failing (by result code)
FAILURE_HINTS = {
    "stalled": "the inner solver cannot reach stationarity: dF or d2F probably does not belong "
    "to F (check_derivatives=True compares them with finite differences)",
    "max_iterations": "the inner solver cannot reach stationarity: dF or d2F probably does not "
    "belong to F (check_derivatives=True compares them with finite "
    "differences)",
    "nonfinite": "F, dF, d2F or the load gave a non-finite value (overflow or NaN)",
}


def initial_trajectory(problem: RISProblem, meta: dict | None = None, space=None) -> Trajectory:
    """The trajectory with the initial state; ``space`` (the stepper's RISSpaceAdaptivity):
    z is a ragged series, every state records its mesh id and dofs, the meshes are kept."""
    traj = Trajectory(meta=meta)
    traj.append(
        s=0.0,
        t=0.0,
        z=problem.full_state(problem.z0),
        z_step=0,
        energy=problem.energy(0.0, problem.z0),
    )
    if space is not None:
        _space_trajectory(traj, space)
        traj.append(z_mesh_id=0, mesh_id=0, n_dofs=problem.n)
    return traj


def _space_trajectory(traj: Trajectory, space) -> None:
    traj.set_ragged("z")
    traj.meshes = space.series


def stored_states(traj: Trajectory):
    """(s, t, z) of the states whose z was kept (all of them unless keep_every > 1)."""
    z = traj["z"]
    idx = traj["z_step"] if "z_step" in traj else np.arange(len(z))
    return traj["s"][idx], traj["t"][idx], z


def _keep_last_z(problem, stepper: RISStepper, traj: Trajectory, state: RISState) -> None:
    """With keep_every > 1: make sure z of the last state is kept (once)."""
    steps = traj.entries("z_step")
    if not steps or int(steps[-1]) != state.k:
        traj.append(z=stepper.problem.full_state(state.z), z_step=state.k)
        if stepper.space is not None:
            traj.append(z_mesh_id=stepper.space.mesh_id)


def _evolve_ris(problem, stepper, controller, traj, state, *, tau_min, progress, checkpointer):
    try:
        state = evolve(
            stepper,
            controller,
            state,
            traj,
            tau_min=tau_min,
            progress=progress,
            checkpointer=checkpointer,
        )
    except RunInterrupted as exc:
        if exc.state is not None:
            _keep_last_z(problem, stepper, traj, exc.state)
        raise
    except RunFailed as exc:
        hint = FAILURE_HINTS.get(exc.where.get("code"))
        if hint and exc.args and "stagnation_window" not in exc.where:
            exc.args = (f"{exc.args[0]}; {hint}",) + exc.args[1:]
        raise
    finally:
        traj.meta["linear_solver"] = stepper.solver.linear.kind_used
        if stepper.space is not None:  # space_adaptations, transfer_failures, ...
            traj.meta.update(stepper.space.meta())
    _keep_last_z(problem, stepper, traj, state)
    traj.meta["landing"] = landing_record(stepper, state)
    return state


def _where(traj: Trajectory, state: RISState) -> dict:
    st = traj.stats
    return {
        "accepted_steps": st.accepted_steps,
        "rejected_steps": st.rejected_steps,
        "s": float(state.s),
        "t": float(state.t),
    }


def run_ris(
    problem: RISProblem,
    control: str = "adaptive",
    *,
    tol: float | None = 1e-4,
    tau: float = 0.1,
    tau_min: float = 1e-12,
    tau_max: float = math.inf,
    grid=None,
    S: float | None = None,
    inner: InnerOptions | None = None,
    simpson_subintervals: int = 8,
    progress=False,
    meta: dict | None = None,
    keep_every: int = 1,
    checkpoint=None,
    resume=None,
    space=None,
) -> Trajectory:
    """Run the scheme from (0, 0, z0) until t reaches T (or s reaches S).

    ``space``: a :class:`~rothe.fem.adapt.SpaceAdaptivity` adapts the P1 mesh of a
    :class:`~rothe.ris.fem_problem.FERISProblem` after every ``adapt_every``-th accepted step
    (:mod:`rothe.ris.adapt`); None keeps the problem's mesh (the run is then exactly
    the fixed-mesh one). With it, ``traj["z"]`` is a list (one array per stored state, on its
    mesh), ``z_mesh_id`` / ``mesh_id`` / ``n_dofs`` say which mesh each state lives on,
    ``transfer_energy`` per step the energy change by the transfer, and ``traj.meshes`` keeps
    every distinct mesh once.

    ``keep_every = k`` keeps z of every k-th accepted state and of the last one (the other series
    are kept for every step; ``z_step`` says which steps z holds, :func:`stored_states`).
    ``meta['linear_solver']`` records the linear solver that ran. ``progress``: bool or
    :class:`~rothe.stepping.progress.ProgressOptions`.

    ``checkpoint``: a directory or :class:`~rothe.io.checkpoint.CheckpointOptions` (interval,
    default 60 s); a checkpoint is written at the start, every interval, when the run stops and
    at the end. ``resume``: a checkpoint directory written by ``run_ris`` with the same
    arguments and problem (else :class:`~rothe.io.checkpoint.CheckpointError`); the run
    continues from it and returns the trajectory the uninterrupted run would have returned, bit
    for bit (the statistics too, except the wall time, which sums the sessions).

    Raises :class:`RunFailed` (with ``.trajectory``) when the step size would fall below
    ``tau_min``, and :class:`~rothe.errors.RunInterrupted` (with ``.trajectory`` and
    ``.checkpoint``) when SIGINT or SIGTERM arrives; both carry the trajectory computed so far.
    """
    controller = make_controller(
        control, tol=tol, tau=tau, tau_min=tau_min, tau_max=tau_max, grid=grid
    )
    stepper = RISStepper(
        problem, inner, simpson_subintervals, S=S, keep_every=keep_every, space=space
    )
    info = {"example": problem.name, "control": controller.name, "tol": tol, "tau0": tau}
    if space is not None:
        info["space"] = space.describe()
    info.update(meta or {})
    extra = {} if space is None else {"space": space.describe()}
    arguments = run_arguments(
        control=control,
        tol=tol,
        tau=tau,
        tau_min=tau_min,
        tau_max=tau_max,
        grid=None if grid is None else np.asarray(grid, dtype=float),
        S=S,
        inner=asdict(inner or InnerOptions()),
        simpson_subintervals=simpson_subintervals,
        keep_every=keep_every,
        **extra,
    )
    with RunCheckpointing("run_ris", problem, arguments, checkpoint, resume) as rc:
        cp, restored = rc.checkpointer, rc.restored
        if restored is not None:
            traj = restored.trajectory(0)
            traj.meta.update(info)
            state = stepper.restore_state(restored.state["stepper"])
            if stepper.space is not None:
                _space_trajectory(traj, stepper.space)
            controller.restore_state(restored.state["controller"])
            traj.meta["sessions"] = restored.sessions + 1
        else:
            traj = initial_trajectory(problem, info, stepper.space)
            state = RISState(s=0.0, t=0.0, z=problem.z0.copy())
        if cp is not None:
            cp.register(traj)
            if restored is None:
                cp.save_or_warn(stepper, controller, state, where=_where(traj, state))
        state = _evolve_ris(
            problem,
            stepper,
            controller,
            traj,
            state,
            tau_min=tau_min,
            progress=progress,
            checkpointer=cp,
        )
        if cp is not None:
            cp.save_or_warn(
                stepper, controller, state, status="completed", where=_where(traj, state)
            )
    return traj


def landing_record(stepper: RISStepper, state: RISState) -> dict:
    """How the run ended: on T within ``t_tol`` = 1e-10 max(1, T) (``landed``), or at S.

    ``t_final_minus_T`` is the signed miss; ``landed`` is False only if the landing iteration
    (at most ``max_landing_retries`` shortened attempts of the last step) did not reach the
    tolerance, in which case the last accepted step is the attempt closest to T.
    """
    T = stepper.problem.T
    ended_by_S = stepper.S is not None and state.t < T - stepper.t_tol
    return {
        "ended_by": "S" if ended_by_S else "T",
        "T": T,
        "t_final": float(state.t),
        "t_final_minus_T": float(state.t - T),
        "tolerance": stepper.t_tol,
        "landed": bool(ended_by_S or abs(state.t - T) <= stepper.t_tol),
    }


def run_nested(
    problem: RISProblem,
    tols,
    *,
    tau: float = 0.1,
    tau_min: float = 1e-12,
    tau_max: float = math.inf,
    inner: InnerOptions | None = None,
    simpson_subintervals: int = 8,
    progress=False,
    keep_every: int = 1,
    checkpoint=None,
    resume=None,
    space=None,
) -> list[Trajectory]:
    """Alg. 6.2: runs for tol_1 > tol_2 > ...; run n never steps over a grid point of runs < n.

    ``checkpoint`` / ``resume`` as for :func:`run_ris`; a checkpoint holds the finished runs and
    the state of the one under way. ``space`` as for :func:`run_ris`: every run adapts its own
    mesh hierarchy from the problem's mesh.
    """
    from ..errors import check_decreasing

    tols = check_decreasing("tols", tols)
    extra = {} if space is None else {"space": space.describe()}
    arguments = run_arguments(
        tols=tols,
        tau=tau,
        tau_min=tau_min,
        tau_max=tau_max,
        inner=asdict(inner or InnerOptions()),
        simpson_subintervals=simpson_subintervals,
        keep_every=keep_every,
        **extra,
    )
    with RunCheckpointing("run_nested", problem, arguments, checkpoint, resume) as rc:
        cp, restored = rc.checkpointer, rc.restored
        runs: list[Trajectory] = []
        start = 0
        if restored is not None:
            start = int(restored.state["run"]["nested_index"])
            runs = [restored.trajectory(i) for i in range(start)]
            if space is not None:  # the finished runs' meshes are in the checkpoint's context
                from ..io.mesh_series import MeshSeries

                for r, data in zip(runs, restored.state["run"].get("series", []), strict=False):
                    r.meshes = MeshSeries.restore_state(data)
            if cp is not None:
                for r in runs:
                    cp.register(r)
        grid = np.empty(0)
        for r in runs:
            grid = np.union1d(grid, r["s"][1:])
        for i in range(start, len(tols)):
            tol = tols[i]
            nested = i > 0
            controller = make_controller(
                "nested" if nested else "adaptive",
                tol=tol,
                tau=tau,
                tau_min=tau_min,
                tau_max=tau_max,
                grid=grid if nested else None,
            )
            stepper = RISStepper(
                problem, inner, simpson_subintervals, keep_every=keep_every, space=space
            )
            info = {
                "example": problem.name,
                "control": controller.name,
                "tol": tol,
                "tau0": tau,
                "nested_index": i,
            }
            if space is not None:
                info["space"] = space.describe()
            if cp is not None:
                cp.context = {"nested_index": i}
                if space is not None:
                    cp.context["series"] = [r.meshes.checkpoint_state() for r in runs]
            if restored is not None and i == start:
                traj = restored.trajectory(i)
                traj.meta.update(info)
                traj.meta["sessions"] = restored.sessions + 1
                state = stepper.restore_state(restored.state["stepper"])
                if stepper.space is not None:
                    _space_trajectory(traj, stepper.space)
                controller.restore_state(restored.state["controller"])
                if cp is not None:
                    cp.register(traj)
            else:
                traj = initial_trajectory(problem, info, stepper.space)
                state = RISState(s=0.0, t=0.0, z=problem.z0.copy())
                if cp is not None:
                    cp.register(traj)
                    cp.save_or_warn(stepper, controller, state, where=_where(traj, state))
            try:
                state = _evolve_ris(
                    problem,
                    stepper,
                    controller,
                    traj,
                    state,
                    tau_min=tau_min,
                    progress=progress,
                    checkpointer=cp,
                )
            except RunFailed as exc:
                exc.where["nested_tol"] = tol
                raise
            runs.append(traj)
            grid = np.union1d(grid, traj["s"][1:])
        if cp is not None:
            cp.context = {"nested_index": len(tols)}
            if space is not None:
                cp.context["series"] = [r.meshes.checkpoint_state() for r in runs]
            last = runs[-1]
            cp.save_or_warn(
                status="completed",
                where={
                    "accepted_steps": last.stats.accepted_steps,
                    "s": float(last["s"][-1]),
                    "t": float(last["t"][-1]),
                },
            )
    return runs
