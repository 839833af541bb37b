"""CLI commands for rate-independent systems: ``rothe run|compare ris-1d`` (and FE examples)."""

from __future__ import annotations

import math
import sys
from abc import ABC, abstractmethod

import numpy as np

from ..errors import (
    RunFailed,
    check_choice,
    check_decreasing,
    check_positive,
    described,
    fail,
)
from ..parallel.executor import add_parallel_options, executor_from_args
from ..ris.controllers import CONTROLS
from ..ris.stepper import run_nested, run_ris
from .common import (
    add_output_options,
    given,
    output_dir,
    parse_float,
    parse_float_list,
    print_summary,
    write_summary,
    write_table,
)
from .registry import command
from .session import RunSession, add_run_options

SUMMARY_KEYS = (
    "example",
    "control",
    "tol",
    "tols",
    "accepted_steps",
    "rejected_steps",
    "inner_solves",
    "newton_iterations",
    "t_final",
    "s_final",
    "max_residual",
    "sum_residual",
    "error_l2",
    "error_linf",
    "wall_time_s",
)


def ris_summary(traj, example: str, extra: dict | None = None) -> dict:
    """The summary.json fields of one RIS trajectory (README, "Where results go")."""
    st = traj.stats

    def steps(key):  # a run that failed at its first step has no step series at all
        return traj[key] if key in traj else np.zeros(0)

    I1, I2 = steps("I1"), steps("I2")
    res = I1 + I2 if len(I1) else np.zeros(0)
    meta = traj.meta
    summary = {
        "example": example,
        "control": meta.get("control"),
        "tol": meta.get("tol"),
        "tau0": meta.get("tau0"),
        "accepted_steps": st.accepted_steps,
        "rejected_steps": st.rejected_steps,
        "inner_solves": st.inner_solves,
        "newton_iterations": st.newton_iterations,
        "fb_steps": st.fb_steps,
        "linear_factorizations": st.linear_factorizations,
        "landing_retries": st.landing_retries,
        "t_final": float(traj["t"][-1]),
        # how the run ended: on T within 1e-10 max(1, T), or at S (rothe.ris.stepper)
        "landing": meta.get("landing"),
        "s_final": float(traj["s"][-1]),
        "max_residual": float(res.max()) if res.size else 0.0,
        "sum_residual": float(res.sum()) if res.size else 0.0,
        "min_I2": float(I2.min()) if I2.size else 0.0,
        "max_kkt_residual": float(steps("kkt").max()) if len(traj) else 0.0,
        "max_multiplier": float(steps("lam").max()) if len(traj) else 0.0,
        "energy_final": float(traj["energy"][-1]),
        "wall_time_s": st.wall_time_s,
        "status": "completed",
    }
    summary.update(extra or {})
    return summary


#: The options each step control reads. An option written on the command line that the chosen
#: control does not read is refused (exit 2), never silently dropped: ``--control nested --tol
#: 1e-6`` would otherwise run the default tolerances. A control missing from this table (a new
#: one) is taken to read ``--tol`` like adaptive and order2; tests/cli checks that every name
#: in CONTROLS is listed.
CONTROL_OPTIONS = {
    "uniform": (),
    "adaptive": ("--tol",),
    "order2": ("--tol",),
    "nested": ("--tols",),
    "regime": ("--tol",),
}
#: the options that only some controls read (--tau, --tau-min, ... are read by all)
CONTROL_SPECIFIC = ("--tol", "--tols")
#: smallest --tau-min relative to max(1, T): below it s + tau == s in double precision for
#: curve parameters of the size of T
STEP_FLOOR = 1e-14


def control_options(control: str) -> tuple[str, ...]:
    return CONTROL_OPTIONS.get(control, ("--tol",))


