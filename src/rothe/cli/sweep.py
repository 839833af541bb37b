"""Parameter sweeps: the Cartesian product of option values of any ``rothe run`` command.

A sweep is planned completely before anything runs (:func:`plan_sweep`): every run gets its argv
(``run <example> <fixed options> --<name>=<value> ... --out=<folder> --quiet``) and its own folder
named by its parameters (``tol=1e-05_n=40``, readable and unique). Every argv is then parsed by
the command's own parser and checked by the command's own ``validate(args)`` (where it has one),
so that a value the command would refuse stops the sweep with one line naming the run before the
first run starts. The runs are :func:`~rothe.cli.tasks.cli_task` tasks for an
:class:`~rothe.parallel.executor.Executor`; each run's ``summary.json`` comes back as the task's
value and becomes one row of ``sweep.csv`` / ``sweep.json`` (:func:`collect_rows`): the run's
folder, its parameters (as the command parsed them), status, message, then the summary fields.

Since the sweep goes through the command line, a new option of a ``run`` command is sweepable
as soon as it exists.
"""

from __future__ import annotations

import argparse
import csv
import io
import itertools
import json
import math
import os
import re
import signal
import time
from dataclasses import dataclass
from pathlib import Path

from ..cli.common import _jsonable as conv
from ..errors import RotheInputError, RunInterrupted, fail
from ..fem.mesh import load_mesh
from ..io.atomic import check_writable
from ..io.checkpoint import CHECKPOINT_SUBDIR, MAIN, CheckpointError, load_checkpoint
from ..io.outputs import read_summary
from ..parallel.executor import Executor
from ..parallel.tasks import Task, TaskResult
from ..plotting.sweep import plot_sweep
from ..stepping.interrupt import signal_name
from . import registry
from .main import build_parser, parse_command
from .session import strip_argv
from .tasks import cli_task

#: options the sweep sets for every run itself
RESERVED = {
    "--out": "the sweep gives every run its own folder under the sweep's --out",
    "--quiet": "every run is quiet (the sweep reports progress)",
    "--resume": "every run has its own folder and checkpoint (rothe resume <run folder> "
    "continues one)",
    "--help": "not an option of a run",
}
#: options whose value names an input file, checked for every run before any run starts (a
#: command adds its own with a ``file_options`` attribute: option strings); a mesh is also read
#: (once per file), so that a file the run would refuse stops the sweep before the first run
FILE_OPTIONS = ("--mesh",)
#: a sweep of more runs than this needs ``--yes`` (``max_runs`` of :func:`run_sweep`)
CONFIRM_ABOVE = 1000
_TRUE = ("true", "yes", "on", "1")
_FALSE = ("false", "no", "off", "0")


@dataclass
class SweepParam:
    """One swept option: ``name`` as given, ``option`` (e.g. ``--tol``), the values as typed."""

    name: str
    option: str
    values: list[str]
    flag: bool = False  # an option without a value (e.g. --no-plots): values are true/false


@dataclass
class SweepRun:
    """One run of the sweep: its folder name, its parameter values (as typed) and its argv."""

    name: str
    values: dict
    argv: list[str]
    out: str
    parsed: dict  # the parameter values as the command's parser converted them
    #: ``--continue``: the summary of this run's completed result already in its folder (the
    #: run is not started again; its checkpoint was removed when it completed)
    done: dict | None = None


def split_param(text: str) -> tuple[str, list[str]]:
    """``NAME=V1,V2,...`` -> (NAME, [V1, V2, ...]); ``;`` separates values that hold commas."""
    name, eq, values = text.partition("=")
    name = name.strip()
    if not eq or not name:
        raise fail("--param", text, "must be NAME=V1,V2,... (e.g. tol=1e-4,1e-5)")
    sep = ";" if ";" in values else ","
    vals = [v.strip() for v in values.split(sep)]
    if not any(vals):
        raise fail("--param", text, f"needs at least one value after {name}=")
    if not all(vals):
        raise fail("--param", text, "has an empty value (V1,,V2 or a trailing comma)")
    if len(set(vals)) != len(vals):
        raise fail("--param", text, "repeats a value")
    return name, vals


