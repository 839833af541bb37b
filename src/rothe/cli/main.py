"""The ``rothe`` command line: ``rothe run|compare|study|sweep <name> [options]``,
``rothe resume DIR``.

Commands are registered by modules under :mod:`rothe.cli` with :func:`rothe.cli.registry.command`;
each has ``configure(parser)`` and ``execute(args) -> int``. Errors a user can cause (bad values,
unknown names, missing files, a checkpoint that cannot be resumed, an ``--out`` that cannot be
written) print one line ``rothe: error: ...`` and exit with status 2, no traceback; a run that
fails midway (e.g. step size below tau_min) prints one line and exits with status 1 after writing
what it computed; a run stopped by SIGINT / SIGTERM / SIGHUP / SIGQUIT writes its results so far
and a checkpoint and exits with 130 / 143 / 129 / 131 (:mod:`rothe.stepping.interrupt`); SIGUSR1
makes a run write a checkpoint at its next step boundary and go on; an output that cannot be
written (e.g. a full disk) is one line naming the file, exit status 1, the earlier files
unchanged.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path

from .._version import __version__
from ..errors import OutputWriteError, RotheInputError, RunFailed, RunInterrupted
from ..io.checkpoint import MAIN, CheckpointError, checkpoint_dir, load_checkpoint
from ..io.outputs import read_summary
from ..stepping import interrupt
from . import registry
from .common import float_option
from .session import _run_dir


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line and exit status 2, and options are never
    abbreviated (``--n 8`` must not be read as ``--no-plots 8``, nor ``--tol`` as ``--tols``)."""

    def __init__(self, *args, **kwargs):
        kwargs["allow_abbrev"] = False
        super().__init__(*args, **kwargs)

    def error(self, message):  # noqa: D401 - argparse API
        raise RotheInputError(message)


