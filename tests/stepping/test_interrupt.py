"""Signals during a run (rothe.stepping.interrupt and the evolve loop).

The signal guard, deterministically, in child processes: the first SIGINT/SIGTERM is only
recorded; the second ends the process at once on the command line (hard_second=True) and raises
KeyboardInterrupt in the Python API (hard_second=False).

Issue 21: a fake stepper whose steps are long (many inner iterations, each followed by
``interrupt.check()``, as the ELD Newton loop and the RIS inner solver will call it) shows that a
stop signal takes effect within one iteration, that the step under way is abandoned (never
accepted, its attempts not counted), that the checkpoint of the last accepted state resumes bit
for bit when the stepper undoes its own changes in ``abandon``, and what happens without that.
SIGHUP and SIGQUIT stop like SIGTERM (exit status 129, 131), a repeated SIGHUP never escalates,
and SIGUSR1 writes a checkpoint at the next step boundary while the run goes on.
"""

from __future__ import annotations

import io
import json
import os
import pty
import re
import signal
import subprocess
import sys
import textwrap
import threading
import time
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import pytest

from rothe.errors import RunInterrupted
from rothe.io.checkpoint import RunCheckpointing, load_checkpoint, restored_vector
from rothe.io.trajectory import Trajectory
from rothe.stepping import interrupt
from rothe.stepping.controllers import UniformController
from rothe.stepping.evolve import evolve
from rothe.stepping.progress import ProgressOptions

from ..conftest import assert_same_trajectory


@dataclass
class State:
    s: float
    t: float
    x: np.ndarray
    k: int = 0


@dataclass
class Result:
    state: State
    tau: float
    converged: bool = True
    code: str = "ok"
    errors: dict = field(default_factory=dict)
    counters: dict = field(default_factory=dict)


class LongStepper:
    """Steps of ``iterations`` inner iterations of ``pause`` seconds each, every one followed by
    ``interrupt.check()``. ``cache`` stands for a reused factorization: each iteration replaces
    it and the next step starts from it, so it changes results (here not only in the last bits,
    to make the point visible). ``abandon`` puts back the cache of the last accepted state."""

    def __init__(self, T=1.0, iterations=20, pause=0.02, undo=True):
        self.problem = SimpleNamespace(T=T)
        self.iterations, self.pause = iterations, pause
        self.cache = 0.0
        self._cache_before = 0.0
        self.undo = undo
        self.abandoned = 0

    def initial(self):
        return State(0.0, 0.0, np.linspace(0.1, 0.3, 3))

    def step(self, state, tau, s_end):
        self._cache_before = self.cache
        x = state.x.copy()
        for _ in range(self.iterations):
            x = x + tau * np.sin(x + self.cache) / self.iterations
            self.cache = float(np.sum(x))
            time.sleep(self.pause)
            interrupt.check()
        return Result(
            State(state.s + tau, state.t + tau, x, state.k + 1),
            tau,
            counters={"newton_iterations": self.iterations},
        )

    def abandon(self, state):
        self.abandoned += 1
        if self.undo:
            self.cache = self._cache_before

    # -- the rest of the stepper protocol --------------------------------------------------
    def adapt(self, state, result):
        return state

    def record(self, traj, result, state):
        traj.append(t=state.t, x=state.x.copy(), tau=result.tau)

    def finished(self, state):
        return state.t >= self.problem.T - 1e-12

    def limit(self, state, tau):
        return min(tau, self.problem.T - state.t)

    def overshoot(self, state, attempts):
        return None

    def pick_landing(self, state, attempts):
        return attempts[-1]

    def where(self, state, result):
        return {"step": state.k, "s": state.s, "t": state.t}

    def progress_fields(self, state):
        return {"t": f"{state.t:.3g}"}

    def checkpoint_state(self, state):
        return {"s": state.s, "t": state.t, "x": state.x, "k": state.k, "cache": self.cache}

    def restore_state(self, data):
        self.cache = float(data["cache"])
        return State(
            float(data["s"]), float(data["t"]), restored_vector(data, "x", 3), int(data["k"])
        )


class NoUndo(LongStepper):
    """The same stepper without ``abandon``: the abandoned attempt's cache stays."""

    abandon = None


class Problem:
    T = 1.0

    def fingerprint(self):
        return {"fake": 1}


def drive(stepper, checkpoint=None, resume=None, progress=False):
    """A driver as run_ris / run_eld are: checkpoint at the start, evolve, completed at the
    end."""
    controller = UniformController(0.1)
    with RunCheckpointing("fake", Problem(), {"tau": 0.1}, checkpoint, resume) as rc:
        if rc.resuming:
            traj = rc.restored.trajectory(0)
            state = rc.restore(stepper, controller)
        else:
            traj = Trajectory()
            state = stepper.initial()
            traj.append(t=state.t, x=state.x.copy())
        cp = rc.checkpointer
        if cp is not None:
            cp.register(traj)
            cp.save(stepper, controller, state)
        state = evolve(stepper, controller, state, traj, checkpointer=cp, progress=progress)
        if cp is not None:
            cp.save(stepper, controller, state, status="completed")
    return traj