def command_parser(verb: str, example: str) -> argparse.ArgumentParser:
    """The argparse parser of ``rothe <verb> <example>``, exactly as the CLI builds it."""

    def sub(parser, name):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                return action.choices.get(name)
        return None

    verb_parser = sub(build_parser(), verb)
    parser = sub(verb_parser, example) if verb_parser is not None else None
    if parser is None:
        known = ", ".join(sorted(registry.commands(verb)))
        raise fail(f"sweep {verb}", example, f"must be one of {known}")
    return parser


def resolve_params(parser, verb: str, example: str, texts: list[str]) -> list[SweepParam]:
    """Check every ``--param`` against the options of the command."""
    if not texts:
        raise RotheInputError(
            "--param: none given, needs at least one NAME=V1,V2,... to sweep over"
        )
    options = parser._option_string_actions
    params: list[SweepParam] = []
    for text in texts:
        name, values = split_param(text)
        option = "--" + name.lstrip("-")
        if option not in options and option.replace("_", "-") in options:
            option = option.replace("_", "-")
        if option in RESERVED:
            raise fail("--param", name, f"cannot be swept: {RESERVED[option]}")
        if option not in options:
            names = sorted(o[2:] for o in options if o.startswith("--") and o not in RESERVED)
            raise fail(
                "--param",
                name,
                f"is not an option of 'rothe {verb} {example}' (its options: {', '.join(names)})",
            )
        if any(p.option == option for p in params):
            raise fail("--param", name, "is given twice")
        action = options[option]
        flag = action.nargs == 0
        if flag:
            for v in values:
                if v.lower() not in _TRUE + _FALSE:
                    raise fail(
                        "--param", f"{name}={v}", f"{option} takes no value: use {name}=true,false"
                    )
        params.append(SweepParam(name.lstrip("-"), option, values, flag))
    return params


def _fixed_options(tokens: list[str]) -> set[str]:
    return {t.split("=", 1)[0] for t in tokens if t.startswith("--")}


def run_name(assignment: list[tuple[str, str]]) -> str:
    """A readable folder name from the parameter values: ``tol=1e-05_n=40``."""
    name = "_".join(f"{k}={v}" for k, v in assignment)
    name = re.sub(r"[^A-Za-z0-9._=,+-]+", "-", name).strip("-.") or "run"
    return name[:150]


def plan_sweep(
    verb: str, example: str, params: list[SweepParam], fixed: list[str], out: Path
) -> list[SweepRun]:
    """Every run of the product, with its argv and folder (product order, last varies fastest)."""
    both = _fixed_options(fixed) & {p.option for p in params}
    if both:
        opt = sorted(both)[0]
        raise RotheInputError(f"{opt}: given both in --param and as an option of every run")
    for opt in sorted(_fixed_options(fixed) & set(RESERVED)):
        raise RotheInputError(f"{opt}: cannot be passed to the runs: {RESERVED[opt]}")
    runs: list[SweepRun] = []
    used: set[str] = set()
    for combo in itertools.product(*(p.values for p in params)):
        assignment = [(p.name, v) for p, v in zip(params, combo, strict=True)]
        name = base = run_name(assignment)
        k = 2
        while name.lower() in used:  # names that differ only in replaced characters or case
            name = f"{base}-{k}"
            k += 1
        used.add(name.lower())
        folder = (out / name).resolve()
        argv = [verb, example, *fixed]
        for p, v in zip(params, combo, strict=True):
            if p.flag:
                if v.lower() in _TRUE:
                    argv.append(p.option)
            else:
                argv.append(f"{p.option}={v}")
        argv += [f"--out={folder}", "--quiet"]
        runs.append(SweepRun(name, dict(assignment), argv, str(folder), {}))
    return runs


def _scalar(value):
    return value if isinstance(value, (int, float, str, bool)) or value is None else None


