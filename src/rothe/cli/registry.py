"""Registry of CLI commands: ``@command("run", "ris-1d", help=...)`` on a class or module object.

A command is any object with ``help: str``, ``configure(parser)`` and ``execute(args) -> int``.
Modules that define commands are listed in ``MODULES`` and imported by :func:`load_all`.
"""

from __future__ import annotations

import importlib

VERBS = {
    "run": "run one example and write results and figures",
    "compare": "run several controllers on one example and compare them",
    "study": "run a parameter study (convergence, perturbation)",
    "sweep": "run a command over the Cartesian product of option values, in parallel",
}

MODULES = (
    "rothe.cli.ris_commands",
    "rothe.cli.ris_fem_commands",
    "rothe.cli.eld_commands",
    "rothe.cli.coupled_commands",
    "rothe.cli.sweep_commands",
)

_COMMANDS: dict[str, dict[str, object]] = {verb: {} for verb in VERBS}


def command(verb: str, name: str):
    """Class decorator: register an instance of the class under ``verb name``."""

    def wrap(cls):
        _COMMANDS[verb][name] = cls()
        return cls

    return wrap


def commands(verb: str) -> dict:
    """The registered commands of ``verb`` by name (empty for an unknown verb)."""
    return _COMMANDS.get(verb, {})


def load_all() -> None:
    """Import the modules of :data:`MODULES` (registering their commands); a module that does
    not exist is skipped.
    """
    for mod in MODULES:
        try:
            importlib.import_module(mod)
        except ModuleNotFoundError as exc:
            if exc.name != mod:  # a real import error inside an existing module
                raise