def signal_after(seconds: float, sig=signal.SIGINT) -> list[float]:
    """Send ``sig`` to this process after ``seconds`` (from a thread, as a kill would); the
    list receives the instant it was sent."""
    sent: list[float] = []

    def send():
        sent.append(time.perf_counter())
        os.kill(os.getpid(), sig)

    threading.Timer(seconds, send).start()
    return sent


@pytest.fixture(autouse=True)
def _keep_the_terminal(monkeypatch):
    """In-process SIGHUP: do not send a terminal running pytest -s to /dev/null."""
    monkeypatch.setattr(interrupt, "_detach_terminal", lambda: None)


def test_a_signal_inside_a_long_step_takes_effect_within_one_iteration(tmp_path):
    kw = dict(T=0.5, iterations=40, pause=0.02)  # 5 steps of 40 iterations, 0.8 s each
    full = drive(LongStepper(**kw))
    stepper = LongStepper(**kw)
    sent = signal_after(1.2)  # during the second step (or, on a loaded machine, the first)
    with pytest.raises(RunInterrupted) as info:
        drive(stepper, checkpoint=tmp_path / "c")
    latency = time.perf_counter() - sent[0]
    exc = info.value
    assert latency < 0.4  # one iteration is 0.02 s; the rest of the step would be up to 0.8 s
    assert exc.exit_status == 130 and stepper.abandoned == 1
    k = exc.where["accepted_steps"]
    assert exc.where["abandoned_step"] is True and 0 <= k < 5
    assert str(exc).endswith("; the step under way was abandoned)")
    # the abandoned attempt is nowhere: not recorded, not counted
    traj = exc.trajectory
    assert len(traj["tau"]) == k and traj.stats.inner_solves == k
    assert traj.stats.newton_iterations == 40 * k and traj.stats.rejected_steps == 0
    ckpt = load_checkpoint(tmp_path / "c")
    assert ckpt.status == "interrupted" and ckpt.where["abandoned_step"] is True
    assert ckpt.where["accepted_steps"] == k
    # resumed: the uninterrupted run, bit for bit, statistics too
    resumed = drive(LongStepper(**kw), resume=tmp_path / "c")
    assert_same_trajectory(full, resumed)


def test_without_abandon_the_abandoned_attempt_leaks_into_the_resumed_run(tmp_path):
    """Why a stepper whose caches change results must implement ``abandon``: the checkpoint
    holds the cache the abandoned attempt left, and the resumed run differs."""
    kw = dict(T=0.5, iterations=40, pause=0.02)
    full = drive(NoUndo(**kw))
    signal_after(1.2)
    with pytest.raises(RunInterrupted) as info:
        drive(NoUndo(**kw), checkpoint=tmp_path / "c")
    assert info.value.where["abandoned_step"] is True
    resumed = drive(NoUndo(**kw), resume=tmp_path / "c")
    assert len(resumed["tau"]) == len(full["tau"])
    assert not np.array_equal(resumed["x"], full["x"])


@pytest.mark.parametrize(
    "sig, status",
    [(signal.SIGINT, 130), (signal.SIGTERM, 143), (signal.SIGHUP, 129), (signal.SIGQUIT, 131)],
)
def test_every_stop_signal_stops_the_run_with_128_plus_its_number(sig, status):
    signal_after(0.5, sig)
    with pytest.raises(RunInterrupted) as info:
        drive(LongStepper())
    assert info.value.exit_status == status
    assert info.value.where["signal"] == signal.Signals(sig).name
    assert signal.getsignal(sig) is not None  # handlers restored after the run


def test_sigusr1_writes_a_checkpoint_and_the_run_goes_on(tmp_path):
    stream = io.StringIO()
    signal_after(0.9, signal.SIGUSR1)
    traj = drive(
        LongStepper(),
        checkpoint=tmp_path / "c",
        progress=ProgressOptions(enabled=True, stream=stream, terminal=False, every_seconds=1e9),
    )
    assert len(traj["tau"]) == 10
    ckpt = load_checkpoint(tmp_path / "c")
    assert ckpt.status == "completed" and ckpt.sequence == 3  # start, SIGUSR1, end
    lines = [ln for ln in stream.getvalue().splitlines() if "SIGUSR1" in ln]
    assert len(lines) == 1 and re.fullmatch(
        rf"rothe: SIGUSR1: checkpoint written to {re.escape(str(tmp_path / 'c'))} after [1-9] "
        r"accepted steps \(s = [\d.]+, t = [\d.]+\); the run goes on",
        lines[0],
    ), lines


