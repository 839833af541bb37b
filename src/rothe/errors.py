"""Errors a user can cause, and the checks that raise them where input enters.

Every message names the parameter, the value received and what is allowed, on one line, e.g.
``tol: got -0.001, must be > 0``. The Python API raises :class:`RotheInputError`, a
:class:`ValueError`, with that message and the parameter's name in ``parameter``; the command line
prints the same line with the parameter replaced by the option it came from (``--tol: got
-0.001, must be > 0``, :meth:`RotheInputError.renamed`, looked up in argparse's own table of the
command) and exits with status 2. Validation happens once, where the value enters the library.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence

import numpy as np


class RotheInputError(ValueError):
    """Bad input: the message names the parameter, the value and what is allowed.

    ``parameter``: the name the message starts with (``tau`` in ``tau: got 0, must be > 0``),
    or None when the message names no single parameter.

    Parameters
    ----------
    message : str
        The one-line message, ``'<parameter>: got <value>, must be ...'``.
    parameter : str, optional
        The parameter it names first.
    mentions : sequence of str
        The other parameters the message names (the command line renames them all to options).
    """

    def __init__(self, message: str, parameter: str | None = None, mentions: Sequence[str] = ()):
        super().__init__(message)
        self.parameter = parameter
        #: other parameters the message names after the first (e.g. the second of a pair)
        self.mentions = tuple(mentions)

    def renamed(self, name: str, others: dict[str, str] | None = None) -> RotheInputError:
        """The same error naming ``name`` (e.g. the CLI option ``--tau``) instead of the
        parameter, and each of ``mentions`` by its entry in ``others`` (parameter -> option);
        unchanged where the message does not start with the parameter's name."""
        message = str(self)
        lead = None if self.parameter is None else re.escape(self.parameter) + r"(?=[: ])"
        if name is not None and lead is not None and re.match(lead, message):
            message = name + message[len(self.parameter) :]
        else:
            name = self.parameter
        for mention in self.mentions:
            option = (others or {}).get(mention)
            if option is not None:
                message = re.sub(rf"(?<![\w-]){re.escape(mention)}(?![\w-])", option, message)
        if message == str(self):
            return self
        out = type(self)(message, name, self.mentions)
        out.__cause__ = self.__cause__
        return out


class DataError(RotheInputError):
    """Problem data that cannot be evaluated (a non-finite load, a load function that raises).

    Found when a problem is built it is bad input like any other (exit status 2); found during
    a run (e.g. a load that turns NaN at t = 0.5) the stepper turns it into :class:`RunFailed`,
    which keeps the trajectory computed so far (exit status 1).
    """


class RunFailed(RuntimeError):
    """A run stopped midway (e.g. the step size fell below tau_min).

    ``where`` holds the context (step, s, t, tau, residuals); the trajectory computed so far is
    attached as ``trajectory`` so that callers can still write it to disk.

    Parameters
    ----------
    message : str
    where : dict, optional
        The context where the run stopped.
    trajectory : Trajectory, optional
        The trajectory computed so far.
    """

    def __init__(self, message: str, where: dict | None = None, trajectory=None):
        super().__init__(message)
        self.where = dict(where or {})
        self.trajectory = trajectory


class RunInterrupted(KeyboardInterrupt):
    """A run stopped by SIGINT or SIGTERM between two steps (the step under way was finished).

    A ``KeyboardInterrupt`` (not an ``Exception``): code that catches failures of single runs
    (``except Exception``, ``except RunFailed``) lets it through, and the run stops. Carries the
    trajectory computed so far (``trajectory``), where the run stopped (``where``: step, s, t),
    the signal number (``signum``) and the checkpoint written (``checkpoint``, a directory, or
    None when the run had no checkpoint); pass that directory as ``resume=`` to continue.
    """

    def __init__(
        self,
        message: str,
        *,
        signum: int,
        where: dict | None = None,
        trajectory=None,
        checkpoint=None,
        state=None,
    ):
        super().__init__(message)
        self.signum = int(signum)
        self.where = dict(where or {})
        self.trajectory = trajectory
        self.checkpoint = checkpoint
        self.state = state

    @property
    def exit_status(self) -> int:
        """128 + signal number: 130 for SIGINT, 143 for SIGTERM (the shell's convention)."""
        return 128 + self.signum


