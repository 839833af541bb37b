"""CLI commands for rate-independent systems: ``rothe run|compare ris-1d`` (and FE examples).

The names of ``--control`` become step-control objects in one place (:func:`control_object`);
the run's summary and the work ratios of a comparison are :mod:`rothe.ris.summary`.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

from ..errors import (
    RunFailed,
    check_choice,
    check_decreasing,
    check_positive,
    described,
    fail,
    integer_allowed,
)
from ..parallel import Executor, Task, TaskFailed
from ..ris import examples
from ..ris.controllers import Nested, Order2, Regime
from ..ris.run import run_nested, run_ris
from ..ris.summary import ris_summary, uniform_work_at_error
from ..stepping.controllers import Adaptive, Uniform
from .common import (
    add_output_options,
    add_parallel_options,
    dofs_keys,
    executor_from_args,
    float_option,
    given,
    output_dir,
    parse_float_list,
    print_summary,
    write_summary,
    write_table,
)
from .registry import command
from .session import add_run_options, run_sequence

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


def summary_notes(summary: dict) -> dict:
    """Remarks on the summary lines of a RIS run: with Alg. 3.2 (``adaptive``, ``nested``) the
    rejections per acceptance and why there are so many (docs/ris.md, *Step control*); with
    --adapt-space the transfer and relaxation energy as shares of the path's dissipation."""
    notes = {}
    dissipation = summary.get("dissipation_sum")
    if dissipation:  # --adapt-space: the mesh changes' energy against the path's dissipation
        for key in ("transfer_energy_abs_sum", "relax_energy_sum"):
            if summary.get(key) is not None:
                notes[key] = f"{summary[key] / dissipation:.2g} of the dissipation"
    accepted, rejected = summary.get("accepted_steps"), summary.get("rejected_steps")
    if summary.get("control") not in ("adaptive", "nested") or not accepted or not rejected:
        return notes
    notes["rejected_steps"] = (
        f"{rejected / accepted:.2f} per accepted step: Alg. 3.2's double/"
        "reject cycle -- after a step with I1, I2 < tol/2 the step is doubled, the doubled "
        "attempt rejected and halved again -- rejects up to one attempt per acceptance"
    )
    return notes


#: ``--control`` NAME -> the step-control object of the options (--tol, --tols, --tau,
#: --tau-min); the one place where the command line's names become objects
CONTROL_OBJECTS = {
    "adaptive": lambda tol, tols, tau, tau_min: Adaptive(tol, tau=tau, tau_min=tau_min),
    "uniform": lambda tol, tols, tau, tau_min: Uniform(tau, tau_min=tau_min),
    "nested": lambda tol, tols, tau, tau_min: Nested(tols, tau=tau, tau_min=tau_min),
    "order2": lambda tol, tols, tau, tau_min: Order2(tol, tau=tau, tau_min=tau_min),
    "regime": lambda tol, tols, tau, tau_min: Regime(tol, tau=tau, tau_min=tau_min),
}
#: the values of --control
CONTROLS = tuple(CONTROL_OBJECTS)


def control_object(control: str, *, tol=None, tols=None, tau: float, tau_min=None):
    """The step-control object of ``--control`` ``control`` (a name of :data:`CONTROLS`)."""
    return CONTROL_OBJECTS[control](tol, tols, tau, tau_min)


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
    """The options of :data:`CONTROL_SPECIFIC` that ``--control`` ``control`` reads."""
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