def test_check_does_nothing_outside_a_step():
    with interrupt.interruptible():
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.01)
        assert interrupt.requested() == signal.SIGINT
        interrupt.check()  # not inside abandonable(): no exception
        with pytest.raises(interrupt.StepAbandoned), interrupt.abandonable():
            interrupt.check()
    interrupt.check()  # no guard at all


def test_agree_acts_only_on_what_every_process_was_told():
    """Many processes (interrupt.agree, the PETSc backend): a signal that arrives while this
    process waits in the agreement's allreduce (here: inside reduce) must not make it stop, or
    write a checkpoint, alone -- the others have passed that agreement and would wait in the
    next collective operation for ever (the CI hang of tests/mpi's SIGTERM test). It becomes
    everybody's at the next agreement; what another process received arrives through reduce."""
    others = [0, 0]  # what the other process contributes to the maximum

    def reduce(mine):
        os.kill(os.getpid(), signal.SIGTERM)  # arrives "during" the allreduce, after the send
        time.sleep(0.01)
        return [max(a, b) for a, b in zip(others, [0, 0], strict=True)]  # sent before it came

    with interrupt.interruptible():
        interrupt.agree(reduce)
        assert interrupt.requested() is None  # received here, not yet agreed
        with interrupt.abandonable():
            interrupt.check()  # nothing to act on either
        assert interrupt.checkpoint_requested() is False
        sent = []
        interrupt.agree(lambda mine: sent.append(list(mine)) or list(mine))
        assert sent == [[signal.SIGTERM, 0]]
        assert interrupt.requested() == signal.SIGTERM
    # the other side: a checkpoint request and a stop that reached another process
    with interrupt.interruptible():
        interrupt.agree(lambda mine: [max(mine[0], signal.SIGINT), max(mine[1], 1)])
        assert interrupt.requested() == signal.SIGINT
        assert interrupt.checkpoint_requested() is True
        assert interrupt.checkpoint_requested() is False  # taken once
        interrupt.agree(lambda mine: [signal.SIGTERM, 0])
        assert interrupt.requested() == signal.SIGINT  # the first agreed signal stays
    interrupt.agree(lambda mine: pytest.fail("no guard: no collective call"))


CHILD = textwrap.dedent("""
    import os, signal, sys, time
    from rothe.stepping import interrupt
    with interrupt.interruptible(hard_second=True):
        for sig in map(int, sys.argv[1:]):
            os.kill(os.getpid(), sig)
            time.sleep(0.05)
        print("alive", interrupt.requested(), flush=True)
    """)


@pytest.mark.parametrize(
    "signals, survives",
    [
        ((signal.SIGHUP, signal.SIGHUP, signal.SIGHUP), True),  # kernel + shell: never escalates
        ((signal.SIGHUP, signal.SIGTERM), False),  # a deliberate second signal does
        ((signal.SIGQUIT, signal.SIGINT), False),
        ((signal.SIGUSR1, signal.SIGUSR1), True),  # a checkpoint request never ends a run
    ],
)
def test_repeated_hangups_do_not_escalate(signals, survives):
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, *map(str, map(int, signals))],
        capture_output=True,
        text=True,
        timeout=60,
    )
    if survives:
        first = next((s for s in signals if s in interrupt.SIGNALS), None)
        assert proc.stdout.split() == ["alive", str(None if first is None else int(first))]
        assert proc.returncode == 0, proc.stderr
    else:
        assert proc.stdout == "" and proc.returncode == -signals[-1]


def test_a_hangup_sends_a_terminal_output_to_dev_null(tmp_path):
    """In a child whose stdout is a pseudo-terminal: after SIGHUP the fd is /dev/null (writes
    to a vanished terminal fail with EIO); a log file is left alone."""
    script = textwrap.dedent("""
        import os, signal, sys
        from rothe.stepping import interrupt
        with interrupt.interruptible(hard_second=True):
            os.kill(os.getpid(), signal.SIGHUP)
        null = os.stat(os.devnull).st_rdev
        out = os.fstat(1).st_rdev == null and not os.isatty(1)
        err = os.fstat(2).st_rdev == null
        with open(sys.argv[1], "w") as f:
            f.write(f"{out} {err}")
        """)
    master, slave = pty.openpty()
    log = open(tmp_path / "log", "w")  # noqa: SIM115 - the child's stderr
    try:
        proc = subprocess.run(
            [sys.executable, "-c", script, str(tmp_path / "result")],
            stdout=slave,
            stderr=log,
            timeout=60,
        )
    finally:
        os.close(slave)
        os.close(master)
        log.close()
    assert proc.returncode == 0
    assert (tmp_path / "result").read_text() == "True False"


