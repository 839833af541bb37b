"""Progress of the evolve loop: a bar on a terminal, plain lines in logs.

On a terminal (stderr is a tty): a tqdm bar whose total is the end of the run -- t/T, or s/S when
the stepper stops at a given S -- with the rate and the ETA, and step, s, t, tau and the
accepted/rejected counts as postfix. It appears only for runs longer than about a second.

Otherwise (a log file, CI, a pipe): one plain line every ``every_seconds`` (default 30 s), e.g.

    rothe: step 1234 (accepted 1200, rejected 34)  s = 1.2345  t = 0.5678/1 (56.8%)  tau = 1.2e-03
      elapsed 0:12:34  eta 0:09:30

(on one line), and a last line when the run stops if any line was printed. No carriage returns.

The position comes from ``stepper.progress_position(state) -> (label, value, total)``; a stepper
without it is shown by its ``state.t`` against ``stepper.problem.T`` when those exist.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass

from ..errors import check_positive


@dataclass
class ProgressOptions:
    """``enabled``: show progress at all; ``every_seconds``: interval of the plain lines written
    when stderr is not a terminal; ``stream``: where to write (default ``sys.stderr``);
    ``terminal``: force (True/False) or detect (None) the bar."""

    enabled: bool = True
    every_seconds: float = 30.0
    stream: object = None
    terminal: bool | None = None

    def __post_init__(self):
        self.every_seconds = check_positive("progress every_seconds", self.every_seconds)


def as_progress_options(progress) -> ProgressOptions:
    """``progress`` if it is :class:`ProgressOptions`, else on/off by its truth value."""
    if isinstance(progress, ProgressOptions):
        return progress
    return ProgressOptions(enabled=bool(progress))


def _clock(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "?"
    seconds = int(round(seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


def _position(stepper, state):
    pos = getattr(stepper, "progress_position", None)
    if pos is not None:
        return pos(state)
    T = getattr(getattr(stepper, "problem", None), "T", None)
    t = getattr(state, "t", None)
    if T is None or t is None:
        return None
    return "t", float(t), float(T)


class Progress:
    """Reports the loop's progress; ``update`` after every step, ``close`` at the end."""

    def __init__(self, options: ProgressOptions, stepper, state):
        self.o = options
        self.stepper = stepper
        self.stream = options.stream if options.stream is not None else sys.stderr
        self.t0 = time.monotonic()
        self.last_line = self.t0
        self.lines = 0
        self.bar = None
        self.start_value = None
        if not options.enabled:
            return
        terminal = options.terminal
        if terminal is None:
            try:
                terminal = self.stream.isatty()
            except (AttributeError, ValueError):
                terminal = False
        pos = _position(stepper, state)
        if pos is not None:
            self.start_value = pos[1]
        if terminal:
            self.bar = self._make_bar(pos)

    def _make_bar(self, pos):
        try:
            from tqdm import tqdm  # heavy: imported when first needed (start-up time)
        except ImportError:  # pragma: no cover - tqdm is a dependency
            return None
        if pos is None:
            return tqdm(
                total=None,
                file=self.stream,
                delay=1.0,
                unit="step",
                leave=False,
                dynamic_ncols=True,
            )
        label, value, total = pos
        bar = tqdm(
            total=total,
            initial=value,
            file=self.stream,
            delay=1.0,
            leave=False,
            dynamic_ncols=True,
            unit=label,
            bar_format="{desc}{percentage:3.0f}%|{bar}| "
            + label
            + " {n:.4g}/{total:.4g} [{elapsed}<{remaining}{postfix}]",
        )
        return bar

    def update(self, state, stats) -> None:
        """After a step: advance the bar (position, fields, accepted/rejected), or print a line
        when ``every_seconds`` have passed since the last.
        """
        if not self.o.enabled:
            return
        if self.bar is not None:
            pos = _position(self.stepper, state)
            if pos is not None:
                self.bar.update(pos[1] - self.bar.n)
            else:
                self.bar.update(1)
            fields = dict(self.stepper.progress_fields(state))
            fields.update(acc=stats.accepted_steps, rej=stats.rejected_steps)
            self.bar.set_postfix(fields, refresh=False)
            return
        now = time.monotonic()
        if now - self.last_line >= self.o.every_seconds:  # only then format anything
            self.last_line = now
            self._line(
                state,
                stats,
                _position(self.stepper, state),
                dict(self.stepper.progress_fields(state)),
                now,
            )

    def _line(self, state, stats, pos, fields, now, prefix="rothe: ") -> None:
        elapsed = now - self.t0
        parts = [
            f"{prefix}step {stats.accepted_steps + stats.rejected_steps} "
            f"(accepted {stats.accepted_steps}, rejected {stats.rejected_steps})"
        ]
        for key in ("s", "t", "tau"):
            if key in fields:
                value = fields[key]
                if pos is not None and key == pos[0]:
                    frac = pos[1] / pos[2] if pos[2] else math.nan
                    value = f"{pos[1]:.5g}/{pos[2]:.5g} ({100 * frac:.1f}%)"
                parts.append(f"{key} = {value}")
        for key, value in fields.items():
            if key not in ("s", "t", "tau"):
                parts.append(f"{key} = {value}")
        parts.append(f"elapsed {_clock(elapsed)}")
        if pos is not None and self.start_value is not None and pos[2]:
            done = (pos[1] - self.start_value) / max(pos[2] - self.start_value, 1e-300)
            if 0 < done < 1:
                parts.append(f"eta {_clock(elapsed * (1 - done) / done)}")
        print("  ".join(parts), file=self.stream, flush=True)
        self.lines += 1

    def note(self, text: str) -> None:
        """One line for the user (e.g. a checkpoint written on SIGUSR1), above the bar on a
        terminal; nothing with ``--quiet``."""
        if not self.o.enabled:
            return
        if self.bar is not None:
            self.bar.write(text, file=self.stream)
        else:
            print(text, file=self.stream, flush=True)

    def close(self, state=None, stats=None, how: str = "stopped") -> None:
        """Close the bar, or print a last line ``rothe: <how> at ...`` if lines were printed."""
        if self.bar is not None:
            self.bar.close()
            self.bar = None
            return
        if self.o.enabled and self.lines and state is not None and stats is not None:
            fields = dict(self.stepper.progress_fields(state))
            self._line(
                state,
                stats,
                _position(self.stepper, state),
                fields,
                time.monotonic(),
                prefix=f"rothe: {how} at ",
            )
