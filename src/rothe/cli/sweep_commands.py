"""``rothe sweep run <example> --param NAME=V1,V2,... [--param ...] [options of the run]``.

Runs the Cartesian product of the given option values of a ``run`` command, each run in its own
folder under ``--out`` (named by its parameters), on ``--workers`` processes or an existing Dask
``--scheduler``, and collects every run's summary.json into ``sweep.csv`` and ``sweep.json`` (and a
figure of two columns with ``--plot X,Y``). Any other option after the example goes to every run.
The machinery is :mod:`rothe.cli.sweep`.
"""

from __future__ import annotations

import argparse
import sys

from ..errors import RotheInputError
from .common import add_parallel_options, executor_from_args
from .registry import command
from .sweep import CONFIRM_ABOVE, format_rows, parse_plot, run_sweep

#: the sweep's own options; everything else after the example is passed to every run
_VALUED = ("--param", "--out", "--plot", "--workers", "--scheduler")
_FLAGS = ("--quiet", "--continue", "--yes", "-h", "--help")


class _OwnParser(argparse.ArgumentParser):
    def error(self, message):  # noqa: D401 - argparse API
        raise RotheInputError(message)


def _sweep_options(parser) -> None:
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=V1,V2,...",
        help="an option of the run and its values (repeatable; the runs are the "
        "Cartesian product); separate values by ';' when they hold commas",
    )
    parser.add_argument(
        "--out",
        default=None,
        help="folder of the sweep (default rothe-out/sweep-<example>); every run "
        "writes into a subfolder named by its parameters",
    )
    parser.add_argument(
        "--plot",
        default=None,
        metavar="X,Y",
        help="draw column Y against column X of the table (log axes where the "
        "values span a decade or more), a line per value of the other "
        "parameters",
    )
    parser.add_argument(
        "--quiet", action="store_true", help="no progress and no table on the terminal"
    )
    parser.add_argument(
        "--continue",
        dest="continue_sweep",
        action="store_true",
        help="continue a sweep stopped earlier into the same --out: completed "
        "runs are kept, interrupted or killed runs resume from their "
        "checkpoints, the others run",
    )
    parser.add_argument(
        "--yes",
        action="store_true",
        help=f"start a sweep of more than {CONFIRM_ABOVE} runs (without it such a "
        "sweep is refused, saying how many runs it has)",
    )
    add_parallel_options(parser)


def split_sweep_args(tokens: list[str]) -> tuple[list[str], list[str]]:
    """(the sweep's own options, the options passed to every run), order kept."""
    own, rest = [], []
    i = 0
    while i < len(tokens):
        tok = tokens[i]
        opt = tok.split("=", 1)[0]
        if opt in _VALUED:
            own.append(tok)
            if "=" not in tok and i + 1 < len(tokens):
                own.append(tokens[i + 1])
                i += 1
        elif tok in _FLAGS:
            own.append(tok)
        else:
            rest.append(tok)
        i += 1
    return own, rest


@command("sweep", "run")
class SweepRunCommand:
    """``rothe sweep run <example>``: a ``rothe run`` command over the Cartesian product of
    ``--param`` values (:func:`rothe.cli.sweep.run_sweep`).
    """

    help = (
        "the Cartesian product of option values of a run command (--param NAME=V1,V2,...), "
        "in parallel; one table of all summaries"
    )

    def configure(self, parser) -> None:
        """The example, the sweep's own options and the options passed to every run."""
        parser.add_argument("example", help="the example of `rothe run` to sweep, e.g. ris-2d")
        _sweep_options(parser)
        parser.add_argument(
            "run_options",
            nargs=argparse.REMAINDER,
            help="options passed to every run (e.g. --no-plots --control order2)",
        )
        parser.epilog = (
            "example: rothe sweep run ris-2d --param tol=1e-4,1e-5 --param n=20,40 "
            "--no-plots --plot tol,sum_residual --workers 2"
        )
        self._parser = parser

    def execute(self, args) -> int:
        """Split the sweep's options from the runs', run the sweep and print its table."""

        own_tokens, fixed = split_sweep_args(list(args.run_options))
        if "-h" in own_tokens or "--help" in own_tokens:
            self._parser.print_help()
            print(f"\nthe options of the run: rothe run {args.example} --help")
            return 0
        own = _OwnParser(prog="rothe sweep run", allow_abbrev=False, add_help=False)
        _sweep_options(own)
        own.set_defaults(
            **{
                k: getattr(args, k)
                for k in ("out", "plot", "quiet", "workers", "scheduler", "continue_sweep", "yes")
            }
        )
        opts = own.parse_args(own_tokens)
        params = list(args.param) + list(opts.param)
        plot = parse_plot(opts.plot)
        title = f"rothe sweep run {args.example}"
        executor = executor_from_args(opts, title)
        # run_sweep plans and validates every run before the executor connects or anything runs
        result = run_sweep(
            args.example,
            params,
            fixed,
            out=opts.out,
            executor=executor,
            plot=plot,
            continue_sweep=opts.continue_sweep,
            max_runs=None if opts.yes else CONFIRM_ABOVE,
        )
        resolved = result.params
        for col in result.missing_plot_columns:
            print(
                f"rothe: warning: --plot: no column {col!r} in the table (see "
                f"{result.csv.name} for the columns); no figure drawn",
                file=sys.stderr,
            )
        if not opts.quiet:
            print(
                format_rows(
                    result.rows,
                    resolved,
                    [p.name for p in resolved]
                    + [c for c in (plot or ()) if c not in {p.name for p in resolved}],
                )
            )
            done = sum(r["status"] == "completed" for r in result.rows)
            print(
                f"{done} of {len(result.rows)} runs completed; wrote {result.csv}, "
                f"{result.json.name}" + (f", {result.figure.name}" if result.figure else "")
            )
        return 0 if result.all_completed else 1