def check_control_options(args, control: str) -> None:
    """Refuse options the chosen control ignores (see CONTROL_OPTIONS)."""
    for option in CONTROL_SPECIFIC:
        if given(args, option) and option not in control_options(control):
            users = [c for c in CONTROLS if option in control_options(c)]
            value = getattr(args, option.lstrip("-").replace("-", "_"))
            if isinstance(value, list):
                value = described(",".join(f"{v:g}" for v in value))
            reads = (
                "it reads " + ", ".join(control_options(control))
                if control_options(control)
                else "no tolerance: its step is --tau"
            )
            raise fail(
                option,
                value,
                f"is not used by --control {control} ({reads}); "
                f"{option} is for --control {' or '.join(users)}",
            )


def check_step(option: str, value, T: float, tau_min: float = 1e-12) -> float:
    """A step size of a compare run: tau_min <= tau <= T (the runs stop below tau_min)."""
    tau = check_positive(option, value)
    if tau < tau_min:
        raise fail(option, tau, f"must be >= {tau_min:g} (the smallest step tau_min of the runs)")
    if tau > T:
        raise fail(option, tau, f"must be <= T (= {T:g}), the end time of the run")
    return tau


# -- work against residual: the ratios of compare ris-2d (issue 12), shared with the benchmarks --

#: the keys of a row of compare.json, in this order
COMPARE_KEYS = (
    "control",
    "tol",
    "tau",
    "accepted",
    "rejected",
    "solves",
    "newton",
    "seconds",
    "local_residual",
    "global_residual",
    "ratio_steps",
    "ratio_solves",
    "ratio_seconds",
)


def equidistribution_bound(residuals) -> float | None:
    """(sum_k sqrt(J_k))^2 / (M sum_k J_k) over the pair means J_k = (I_k + I_{k+1}) / 2 of the
    residuals I_k = I1^k + I2^k of a uniform run (M = N - 1 pairs).

    A lower bound for the accepted steps of *any* step sequence, as a fraction of the uniform
    run's, at the same global residual G, when the residual of a step is I = C(s) tau^2 with a
    density C(s) that the steps do not change (Lemma 5.3): by Cauchy-Schwarz,
    (sum_k sqrt(I_k))^2 <= N sum_k I_k = N G, and sum_k sqrt(I_k) = sum_k sqrt(C(s_k)) tau_k
    ~ int sqrt(C) ds is the same for every sequence; equality holds when all I_k are equal. For a
    uniform run, sqrt(C_k) tau = sqrt(I_k), so its own steps give C. Pair means, because in slip
    the time increments carry a period-2 oscillation, dt_k = tau - v dt_{k-1} (neutral in
    Example 7.1, v = 1): single residuals alternate between two levels at a fixed density --
    there I1 = L dt_k (dt_{k-1} + dt_k) / 2, whose sum over a pair does not depend on the phase --
    and Cauchy-Schwarz over the raw steps would give a bound no step sequence reaches (0.19
    instead of the 0.375 of Example 7.1). None without residual.
    """
    I = np.maximum(np.asarray(residuals, dtype=float), 0.0)
    if I.size < 2 or I.sum() <= 0.0:
        return None
    J = 0.5 * (I[1:] + I[:-1])
    return float(np.sum(np.sqrt(J)) ** 2 / (J.size * J.sum()))


#: work measures of a run (key of its summary row) and the ratio they enter in compare.json
WORK_RATIOS = (
    ("accepted_steps", "ratio_steps"),
    ("inner_solves", "ratio_solves"),
    ("wall_time_s", "ratio_seconds"),
)


def uniform_work_interpolant(rows, work: str, key: str = "sum_residual"):
    """Work of the uniform scheme at a given global residual, interpolated log-log between the
    two uniform runs whose residuals bracket it; None outside their range (no extrapolation).

    Returns a callable residual -> work or None, or None if fewer than two uniform runs completed.
    """
    u = sorted(
        (r[key], r[work])
        for r in rows
        if r["control"] == "uniform"
        and r.get("status", "completed") == "completed"
        and r.get(key, 0) > 0
        and r.get(work, 0) > 0
    )
    if len(u) < 2:
        return None
    x = np.log([g for g, _ in u])
    y = np.log([w for _, w in u])

    def work_at(residual: float) -> float | None:
        if not residual > 0:
            return None
        lx = math.log(residual)
        # a residual equal to the smallest/largest uniform one (to round-off) is in range
        if lx < x[0] - 1e-12 or lx > x[-1] + 1e-12:
            return None
        return float(np.exp(np.interp(lx, x, y)))

    return work_at