class RISRunBase(ABC):
    """Shared ``run`` logic; subclasses provide the problem and example-specific output."""

    name = "ris"
    default_tau = 0.1
    #: default --control
    default_control = "adaptive"
    #: --tol of the residual controls (adaptive, order2, regime)
    default_tol = 1e-4
    #: --tols of the nested control (its passes, decreasing; the last equals default_tol / 10)
    default_tols = (1e-3, 1e-4, 1e-5)
    T = 1.0  # end time of the example

    def add_example_options(self, parser) -> None:
        """Optional hook: options of this example (none by default)."""
        return None

    def configure(self, parser) -> None:
        """The options of every RIS run: the step control, Simpson, keep-every, outputs."""
        parser.add_argument(
            "--control",
            default=self.default_control,
            help=f"adaptive | uniform | nested | order2 | regime (default {self.default_control}; "
            "regime: every step at the same residual, Alg. 3.2's acceptance)",
        )
        float_option(
            parser,
            "--tol",
            default=self.default_tol,
            help=f"residual tolerance of adaptive/order2/regime (default {self.default_tol:g})",
        )
        parser.add_argument(
            "--tols",
            type=parse_float_list("--tols"),
            default=None,
            help="decreasing tolerances for --control nested (default "
            + ",".join(f"{x:g}" for x in self.default_tols)
            + ")",
        )
        float_option(
            parser,
            "--tau",
            default=None,
            help=f"fixed step (uniform) or first step (default {self.default_tau})",
        )
        float_option(
            parser,
            "--tau-min",
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
        """Fields of summary.json particular to the example (none by default)."""
        return {}

    def write_extra(self, args, problem, traj, out) -> None:
        """Optional hook: extra output files (none by default)."""
        return None

    def exact(self):
        """(t(s), z(s)) of an exact solution to draw beside the run, or None."""
        return None

    def summary_at_end(self, args) -> dict:
        """Fields measured last, just before summary.json is written (e.g. peak memory)."""
        return {}

    def inner_options(self, args):
        """InnerOptions for the run (None: the solver's defaults)."""
        return None

    def run_options(self, args) -> dict:
        """Extra keyword arguments of run_ris / run_nested (e.g. ``adapt``); none by default."""
        return {}

    # ------------------------------------------------------------------------------------------
    def validate(self, args):
        """(control, tol, tau, tau_min, tols) from the options; one-line refusals (exit 2)."""
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
            tols = check_decreasing("--tols", args.tols or list(self.default_tols))
        if args.keep_every < 1:
            raise fail("--keep-every", args.keep_every, integer_allowed(1))
        if args.simpson < 2 or args.simpson % 2:
            raise fail("--simpson", args.simpson, "must be an even integer >= 2")
        return control, tol, tau, tau_min, tols

    def end_time(self, args) -> float:
        """T of the example (bounds --tau); validated before the problem is built."""
        return self.T

    def execute(self, args) -> int:
        """Validate, build the problem, run (or resume) it and write its results."""
        control, tol, tau, tau_min, tols = self.validate(args)
        problem = self.build_problem(args)
        common = dict(
            simpson_subintervals=args.simpson,
            inner=self.inner_options(args),
            keep_every=args.keep_every,
        )
        common.update(self.run_options(args))

        spec = control_object(control, tol=tol, tols=tols, tau=tau, tau_min=tau_min)

        def run(**kw):
            if isinstance(spec, Nested):
                return [r.trajectory for r in run_nested(problem, spec, **common, **kw)]
            return [run_ris(problem, spec, **common, **kw).trajectory]

        def write(stage, outcome):
            return self.write_results(args, problem, outcome, stage, control, tols, tau)

        code, outcome, results, summary = run_sequence(args, self.name, run, write)
        if outcome is not None and outcome.status == "completed" and not args.quiet:
            print(f"rothe run {self.name}: wrote {results}/")
            keys = SUMMARY_KEYS + tuple(self.summary_keys_extra())
            keys = dofs_keys(keys, summary, "n_dofs_final", "n_dofs_initial", "n_dofs_max")
            print_summary(summary, keys, summary_notes(summary))
        return code

    def write_results(self, args, problem, outcome, out, control, tols, tau) -> dict:
        """Every output file of the run into ``out`` (the staging directory); returns the
        summary (the run sequence annotates it and writes it last)."""
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
        return summary

    def summary_keys_extra(self):
        """Keys of summary.json printed after the common ones."""
        return ()

    def npz_extra(self, problem) -> dict:
        """Arrays written into trajectory.npz beside the trajectory (none by default)."""
        return {}

    def plot(self, args, problem, runs, out) -> None:
        """fig1_path.png and fig2_steps.png of the last run."""
        # matplotlib only when figures are drawn (start-up time of the command line)
        from ..ris.figures import plot_path, plot_steps

        traj = runs[-1]
        label = f"{self.name}, {traj.meta.get('control')}"
        if traj.meta.get("tol") is not None:
            label += f", tol={traj.meta['tol']:g}"
        plot_path(traj, out / "fig1_path.png", exact=self.exact(), title=label)
        plot_steps(traj, out / "fig2_steps.png", title=label)


@command("run", "ris-1d")
class RunRIS1D(RISRunBase):
    """``rothe run ris-1d``: Example 7.1 with its errors against (7.1)."""

    help = "Example 7.1 of Andreia & Meyer (2022): 1-D RIS with exact BV solution (7.1)"
    name = "ris-1d"
    default_tau = 0.1
    T = 5.0  # example_7_1()

    def validate(self, args):
        """--keep-every must be 1 (the errors need every state); then the common checks."""
        if args.keep_every != 1:
            raise fail(
                "--keep-every",
                args.keep_every,
                "must be 1 for ris-1d (one unknown; the errors against (7.1) need every state)",
            )
        return super().validate(args)

    def build_problem(self, args):
        """Example 7.1."""
        return examples.example_7_1()

    def exact(self):
        """(7.1)."""
        return examples.exact_solution

    def extra_summary(self, args, problem, traj) -> dict:
        """L2 and L-infinity errors against (7.1)."""
        return examples.errors_against_exact(traj["s"], traj["t"], traj["z"])


def run_cost(tol: float | None, tau: float) -> float:
    """Relative run time of a compare run, to start the longest first: uniform ~ 1/tau steps,
    adaptive/order2 ~ 10 tol^(-1/2) (the accepted steps grow like tol^(-1/2); on Example 7.2 at
    40 x 40 adaptive at tol = 1e-6 took 294 s and uniform at tau = 7.8e-5 253 s)."""
    return 1.0 / tau if tol is None else 10.0 * tol**-0.5


def compare_ris_1d_row(control: str, tol: float | None, tau: float, uniform: bool) -> dict:
    """One run of ``compare ris-1d`` (a task: builds Example 7.1 itself); its table row."""
    try:
        traj = run_ris(examples.example_7_1(), control_object(control, tol=tol, tau=tau)).trajectory
        failure = None
    except RunFailed as exc:  # keep the table: a failed run is a row with its status
        traj, failure = exc.trajectory, exc
    if traj is None or len(traj) == 0:
        row = {"control": control, "tol": tol, "tau0": tau}
    else:
        row = ris_summary(
            traj, "ris-1d", examples.errors_against_exact(traj["s"], traj["t"], traj["z"])
        )
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
    return compare_rows_of(tasks, executor)


def compare_rows_of(tasks, executor=None) -> list[dict]:
    """Run the tasks of a ``compare ris-*`` command (one ``Executor`` process when ``executor``
    is None); a task that failed gives a row with its control, tol, tau0 and status."""
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


def format_table(rows, work_fit=None) -> str:
    """The table of ``compare ris-1d`` (with solves / uniform's at equal L-infinity error when
    ``work_fit`` is given, :func:`rothe.ris.summary.uniform_work_at_error`)."""
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
    """``rothe compare ris-1d``: the controllers against uniform steps on Example 7.1."""

    help = (
        "Fig. 3 of Andreia & Meyer: error against steps, adaptive/order2/regime vs uniform "
        "(Ex. 7.1)"
    )

    def configure(self, parser) -> None:
        """--tols, --taus, the outputs and the executor."""
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
        """Run every comparison, write the table, summary and Fig. 3."""
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
            # matplotlib only when figures are drawn (start-up time of the command line)
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