def check_input_file(option: str, value) -> None:
    """One line naming ``option`` unless ``value`` names a readable regular file."""
    path = Path(str(value))
    if not str(value).strip():
        raise fail(option, str(value), "must name a file")
    if not path.exists():
        raise fail(option, str(value), "no such file")
    if path.is_dir():
        raise fail(option, str(value), "is a directory, must be a file")
    if not path.is_file():
        raise fail(option, str(value), "is not a regular file (a FIFO, socket or device)")
    try:
        with open(path, "rb") as f:
            f.read(1)
    except OSError as exc:
        raise fail(option, str(value), f"cannot be read ({exc.strerror or exc})") from None


def _check_mesh_file(args, value, seen: set) -> None:
    """Read a --mesh file as the run will (triangles or tetrahedra by the command's ``dim``,
    its --duplicate-nodes), once per file and settings."""
    dim = getattr(args._command, "dim", None)
    duplicates = getattr(args, "duplicate_nodes", None) or "error"
    key = (str(value), dim, duplicates)
    if key not in seen:
        seen.add(key)
        load_mesh(value, dim=dim, name="--mesh", duplicate_nodes=duplicates)


def _check_files(args, parser, seen: set) -> None:
    options = FILE_OPTIONS + tuple(getattr(args._command, "file_options", ()))
    actions = parser._option_string_actions
    for option in options:
        if option in actions:
            value = getattr(args, actions[option].dest, None)
            if value is not None:
                check_input_file(option, value)
                if option == "--mesh":
                    _check_mesh_file(args, value, seen)


def validate_runs(runs: list[SweepRun], parser, params: list[SweepParam]) -> None:
    """Parse every run's argv with the CLI, check its input files (:data:`FILE_OPTIONS`: a
    sweep over ``mesh=good.msh,missing.msh`` must not find the missing file after the good
    runs) and run the command's own ``validate``; the first refusal is one line naming the run.
    Fills ``run.parsed`` (the values as the command sees them)."""

    full = build_parser()
    seen: set = set()
    for run in runs:
        try:
            args = parse_command(full, run.argv)
            _check_files(args, parser, seen)
            validate = getattr(args._command, "validate", None)
            if validate is not None:
                validate(args)
        except RotheInputError as exc:
            raise RotheInputError(f"sweep run {run.name}: {exc}") from None
        for p in params:
            dest = parser._option_string_actions[p.option].dest
            value = _scalar(getattr(args, dest, None))
            run.parsed[p.name] = value if value is not None else run.values[p.name]


def continue_runs(runs: list[SweepRun]) -> dict[str, str]:
    """``--continue``: every run whose folder holds a resumable checkpoint (the run was
    interrupted or killed, or it completed with ``--keep-checkpoint``) gets
    ``--resume=<its folder>``: an unfinished run continues from its checkpoint, a completed one
    is not run again (its summary is its row). The run's session refuses a checkpoint made with
    other options (status ``error``, the message says which). A run whose folder holds the
    completed result of the same command line (``summary.json``: status ``completed`` and the
    same ``argv``; a completed run removes its checkpoint) is ``done``: not started, its summary
    is its row. The other runs, and those whose checkpoint is of a failed run, run anew.
    Returns what happens to each run: ``resume`` | ``done`` | ``run``."""

    what = {}
    for run in runs:
        ckpt_dir = Path(run.out) / CHECKPOINT_SUBDIR
        status = None
        if (ckpt_dir / MAIN).is_file():
            try:
                status = load_checkpoint(ckpt_dir, check_version=False, header_only=True).status
            except CheckpointError:
                status = None  # unreadable: the run starts over (nothing resumable is lost)
        earlier = read_summary(run.out) if status is None else None
        if status in ("running", "interrupted", "completed"):
            run.argv.append(f"--resume={run.out}")
            what[run.name] = "resume"
        elif (
            earlier is not None
            and earlier.get("status") == "completed"
            and earlier.get("argv") == strip_argv(run.argv)
        ):
            run.done = earlier
            what[run.name] = "done"
        else:
            what[run.name] = "run"
    return what


def earlier_result(summary: dict) -> dict:
    """The task of a run completed before ``--continue``: its summary is its value."""
    return summary