def compare_rows(rows) -> list[dict]:
    """The rows of compare.json (keys :data:`COMPARE_KEYS`, in that order) from summary rows.

    ``ratio_steps``, ``ratio_solves``, ``ratio_seconds``: the run's accepted steps, inner solves
    and seconds divided by the uniform scheme's at the same global residual sum_k(I1 + I2)
    (:func:`uniform_work_interpolant`); null for the uniform rows, for a residual outside the
    uniform runs' range, and for a run that did not complete.
    """
    interp = {ratio: uniform_work_interpolant(rows, work) for work, ratio in WORK_RATIOS}
    out = []
    for r in rows:
        uniform = r["control"] == "uniform"
        # a run that produced nothing (an error, a lost task) has its status only: nulls
        row = {
            "control": r["control"],
            "tol": None if uniform else r["tol"],
            "tau": r["tau0"],
            "accepted": r.get("accepted_steps"),
            "rejected": r.get("rejected_steps"),
            "solves": r.get("inner_solves"),
            "newton": r.get("newton_iterations"),
            "seconds": r.get("wall_time_s"),
            "local_residual": r.get("max_residual"),
            "global_residual": r.get("sum_residual"),
        }
        for work, ratio in WORK_RATIOS:
            fn = interp[ratio]
            base = None
            if (
                not uniform
                and fn is not None
                and r.get("status", "completed") == "completed"
                and work in r
            ):
                base = fn(r["sum_residual"])
            row[ratio] = None if base is None else r[work] / base
        assert tuple(row) == COMPARE_KEYS
        out.append(row)
    return out


