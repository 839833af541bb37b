"""SIGINT / SIGTERM during a run: the handlers only set a flag; the evolve loop stops between steps.

Inside :func:`interruptible` the first SIGINT or SIGTERM is recorded (:func:`requested`) and
nothing else happens at that instant: the step under way finishes, then the evolve loop writes a
checkpoint and raises :class:`~rothe.errors.RunInterrupted` with the trajectory so far. A handler
never touches files or solver state, so a signal cannot leave anything half-updated.

The second signal is not deferred:

- ``hard_second=True`` (the command line): the first signal resets both signals to the system
  default, so a second Ctrl-C (or TERM) ends the process at once, even inside a long
  factorization. Files stay consistent because every output is written atomically
  (:mod:`rothe.io.atomic`); at worst a hidden temporary file is left, which the next run removes.
- ``hard_second=False`` (the Python API): the handlers that were installed before are restored,
  so in an interactive session a second Ctrl-C raises ``KeyboardInterrupt`` as usual.

Handlers can only be installed from the main thread; elsewhere (e.g. a Dask worker thread)
:func:`interruptible` does nothing and runs are stopped the usual way.
"""

from __future__ import annotations

import signal
import threading

SIGNALS = (signal.SIGINT, signal.SIGTERM)
_active: _Guard | None = None


class _Guard:
    def __init__(self, hard_second: bool):
        self.hard_second = hard_second
        self.signum: int | None = None
        self.previous: dict[int, object] = {}

    def handler(self, signum, frame):  # noqa: ARG002 - signal API
        if self.signum is None:
            self.signum = signum
            for sig in SIGNALS:
                if self.hard_second:
                    signal.signal(sig, signal.SIG_DFL)
                else:
                    prev = self.previous.get(sig)
                    signal.signal(sig, prev if prev is not None else signal.SIG_DFL)


class interruptible:
    """Context manager: SIGINT/SIGTERM set the flag that :func:`requested` reports.

    Re-entrant: inside an active guard (e.g. the command line's, around the whole run and the
    writing of its results) a nested one (the evolve loop's) is a no-op.
    """

    def __init__(self, *, hard_second: bool = False):
        self.hard_second = hard_second
        self._owner = False

    def __enter__(self):
        global _active
        if _active is not None or threading.current_thread() is not threading.main_thread():
            return self
        guard = _Guard(self.hard_second)
        for sig in SIGNALS:
            guard.previous[sig] = signal.getsignal(sig)
            signal.signal(sig, guard.handler)
        _active = guard
        self._owner = True
        return self

    def __exit__(self, *exc):
        global _active
        if not self._owner:
            return False
        guard, _active = _active, None
        for sig, prev in guard.previous.items():
            signal.signal(sig, prev if prev is not None else signal.SIG_DFL)
        self._owner = False
        return False


def requested() -> int | None:
    """The number of the signal received inside the active guard, or None."""
    return None if _active is None else _active.signum


def signal_name(signum: int) -> str:
    """``'SIGINT'``, ``'SIGTERM'``, ... for a signal number (``'signal <n>'`` if unknown)."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"