def sweep_tasks(runs: list[SweepRun]):
    """One :func:`~rothe.cli.tasks.cli_task` per run of the sweep (its argv and folder); a run
    completed before ``--continue`` is a task that returns its summary."""
    return [
        cli_task(run.name, run.argv, out=run.out)
        if run.done is None
        else Task(run.name, earlier_result, {"summary": run.done})
        for run in runs
    ]


def collect_rows(runs: list[SweepRun], results: list[TaskResult]) -> list[dict]:
    """One row per run: folder, parameters, status, message, then the summary fields."""
    rows = []
    for run, res in zip(runs, results, strict=True):
        row = {"run": run.name, **run.parsed, "status": res.status, "message": res.message}
        summary = res.value if isinstance(res.value, dict) else {}
        for key, value in summary.items():
            if key in ("status", "command", "argv"):  # the run's command line: its folder says it
                continue
            if key in row:
                if _same(row[key], value):
                    continue
                key = f"summary_{key}"
            row[key] = value
        rows.append(row)
    return rows


def _same(a, b) -> bool:
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return float(a) == float(b)
    return a == b


def _jsonable(value):

    return conv(value)


def _write_atomic(path: Path, text: str) -> Path:
    """Temporary file beside the target, then rename: a reader sees the old or the new file."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
    return path


def table_columns(rows: list[dict]) -> list[str]:
    """The keys of all rows, in the order they first occur."""
    cols: list[str] = []
    for row in rows:
        cols += [k for k in row if k not in cols]
    return cols


def _csv_cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ""
    if isinstance(value, (list, dict)):
        return json.dumps(_jsonable(value))
    return str(value)


def write_table(out: Path, rows: list[dict], meta: dict) -> tuple[Path, Path]:
    """``sweep.csv`` (one line per run, non-scalar fields as JSON) and ``sweep.json``."""
    cols = table_columns(rows)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(cols)
    for row in rows:
        writer.writerow([_csv_cell(row.get(c)) for c in cols])
    csv_path = _write_atomic(out / "sweep.csv", buf.getvalue())
    doc = dict(meta)
    doc["columns"] = cols
    doc["rows"] = rows
    json_path = _write_atomic(out / "sweep.json", json.dumps(_jsonable(doc), indent=2) + "\n")
    return csv_path, json_path


def parse_plot(text: str | None) -> tuple[str, str] | None:
    """``--plot X,Y`` as the pair (X, Y); None for None; one line naming --plot otherwise."""
    if text is None:
        return None
    cols = [c.strip() for c in text.split(",")]
    if len(cols) != 2 or not all(cols):
        raise fail("--plot", text, "must name two columns X,Y (e.g. tol,sum_residual)")
    return cols[0], cols[1]


def format_rows(rows: list[dict], params: list[SweepParam], extra=()) -> str:
    """A short table for the terminal: folder, status, parameters and a few columns."""
    cols = ["run", "status"] + [c for c in extra if any(c in r for r in rows)]
    if any("wall_time_s" in r for r in rows) and "wall_time_s" not in cols:
        cols.append("wall_time_s")

    def cell(v):
        if isinstance(v, float):
            return f"{v:.4g}"
        return "" if v is None else str(v)

    table = [[cell(r.get(c)) for c in cols] for r in rows]
    widths = [max(len(c), *(len(t[i]) for t in table)) for i, c in enumerate(cols)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(cols, widths, strict=True)).rstrip()]
    lines.append("-" * len(lines[0]))
    for r, t in zip(rows, table, strict=True):
        line = "  ".join(x.ljust(w) for x, w in zip(t, widths, strict=True)).rstrip()
        if r["status"] != "completed" and r.get("message"):
            line += f"  {r['message'][:160]}"
        lines.append(line)
    return "\n".join(lines)


@dataclass
class SweepResult:
    """What :func:`run_sweep` returns: the rows, the sweep's folder, the paths of ``sweep.csv``
    and ``sweep.json``, the figure (None without ``plot`` or when a column is missing), the
    ``plot`` columns no row has, and the swept parameters.
    """

    rows: list[dict]
    out: Path
    csv: Path
    json: Path
    figure: Path | None
    missing_plot_columns: list[str]
    params: list[SweepParam]

    @property
    def all_completed(self) -> bool:
        return all(r["status"] == "completed" for r in self.rows)


def check_run_count(runs: list[SweepRun], params: list[SweepParam], max_runs: int | None) -> None:
    """More than ``max_runs`` runs: one line saying how many (and of what), asking for --yes."""
    if max_runs is None or len(runs) <= max_runs:
        return
    sizes = " x ".join(f"{len(p.values)} {p.name}" for p in params)
    raise RotheInputError(
        f"--param: {len(runs)} runs ({sizes}), more than {max_runs}: pass --yes to start them all",
        "param",
    )


def prepare_sweep(
    example: str,
    params: list[str] | dict,
    fixed=(),
    *,
    verb: str = "run",
    out=None,
    continue_sweep: bool = False,
    max_runs: int | None = None,
) -> tuple[list[SweepRun], list[SweepParam], Path]:
    """Plan and validate a sweep (nothing runs): ``params`` as ``NAME=V1,V2`` strings or a dict
    ``{name: [values]}``; ``continue_sweep``: see :func:`continue_runs`; ``max_runs``: refuse
    a sweep of more runs (:func:`check_run_count`; the CLI's limit is :data:`CONFIRM_ABOVE`
    without ``--yes``)."""
    if isinstance(params, dict):
        params = [
            f"{k}={';'.join(map(str, v))}"
            if any("," in str(x) for x in v)
            else f"{k}={','.join(map(str, v))}"
            for k, v in params.items()
        ]
    parser = command_parser(verb, example)
    resolved = resolve_params(parser, verb, example, list(params))
    if out is not None and not str(out).strip():  # Path('') would be '.'
        raise fail(
            "--out", str(out), f"must name a directory (omit --out for rothe-out/sweep-{example})"
        )
    out = Path(out) if out is not None else Path("rothe-out") / f"sweep-{example}"
    runs = plan_sweep(verb, example, resolved, [str(a) for a in fixed], out)
    check_run_count(runs, resolved, max_runs)
    if continue_sweep:
        continue_runs(runs)
    validate_runs(runs, parser, resolved)
    return runs, resolved, out


def run_sweep(
    example: str,
    params: list[str] | dict,
    fixed=(),
    *,
    verb: str = "run",
    out=None,
    executor: Executor | None = None,
    plot: str | tuple | None = None,
    continue_sweep: bool = False,
    max_runs: int | None = None,
) -> SweepResult:
    """Run a sweep (Python API of ``rothe sweep``): plan, validate, run, collect, write.

    ``executor`` defaults to in-process; e.g. ``Executor(workers=4)`` or
    ``Executor(scheduler=cluster)`` with a dask-jobqueue cluster. ``continue_sweep`` (CLI
    ``--continue``): continue a sweep stopped earlier in the same ``out`` (completed runs are
    kept, interrupted or killed ones resume from their checkpoints; :func:`continue_runs`).
    """
    xy = parse_plot(plot) if isinstance(plot, str) or plot is None else tuple(plot)
    runs, resolved, out = prepare_sweep(
        example, params, fixed, verb=verb, out=out, continue_sweep=continue_sweep, max_runs=max_runs
    )
    executor = executor or Executor(1, progress=False)
    if executor.scheduler is None and executor.workers > len(runs) >= 1:
        executor.workers = len(runs)  # a local worker without a run would only start and idle
    check_writable_sweep(out)
    t0 = time.perf_counter()
    interrupted = None
    with executor:  # connects (or starts the cluster) once --out is known to be writable
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise fail("--out", str(out), f"cannot create this directory ({exc})") from None
        try:
            results = executor.map(sweep_tasks(runs))
        except KeyboardInterrupt as exc:  # SIGINT/SIGTERM: keep the table of what finished
            interrupted = exc
            results = interrupted_results(runs, executor, exc)
    rows = collect_rows(runs, results)
    for run, res in zip(runs, results, strict=True):
        if res.detail and Path(run.out).is_dir():
            _write_atomic(Path(run.out) / "traceback.txt", res.detail)
    meta = {
        "command": " ".join(
            ["rothe", "sweep", verb, example, *map(str, fixed)]
            + [f"--param {p.name}={','.join(p.values)}" for p in resolved]
        ),
        "verb": verb,
        "example": example,
        "params": {p.name: p.values for p in resolved},
        "fixed_options": list(map(str, fixed)),
        "executor": executor.describe(),
        "runs": len(rows),
        "completed": sum(r["status"] == "completed" for r in rows),
        "wall_time_s": time.perf_counter() - t0,
    }
    if interrupted is not None:
        signum = getattr(interrupted, "signum", signal.SIGINT)
        meta["interrupted"] = signal_name(signum)
    csv_path, json_path = write_table(out, rows, meta)
    if interrupted is not None:
        raise RunInterrupted(
            f"sweep interrupted by {meta['interrupted']}: {meta['completed']} of {len(rows)} "
            f"runs completed; table so far in {csv_path}; the same command with --continue "
            "continues the sweep",
            signum=signum,
        ) from None
    figure, missing = None, []
    if xy is not None:
        cols = table_columns(rows)
        missing = [c for c in xy if c not in cols]
        if not missing:
            x, y = xy
            group = [p.name for p in resolved if p.name != x]
            if x not in {p.name for p in resolved} and group:
                group = group[1:]  # the first parameter varies along each line
            figure = plot_sweep(
                rows,
                x,
                y,
                group,
                out / f"sweep_{_file_part(y)}_vs_{_file_part(x)}.png",
                title=f"rothe sweep {verb} {example}",
            )
    return SweepResult(rows, out, csv_path, json_path, figure, missing, resolved)


def check_writable_sweep(out: Path) -> None:
    """Prove that the sweep's folder can be created and written before any cluster starts: a
    read-only file system or a missing parent is one line naming --out (it was an OSError
    traceback from mkdir, after the cluster had started). A folder made only for the check is
    removed again (a sweep that cannot start leaves nothing)."""
    missing = [p for p in (out, *out.parents) if not p.exists()]
    check_writable(out, "--out")
    for p in missing:  # innermost first
        try:
            p.rmdir()
        except OSError:
            break


def interrupted_results(
    runs: list[SweepRun], executor: Executor, exc: BaseException
) -> list[TaskResult]:
    """The results of a map stopped by a signal: those that finished, ``interrupted`` for runs
    under way (with the summary of their results so far, where the run wrote one: in-process the
    run's session does), ``pending`` for runs that never started."""
    name = signal_name(getattr(exc, "signum", signal.SIGINT))
    finished = executor.finished if len(executor.finished) == len(runs) else [None] * len(runs)
    results = []
    for i, (run, res) in enumerate(zip(runs, finished, strict=True)):
        if res is not None:
            results.append(res)
        elif i in executor.started:
            results.append(
                TaskResult(
                    run.name,
                    "interrupted",
                    f"stopped by {name}; continue it with: rothe resume {run.out}",
                    value=_interrupted_summary(Path(run.out)),
                    worker="",
                )
            )
        else:
            results.append(
                TaskResult(run.name, "pending", f"not started (sweep stopped by {name})", worker="")
            )
    return results


def _interrupted_summary(folder: Path) -> dict | None:
    for path in (folder / "summary.json", folder / "incomplete" / "summary.json"):
        try:
            summary = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if isinstance(summary, dict) and summary.get("status") == "interrupted":
            return summary
    return None


def _file_part(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", name)


__all__ = [
    "SweepParam",
    "SweepResult",
    "SweepRun",
    "collect_rows",
    "command_parser",
    "continue_runs",
    "format_rows",
    "interrupted_results",
    "parse_plot",
    "plan_sweep",
    "prepare_sweep",
    "resolve_params",
    "run_name",
    "run_sweep",
    "split_param",
    "sweep_tasks",
    "validate_runs",
    "write_table",
]