class RISRunBase(ABC):
    """Shared ``run`` logic; subclasses provide the problem and example-specific output."""

    name = "ris"
    default_tau = 0.1
    T = 1.0  # end time of the example

    def add_example_options(self, parser) -> None:
        """Optional hook: options of this example (none by default)."""
        return None

    def configure(self, parser) -> None:
        parser.add_argument(
            "--control",
            default="adaptive",
            help="adaptive | uniform | nested | order2 | regime (default adaptive; regime: "
            "every step at the same residual, Alg. 3.2's acceptance)",
        )
        parser.add_argument(
            "--tol",
            type=parse_float("--tol"),
            default=1e-4,
            help="residual tolerance of adaptive/order2/regime (default 1e-4)",
        )
        parser.add_argument(
            "--tols",
            type=parse_float_list("--tols"),
            default=None,
            help="decreasing tolerances for --control nested (default 1e-3,1e-4,1e-5)",
        )
        parser.add_argument(
            "--tau",
            type=parse_float("--tau"),
            default=None,
            help=f"fixed step (uniform) or first step (default {self.default_tau})",
        )
        parser.add_argument(
            "--tau-min",
            type=parse_float("--tau-min"),
            default=1e-12,
            help="smallest step before the run stops with an error (default 1e-12)",
        )
        parser.add_argument(
            "--simpson",
            type=int,
            default=8,
            help="Simpson subintervals for I1, I2 (even, default 8)",
        )
        parser.add_argument(
            "--keep-every",
            type=int,
            default=1,
            help="keep z of every K-th accepted state and of the last (default 1: all); "
            "the other series are kept for every step",
        )
        self.add_example_options(parser)
        add_output_options(parser, self.name)
        add_run_options(parser)

    # hooks -----------------------------------------------------------------------------------
    @abstractmethod
    def build_problem(self, args):
        """The RISProblem of this example from the parsed options."""

    def extra_summary(self, args, problem, traj) -> dict:
        return {}

    def write_extra(self, args, problem, traj, out) -> None:
        """Optional hook: extra output files (none by default)."""
        return None

    def exact(self):
        return None

    def summary_at_end(self, args) -> dict:
        """Fields measured last, just before summary.json is written (e.g. peak memory)."""
        return {}

    def inner_options(self, args):
        """InnerOptions for the run (None: the solver's defaults)."""
        return None

    def run_options(self, args) -> dict:
        """Extra keyword arguments of run_ris / run_nested (e.g. ``space``); none by default."""
        return {}

    # ------------------------------------------------------------------------------------------
    def validate(self, args):
        control = check_choice("--control", args.control, CONTROLS)
        check_control_options(args, control)
        tol = check_positive("--tol", args.tol)
        tau = check_positive("--tau", args.tau if args.tau is not None else self.default_tau)
        tau_min = check_positive("--tau-min", args.tau_min)
        T = self.end_time(args)
        smallest = STEP_FLOOR * max(1.0, T)
        if tau_min < smallest:
            raise fail(
                "--tau-min",
                tau_min,
                f"must be >= {smallest:g} (1e-14 max(1, T): a "
                "smaller step vanishes in the round-off of s)",
            )
        if tau > T:
            raise fail("--tau", tau, f"must be <= T (= {T:g}), the end time of the run")
        if tau_min > tau:
            raise fail("--tau-min", tau_min, f"must be <= --tau (= {tau:g})")
        tols = None
        if control == "nested":
            tols = check_decreasing("--tols", args.tols or [1e-3, 1e-4, 1e-5])
        if args.keep_every < 1:
            raise fail("--keep-every", args.keep_every, "must be an integer >= 1")
        if args.simpson < 2 or args.simpson % 2:
            raise fail("--simpson", args.simpson, "must be an even integer >= 2")
        return control, tol, tau, tau_min, tols

    def end_time(self, args) -> float:
        """T of the example (bounds --tau); validated before the problem is built."""
        return self.T

    def execute(self, args) -> int:
        control, tol, tau, tau_min, tols = self.validate(args)
        problem = self.build_problem(args)
        session = RunSession(args, self.name)
        common = dict(
            tau=tau,
            tau_min=tau_min,
            simpson_subintervals=args.simpson,
            inner=self.inner_options(args),
            keep_every=args.keep_every,
        )
        common.update(self.run_options(args))

        def run(**kw):
            if control == "nested":
                return run_nested(problem, tols, **common, **kw)
            return [
                run_ris(problem, control, tol=None if control == "uniform" else tol, **common, **kw)
            ]

        with session:
            if session.already_completed:
                print(
                    f"rothe: {session.out}: the run already completed; its results are there",
                    file=sys.stderr,
                )
                return 0
            outcome = session.run(run)
            results = session.results_dir(outcome.status)
            if outcome.status == "completed" or outcome.result is not None:
                with session.outputs(outcome.status) as stage:
                    summary = self.write_results(
                        args, problem, outcome, stage, session, control, tols, tau
                    )
            code = session.finish(outcome, results)
        if outcome.status == "completed" and not args.quiet:
            print(f"rothe run {self.name}: wrote {results}/")
            print_summary(summary, SUMMARY_KEYS + tuple(self.summary_keys_extra()))
        return code

    def write_results(self, args, problem, outcome, out, session, control, tols, tau) -> dict:
        """Every output file of the run into ``out`` (the staging directory), summary last."""
        if outcome.status == "completed":
            runs = outcome.result
            traj = runs[-1]
        else:
            traj = outcome.result
            runs = [traj]
        summary = ris_summary(traj, self.name, self.extra_summary(args, problem, traj))
        if control == "nested" and outcome.status == "completed":
            summary["control"] = "nested"
            summary["tols"] = tols
            summary["runs"] = [
                ris_summary(r, self.name, self.extra_summary(args, problem, r)) for r in runs
            ]
            for i, r in enumerate(runs):
                r.save_npz(out / f"nested_{i}.npz")
        summary["tau0"] = tau
        traj.save_npz(out / "trajectory.npz", extra=self.npz_extra(problem))
        self.write_extra(args, problem, traj, out)
        if not args.no_plots and outcome.status == "completed":
            self.plot(args, problem, runs, out)
        summary.update(self.summary_at_end(args))
        session.annotate(summary, outcome)
        write_summary(out, summary)
        return summary

    def summary_keys_extra(self):
        return ()

    def npz_extra(self, problem) -> dict:
        return {}

    def plot(self, args, problem, runs, out) -> None:
        from ..ris.figures import plot_path, plot_steps

        traj = runs[-1]
        label = f"{self.name}, {traj.meta.get('control')}"
        if traj.meta.get("tol") is not None:
            label += f", tol={traj.meta['tol']:g}"
        plot_path(traj, out / "fig1_path.png", exact=self.exact(), title=label)
        plot_steps(traj, out / "fig2_steps.png", title=label)


