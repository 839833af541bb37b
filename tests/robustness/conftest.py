"""Helpers: interrupt a run from inside (a signal sent by the process to itself at the k-th step
attempt, as Ctrl-C would arrive) and compare trajectories bit for bit."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

from rothe.io.trajectory import is_timing_array


@pytest.fixture
def signal_at_attempt(monkeypatch):
    """``signal_at_attempt(StepperClass, k, sig)``: the k-th call of ``step`` (counted from now)
    sends ``sig`` to this process before stepping; returns the call counter (a list)."""

    def install(cls, k: int, sig=signal.SIGINT):
        original = cls.__dict__.get("_rothe_original_step", cls.step)
        monkeypatch.setattr(cls, "_rothe_original_step", original, raising=False)
        calls = [0]

        def step(self, state, tau, s_end=None):
            calls[0] += 1
            if calls[0] == k:
                os.kill(os.getpid(), sig)
            return original(self, state, tau, s_end)

        monkeypatch.setattr(cls, "step", step)
        return calls

    return install


def assert_same_trajectory(a, b, skip=("meta",)):
    """Equal arrays (np.array_equal) for every series and statistic but the wall times."""
    if hasattr(a, "files"):  # two np.load results
        keys_a = {k for k in a.files if k not in skip and not is_timing_array(k)}
        keys_b = {k for k in b.files if k not in skip and not is_timing_array(k)}
        assert keys_a == keys_b
        bad = [k for k in sorted(keys_a) if not np.array_equal(a[k], b[k])]
    else:
        assert set(a.keys()) == set(b.keys())
        bad = [k for k in a.keys() if not np.array_equal(a[k], b[k])]
        assert a.stats.untimed() == b.stats.untimed()
    assert not bad, f"differ: {bad}"
