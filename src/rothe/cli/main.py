"""The ``rothe`` command line: ``rothe run|compare|study <name> [options]``.

Commands are registered by modules under :mod:`rothe.cli` with :func:`rothe.cli.registry.command`;
each has ``configure(parser)`` and ``execute(args) -> int``. Errors a user can cause (bad values,
unknown names, missing files) print one line ``rothe: error: ...`` and exit with status 2, no
traceback; a run that fails midway (e.g. step size below tau_min) prints one line and exits with
status 1 after writing what it computed.
"""

from __future__ import annotations

import argparse
import sys

from ..errors import RotheInputError, RunFailed
from . import registry


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line and exit status 2."""

    def error(self, message):  # noqa: D401 - argparse API
        raise RotheInputError(message)


def build_parser() -> argparse.ArgumentParser:
    registry.load_all()
    parser = _Parser(
        prog="rothe",
        description="Time-first (Rothe) discretizations: adaptive BV paths of rate-independent "
        "systems and elastodynamics with constraints.",
    )
    verbs = parser.add_subparsers(dest="verb", metavar="{run,compare,study}", parser_class=_Parser)
    verbs.required = True
    for verb, help_text in registry.VERBS.items():
        vp = verbs.add_parser(verb, help=help_text)
        names = vp.add_subparsers(dest="name", metavar="NAME", parser_class=_Parser)
        names.required = True
        for name, cmd in sorted(registry.commands(verb).items()):
            sub = names.add_parser(name, help=cmd.help, description=cmd.help)
            cmd.configure(sub)
            sub.set_defaults(_command=cmd)
    return parser


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _join_negative_values(argv: list[str]) -> list[str]:
    """``--tol -1e-3`` -> ``--tol=-1e-3``: argparse takes '-1e-3' for an option otherwise."""
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


def main(argv=None) -> int:
    argv = _join_negative_values(list(sys.argv[1:] if argv is None else argv))
    try:
        parser = build_parser()
        # a clearer message than argparse's for an unknown example name
        if len(argv) >= 2 and argv[0] in registry.VERBS and not argv[1].startswith("-"):
            if argv[1] not in registry.commands(argv[0]):
                raise RotheInputError(
                    f"{argv[0]}: got {argv[1]!r}, must be one of {_known(argv[0])}"
                )
        args = parser.parse_args(argv)
        return int(args._command.execute(args) or 0)
    except RotheInputError as exc:
        print(f"rothe: error: {exc}", file=sys.stderr)
        return 2
    except (FileNotFoundError, IsADirectoryError, PermissionError) as exc:
        print(f"rothe: error: {exc}", file=sys.stderr)
        return 2
    except RunFailed as exc:
        print(f"rothe: run failed: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("rothe: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