@command("run", "ris-1d")
class RunRIS1D(RISRunBase):
    help = "Example 7.1 of Andreia & Meyer (2022): 1-D RIS with exact BV solution (7.1)"
    name = "ris-1d"
    default_tau = 0.1
    T = 5.0  # example_7_1()

    def validate(self, args):
        if args.keep_every != 1:
            raise fail(
                "--keep-every",
                args.keep_every,
                "must be 1 for ris-1d (one unknown; the errors against (7.1) need every state)",
            )
        return super().validate(args)

    def build_problem(self, args):
        from ..ris.examples import example_7_1

        return example_7_1()

    def exact(self):
        from ..ris.examples import exact_solution

        return exact_solution

    def extra_summary(self, args, problem, traj) -> dict:
        from ..ris.examples import errors_against_exact

        return errors_against_exact(traj["s"], traj["t"], traj["z"])


def run_cost(tol: float | None, tau: float) -> float:
    """Relative run time of a compare run, to start the longest first: uniform ~ 1/tau steps,
    adaptive/order2 ~ 10 tol^(-1/2) (the accepted steps grow like tol^(-1/2); on Example 7.2 at
    40 x 40 adaptive at tol = 1e-6 took 294 s and uniform at tau = 7.8e-5 253 s)."""
    return 1.0 / tau if tol is None else 10.0 * tol**-0.5


def compare_ris_1d_row(control: str, tol: float | None, tau: float, uniform: bool) -> dict:
    """One run of ``compare ris-1d`` (a task: builds Example 7.1 itself); its table row."""
    from ..parallel import TaskFailed
    from ..ris.examples import errors_against_exact, example_7_1

    try:
        traj = run_ris(example_7_1(), control, tol=tol, tau=tau)
        failure = None
    except RunFailed as exc:  # keep the table: a failed run is a row with its status
        traj, failure = exc.trajectory, exc
    if traj is None or len(traj) == 0:
        row = {"control": control, "tol": tol, "tau0": tau}
    else:
        row = ris_summary(traj, "ris-1d", errors_against_exact(traj["s"], traj["t"], traj["z"]))
        if uniform:
            row["tau0"] = tau
    row["status"] = "completed" if failure is None else f"failed: {failure}"
    if failure is not None:
        raise TaskFailed(str(failure), value=row)
    return row


def compare_ris_1d(
    tols=(1e-3, 1e-4, 1e-5, 1e-6),
    taus=(0.1, 0.05, 0.02, 0.01, 0.005, 0.002, 0.001),
    tau0=0.1,
    controls=("adaptive", "order2", "regime"),
    executor=None,
) -> list[dict]:
    """Run the ``controls`` over ``tols`` and uniform over ``taus`` on Example 7.1; one row each.

    The runs are independent tasks of ``executor`` (:class:`rothe.parallel.Executor`; default:
    one after another in this process); a run that fails is a row with its status.
    """
    from ..parallel import Executor, Task

    tasks = [
        Task(
            f"{c} tol={tol:g}",
            compare_ris_1d_row,
            {"control": c, "tol": tol, "tau": tau0, "uniform": False},
            cost=run_cost(tol, tau0),
        )
        for c in controls
        for tol in tols
    ]
    tasks += [
        Task(
            f"uniform tau={tau:g}",
            compare_ris_1d_row,
            {"control": "uniform", "tol": None, "tau": tau, "uniform": True},
            cost=run_cost(None, tau),
        )
        for tau in taus
    ]
    results = (executor or Executor(1, progress=False)).map(tasks)
    return [
        r.value
        if isinstance(r.value, dict)
        else {
            "control": t.kwargs["control"],
            "tol": t.kwargs["tol"],
            "tau0": t.kwargs["tau"],
            "status": f"{r.status}: {r.message}",
        }
        for t, r in zip(tasks, results, strict=True)
    ]