def test_evolve_records_abandoned_steps_in_the_checkpoint_header(tmp_path):
    signal_after(0.5, signal.SIGTERM)
    with pytest.raises(RunInterrupted):
        drive(LongStepper(), checkpoint=tmp_path / "c")
    header = load_checkpoint(tmp_path / "c", header_only=True).header
    assert header["where"]["signal"] == "SIGTERM" and header["where"]["abandoned_step"]
    assert json.dumps(header["where"])  # plain JSON


# -- the guard of a run: the second signal ----------------------------------------------------


GUARD_CHILD = textwrap.dedent("""
    import os, signal, sys, time
    from rothe.stepping.interrupt import interruptible, requested
    first, second, hard = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3] == "hard"
    with interruptible(hard_second=hard):
        os.kill(os.getpid(), first)
        time.sleep(0.05)
        print("recorded", requested(), flush=True)
        try:
            os.kill(os.getpid(), second)
            time.sleep(0.5)
        except KeyboardInterrupt:
            print("KeyboardInterrupt", flush=True)
            sys.exit(0)
        print("survived the second signal", flush=True)
    sys.exit(3)
""")


def _child(first, second, mode):
    return subprocess.run(
        [sys.executable, "-c", GUARD_CHILD, str(int(first)), str(int(second)), mode],
        capture_output=True,
        text=True,
        timeout=60,
    )


@pytest.mark.parametrize("first", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize("second", [signal.SIGINT, signal.SIGTERM])
def test_command_line_guard_second_signal_ends_the_process_at_once(first, second):
    proc = _child(first, second, "hard")
    assert proc.stdout.splitlines() == [f"recorded {int(first)}"], proc.stderr
    assert proc.returncode == -second  # killed by the signal itself, not a Python exit


def test_api_guard_second_ctrl_c_raises_keyboard_interrupt():
    proc = _child(signal.SIGINT, signal.SIGINT, "soft")
    assert proc.stdout.splitlines() == [f"recorded {int(signal.SIGINT)}", "KeyboardInterrupt"]
    assert proc.returncode == 0, proc.stderr


def test_call_abandons_a_long_compiled_call_within_a_poll():
    """interrupt.call runs a call that releases the GIL (a sparse LU; here time.sleep) in a
    worker thread inside a step, so that a stop signal abandons the step at once instead of
    after the call; elsewhere it is the call itself, in this thread."""
    where = []

    def long_call():
        where.append(threading.current_thread() is threading.main_thread())
        time.sleep(2.0)
        return 42

    assert interrupt.call(lambda: 7) == 7  # no guard: called as is
    with interrupt.interruptible():
        assert interrupt.call(long_call) == 42 and where == [True]  # outside a step
        with interrupt.abandonable():
            assert interrupt.call(lambda: 8) == 8
            with pytest.raises(ZeroDivisionError):
                interrupt.call(lambda: 1 / 0)  # the worker's exception, raised here
            sent = signal_after(0.2)
            with pytest.raises(interrupt.StepAbandoned):
                interrupt.call(long_call)
            latency = time.perf_counter() - sent[0]
    assert where == [True, False] and latency < 0.5, latency  # the call alone takes 2 s


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        return int(next(line for line in f if line.startswith("VmRSS")).split()[1]) / 1024


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="needs /proc")
def test_splu_in_a_step_is_scipys_and_releases_its_memory():
    """interrupt.splu makes SuperLU factorizations in the worker thread and releases them
    there: SuperLU frees a block only in the thread that allocated it, so factors made in a
    worker and dropped in the main thread leaked (ris-front --adapt-space: +40 MB/s). The same
    factors and solutions as scipy's, bit for bit, and no growth over 400 factorizations."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    n = 40
    T = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n))
    A = (sp.kron(T, sp.identity(n)) + sp.kron(sp.identity(n), T)).tocsc()  # 1600 unknowns
    b = np.linspace(0.0, 1.0, A.shape[0])
    expected = spla.splu(A, permc_spec="MMD_AT_PLUS_A").solve(b)
    with interrupt.interruptible(), interrupt.abandonable():
        lu = interrupt.splu(A, permc_spec="MMD_AT_PLUS_A")
        assert np.array_equal(lu.solve(b), expected) and lu.shape == A.shape
        del lu
        before = _rss_mb()
        for _ in range(400):  # each leaked ~0.5 MB when released in the main thread
            lu = interrupt.splu(A, permc_spec="MMD_AT_PLUS_A")
            lu.solve(b)
        del lu
        grown = _rss_mb() - before
    assert grown < 60, grown