def command_list() -> str:
    """One line per command: ``rothe <verb> <name>`` and its help, for ``rothe`` and ``--help``."""
    registry.load_all()
    rows = [
        (f"rothe {verb} {name}", cmd.help)
        for verb in registry.VERBS
        for name, cmd in sorted(registry.commands(verb).items())
    ]
    rows.append(("rothe resume DIR", Resume.help))
    width = max(len(r[0]) for r in rows)
    lines = ["commands:"] + [f"  {a:<{width}}  {b}" for a, b in rows]
    lines.append("")
    lines.append("rothe <verb> <name> --help lists the options of a command.")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """The parser of ``rothe``: one subparser per verb, one per registered command under it, and
    ``resume``.

    Returns
    -------
    argparse.ArgumentParser
    """
    registry.load_all()
    parser = _Parser(
        prog="rothe",
        description="Time-first (Rothe) discretizations: adaptive BV paths of rate-independent "
        "systems and elastodynamics with constraints.",
        epilog=command_list(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"rothe {__version__}")
    verbs = parser.add_subparsers(
        dest="verb", metavar="{" + ",".join([*registry.VERBS, "resume"]) + "}", parser_class=_Parser
    )
    verbs.required = True
    for verb, help_text in registry.VERBS.items():
        vp = verbs.add_parser(verb, help=help_text)
        names = vp.add_subparsers(dest="name", metavar="NAME", parser_class=_Parser)
        names.required = True
        for name, cmd in sorted(registry.commands(verb).items()):
            sub = names.add_parser(name, help=cmd.help, description=cmd.help)
            cmd.configure(sub)
            sub.set_defaults(_command=cmd, _options=option_table(sub, cmd))
    rp = verbs.add_parser("resume", help=Resume.help, description=Resume.help)
    Resume.configure(rp)
    rp.set_defaults(_command=Resume())
    return parser


class Resume:
    """``rothe resume DIR``: re-run the command recorded in DIR's checkpoint, from it."""

    help = (
        "continue an interrupted run from its checkpoint: re-runs the recorded command "
        "line with --out DIR --resume DIR"
    )

    @staticmethod
    def configure(parser) -> None:
        """DIR, --quiet, --no-plots, --checkpoint-every and --progress-every."""

        parser.add_argument(
            "dir", metavar="DIR", help="the run's output directory (holding checkpoint/)"
        )
        parser.add_argument("--quiet", action="store_true", help="no progress and no summary")
        parser.add_argument("--no-plots", action="store_true", help="do not draw figures")
        float_option(
            parser,
            "--checkpoint-every",
            default=None,
            metavar="SECONDS",
            help="checkpoint interval (default: the recorded one)",
        )
        float_option(
            parser,
            "--progress-every",
            default=None,
            metavar="SECONDS",
            help="progress line interval in logs (default: the recorded one)",
        )

    def execute(self, args) -> int:
        """Re-run the command line recorded in DIR's checkpoint with --out DIR --resume DIR
        (nothing to do for a run that already completed)."""
        run_dir = _run_dir(Path(args.dir))
        if (
            run_dir.is_dir()
            and not (checkpoint_dir(run_dir) / MAIN).is_file()
            and (read_summary(run_dir) or {}).get("status") == "completed"
        ):
            # a completed run removes its checkpoint (unless --keep-checkpoint): nothing to do
            print(
                f"rothe: {run_dir}: the run already completed; its results are there",
                file=sys.stderr,
            )
            return 0
        ckpt = load_checkpoint(args.dir, header_only=True)
        ckpt.require_resumable()
        argv = ckpt.record.get("argv")
        if not argv:
            raise CheckpointError(
                f"{args.dir}: the checkpoint was written by {ckpt.api}() from "
                f"Python, not by a rothe command: resume it with "
                f"{ckpt.api}(..., resume={str(args.dir)!r})"
            )
        new_argv = list(argv) + ["--out", str(run_dir), "--resume", str(run_dir)]
        if args.quiet:
            new_argv.append("--quiet")
        if args.no_plots:
            new_argv.append("--no-plots")
        if args.checkpoint_every is not None:
            new_argv.append(f"--checkpoint-every={args.checkpoint_every!r}")
        if args.progress_every is not None:
            new_argv.append(f"--progress-every={args.progress_every!r}")
        if not args.quiet:
            print(
                f"rothe: resuming 'rothe {' '.join(argv)}' in {run_dir} from its checkpoint "
                f"({ckpt.status}, {ckpt.describe_where()})",
                file=sys.stderr,
            )
        return _dispatch(build_parser(), new_argv)


def _is_number(text: str) -> bool:
    """A number or a comma-separated list of numbers (``-1e-3``, ``-0.1,0.1``)."""
    try:
        for part in text.split(","):
            float(part)
    except ValueError:
        return False
    return True


def _join_negative_values(argv: list[str]) -> list[str]:
    """``--tol -1e-3`` -> ``--tol=-1e-3`` (and ``--tols -0.1,0.1``): argparse takes a value that
    starts with '-' for an option otherwise ("expected one argument")."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        tok = argv[i]
        if (
            tok.startswith("--")
            and "=" not in tok
            and i + 1 < len(argv)
            and argv[i + 1].startswith("-")
            and _is_number(argv[i + 1])
        ):
            out.append(f"{tok}={argv[i + 1]}")
            i += 2
            continue
        out.append(tok)
        i += 1
    return out


def _known(verb: str) -> str:
    return ", ".join(sorted(registry.commands(verb)))


def option_table(parser, command=None) -> dict[str, str]:
    """The option each library parameter comes from, read off argparse's own table of the
    command: ``dest`` -> ``--long-option`` (``tau`` -> ``--tau``, ``space_tol`` ->
    ``--space-tol``), plus the command's ``parameter_options`` for API parameters whose name is
    not the option's (e.g. ``{"adapt": "--adapt-space"}``)."""
    table: dict[str, str] = {}
    for action in parser._actions:
        longs = [s for s in action.option_strings if s.startswith("--")]
        if not longs or action.dest in ("help", "version"):
            continue
        table.setdefault(action.dest, longs[0])
        table.setdefault(longs[0][2:].replace("-", "_"), longs[0])
    table.update(getattr(command, "parameter_options", {}) or {})
    return table


def execute(args) -> int:
    """Execute a parsed command; bad input found by the library names the command-line option
    it came from (:meth:`RotheInputError.renamed` with :func:`option_table`), not the API
    parameter."""
    try:
        return int(args._command.execute(args) or 0)
    except RotheInputError as exc:
        table = getattr(args, "_options", {})
        renamed = exc.renamed(table.get(exc.parameter), table)
        if renamed is exc:
            raise
        raise renamed from exc.__cause__


def _dispatch(parser, argv: list[str]) -> int:
    # a clearer message than argparse's for an unknown example name
    if len(argv) >= 2 and argv[0] in registry.VERBS and not argv[1].startswith("-"):
        if argv[1] not in registry.commands(argv[0]):
            raise RotheInputError(f"{argv[0]}: got {argv[1]!r}, must be one of {_known(argv[0])}")
    try:
        args = parse_command(parser, argv)
    except SystemExit as exc:  # --help, --version: argparse printed them and exits
        return int(exc.code or 0)
    return execute(args)


def parse_command(parser, argv: list[str]):
    """The namespace of one command line as ``rothe`` executes it, with the command line
    (``_argv``) and the options written on it (``_given``); also used by ``rothe sweep``, which
    parses and executes every run's command line itself."""
    args = parser.parse_args(argv)
    args._argv = list(argv)
    args._given = given_options(argv)
    return args


def given_options(argv: list[str]) -> frozenset[str]:
    """The options written on the command line (``--tol`` of ``--tol 1e-3`` or ``--tol=1e-3``),
    so that a command can tell an option the user gave from its default."""
    return frozenset(tok.split("=", 1)[0] for tok in argv if tok.startswith("--"))


def _one_line_warning(message, category, filename, lineno, line=None):
    return f"rothe: warning: {message}\n"


def _stdout_to_devnull() -> None:
    """After a broken pipe: send what Python still flushes at exit to /dev/null (else it prints
    'Exception ignored ... BrokenPipeError')."""

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # stdout without a file descriptor (e.g. captured)
        pass


def main(argv=None) -> int:
    """Run one command; returns the exit status (0 ok, 1 run failed, 2 bad input, 141 when the
    reader of stdout went away, e.g. ``rothe run ris-1d | head -3``: 128 + SIGPIPE, as a shell
    reports for programs killed by the signal; the results are written before anything is
    printed)."""
    try:
        status = _main(argv)
        sys.stdout.flush()  # a broken pipe surfaces here rather than at interpreter exit
    except BrokenPipeError:
        _stdout_to_devnull()
        status = 141
    # a factorization abandoned by a stop signal may still run: the process then ends with
    # this status without waiting for it (rothe.stepping.interrupt.call)
    interrupt.will_exit_with(status)
    return status


def _main(argv=None) -> int:
    argv = _join_negative_values(list(sys.argv[1:] if argv is None else argv))
    if not argv:  # bare ``rothe``: the usage and the list of commands, not a one-line error
        parser = build_parser()
        print(parser.format_usage().rstrip(), file=sys.stderr)
        print(command_list(), file=sys.stderr)
        return 2
    saved_format = warnings.formatwarning
    warnings.formatwarning = _one_line_warning
    # SIGUSR1 (a scheduler's "time limit ahead") asks for a checkpoint: it must never end the
    # process, also not while a run is being set up or between the runs of a sweep
    interrupt.keep_checkpoint_requests()
    try:
        return _dispatch(build_parser(), argv)
    except RotheInputError as exc:
        print(f"rothe: error: {exc}", file=sys.stderr)
        return 2
    except OutputWriteError as exc:
        print(f"rothe: error: {exc} (files written before are unchanged)", file=sys.stderr)
        return 1
    except (FileNotFoundError, IsADirectoryError, PermissionError) as exc:
        print(f"rothe: error: {exc}", file=sys.stderr)
        return 2
    except RunFailed as exc:
        print(f"rothe: run failed: {exc}", file=sys.stderr)
        return 1
    except RunInterrupted as exc:
        print(f"rothe: {exc}", file=sys.stderr)
        return exc.exit_status
    except KeyboardInterrupt:
        print("rothe: interrupted", file=sys.stderr)
        return 130
    finally:
        warnings.formatwarning = saved_format


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