class OutputWriteError(OSError):
    """Writing an output file failed (disk full, read-only file system, permission).

    The message names the file: ``cannot write run1/trajectory.npz: No space left on device``;
    the previous version of the file, if any, is unchanged (outputs are written atomically).
    """

    def __init__(self, path, cause: BaseException):
        errno_ = getattr(cause, "errno", None)
        reason = getattr(cause, "strerror", None) or str(cause) or type(cause).__name__
        super().__init__(errno_, reason, str(path))

    def __str__(self) -> str:
        return f"cannot write {self.filename}: {self.strerror}"


class described(str):
    """A value given as a description (printed without quotes), e.g. 'matrix of shape (2, 2)'."""


def _fmt(value) -> str:
    if isinstance(value, described):
        return str(value)
    if isinstance(value, float):
        return f"{value:g}"
    return repr(value) if isinstance(value, str) else str(value)


def got(value, allowed: str) -> str:
    """``got <value>, <allowed>``: the one-line error after its name (:func:`fail` puts the
    name before it; argparse's type functions of the command line, whose errors argparse
    prefixes with ``argument --option:``, use it alone)."""
    return f"got {_fmt(value)}, {allowed}"


def fail(name: str, value, allowed: str) -> RotheInputError:
    """Build the one-line error ``<name>: got <value>, <allowed>`` (``parameter`` = name)."""
    return RotheInputError(f"{name}: {got(value, allowed)}", name)


def check_real(name: str, value) -> float:
    """``value`` as a finite float; a one-line :class:`RotheInputError` naming ``name``
    otherwise.
    """
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise fail(name, value, "must be a real number") from None
    if not math.isfinite(x):
        raise fail(name, value, "must be finite")
    return x


def check_positive(name: str, value) -> float:
    """``value`` as a finite float > 0 (else a one-line error naming ``name``)."""
    x = check_real(name, value)
    if not x > 0:
        raise fail(name, value, "must be > 0")
    return x


def check_nonnegative(name: str, value) -> float:
    """``value`` as a finite float >= 0 (else a one-line error naming ``name``)."""
    x = check_real(name, value)
    if not x >= 0:
        raise fail(name, value, "must be >= 0")
    return x


def integer_allowed(minimum: int | None = None) -> str:
    """What :func:`check_int` allows, in the words of its message: ``must be an integer``, with
    `` >= minimum`` if given (the one source of that wording: the command line's ``parse_int``
    and the integer checks written by hand use it too)."""
    return "must be an integer" + ("" if minimum is None else f" >= {minimum}")


def check_int(name: str, value, minimum: int | None = None) -> int:
    """``value`` as an int (an integral float is accepted, a bool is not), at least ``minimum``
    if given; else a one-line error naming ``name``. A value that is no number at all (a
    string such as ``'auto'``, None) gets the same line, with the allowed range.
    """
    try:
        integral = not isinstance(value, bool) and float(value).is_integer()
    except (TypeError, ValueError):
        # float('auto') or float(None): it raised its own ValueError/TypeError, naming nothing
        integral = False
    if not integral:
        raise fail(name, value, integer_allowed(minimum))
    n = int(float(value)) if isinstance(value, str) else int(value)  # int('4.0') raises
    if minimum is not None and n < minimum:
        raise fail(name, value, integer_allowed(minimum))
    return n


def check_choice(name: str, value, choices: Sequence[str]) -> str:
    """``value`` if it is one of ``choices``, else a one-line error naming ``name`` that lists
    them.
    """
    if value not in choices:
        raise fail(name, value, "must be one of " + ", ".join(choices))
    return value


def check_instance(name: str, value, types, allowed: str):
    """``value`` if it is an instance of ``types`` (an option object), else the one-line error
    ``<name>: got <value>, must be <allowed>``."""
    if not isinstance(value, types):
        raise fail(name, value, f"must be {allowed}")
    return value


def check_decreasing(name: str, values: Sequence[float]) -> list[float]:
    """A strictly decreasing sequence of positive numbers (the tolerances of Alg. 6.2)."""
    xs = [check_positive(name, v) for v in values]
    if len(xs) == 0:
        raise fail(name, list(values), "must hold at least one tolerance")
    for a, b in zip(xs, xs[1:], strict=False):
        if not b < a:
            raise fail(name, ",".join(_fmt(x) for x in xs), "must be strictly decreasing")
    return xs


def check_finite_array(name: str, array) -> np.ndarray:
    """``array`` as a float array if every entry is finite, else a one-line error naming
    ``name`` with the first NaN or inf.
    """
    a = np.asarray(array, dtype=float)
    if not np.all(np.isfinite(a)):
        bad = a[~np.isfinite(a)].ravel()[0]
        raise fail(name, float(bad), "must be finite (no NaN or inf)")
    return a