def uniform_work_at_error(rows, key="error_linf"):
    """Fit log(inner solves) = a + b log(error) over the completed uniform rows; returns a
    callable (None with fewer than two such rows)."""
    u = [
        r for r in rows if r["control"] == "uniform" and r.get("status", "completed") == "completed"
    ]
    if len(u) < 2:
        return None
    x = np.log([r[key] for r in u])
    y = np.log([r["inner_solves"] for r in u])
    b, a = np.polyfit(x, y, 1)
    return lambda err: float(np.exp(a + b * np.log(err)))


def format_table(rows, work_fit=None) -> str:
    head = (
        f"{'control':<9} {'tol/tau':>8} {'accepted':>8} {'rejected':>8} {'solves':>7} "
        f"{'L2 err':>9} {'Linf err':>9} {'seconds':>8}"
    )
    if work_fit is not None:
        head += f" {'solves/uniform@Linf':>20}"
    lines = [head, "-" * len(head)]
    for r in rows:
        par = r["tau0"] if r["control"] == "uniform" else r["tol"]
        if "accepted_steps" not in r:  # a run that produced nothing: its status only
            lines.append(f"{r['control']:<9} {par:>8.0e}  {r['status']}")
            continue
        line = (
            f"{r['control']:<9} {par:>8.0e} {r['accepted_steps']:>8d} {r['rejected_steps']:>8d} "
            f"{r['inner_solves']:>7d} {r['error_l2']:>9.2e} {r['error_linf']:>9.2e} "
            f"{r['wall_time_s']:>8.3f}"
        )
        if work_fit is not None:
            ratio = (
                r["inner_solves"] / work_fit(r["error_linf"])
                if r["control"] != "uniform" and r.get("status", "completed") == "completed"
                else math.nan
            )
            line += f" {ratio:>20.2f}" if math.isfinite(ratio) else f" {'':>20}"
        if r.get("status", "completed") != "completed":
            line += "  " + r["status"]
        lines.append(line)
    return "\n".join(lines)


@command("compare", "ris-1d")
class CompareRIS1D:
    help = (
        "Fig. 3 of Andreia & Meyer: error against steps, adaptive/order2/regime vs uniform "
        "(Ex. 7.1)"
    )

    def configure(self, parser) -> None:
        parser.add_argument(
            "--tols", type=parse_float_list("--tols"), default=[1e-3, 1e-4, 1e-5, 1e-6]
        )
        parser.add_argument(
            "--taus",
            type=parse_float_list("--taus"),
            default=[0.1, 0.05, 0.02, 0.01, 0.005, 0.002, 0.001],
        )
        add_output_options(parser, "compare-ris-1d")
        add_parallel_options(parser)

    def execute(self, args) -> int:
        tols = [check_positive("--tols", x) for x in args.tols]
        taus = [check_step("--taus", x, RunRIS1D.T) for x in args.taus]
        if len(taus) < 2:
            raise fail("--taus", ",".join(map(str, taus)), "needs at least two step sizes")
        executor = executor_from_args(args, "rothe compare ris-1d")
        out = output_dir(args, "compare-ris-1d")
        rows = compare_ris_1d(tols, taus, executor=executor)
        fit = uniform_work_at_error(rows)
        table = format_table(rows, fit)
        write_table(out, table + "\n")
        write_summary(out, {"example": "ris-1d", "rows": rows})
        if not args.no_plots:
            from ..ris.figures import plot_error_vs_work

            plot_error_vs_work(
                [r for r in rows if r["status"] == "completed"],
                out / "fig3_error_vs_steps.png",
                title="Example 7.1: error against number of steps",
            )
        if not args.quiet:
            print(table)
            print(f"wrote {out}/")
        return 0 if all(r["status"] == "completed" for r in rows) else 1
