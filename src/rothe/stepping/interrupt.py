"""Signals during a run: the handlers only set flags; the evolve loop acts on them.

Inside :func:`interruptible`:

- **SIGINT, SIGTERM, SIGHUP, SIGQUIT** (:data:`SIGNALS`) ask the run to stop. The first one is
  recorded (:func:`requested`) and nothing else happens at that instant. The evolve loop stops
  at the next step boundary, or sooner, inside a long step, at the next :func:`check` the step
  makes (between Newton iterations, between inner solves, while a factorization runs:
  :func:`call`, :func:`splu`): that step is *abandoned* -- never accepted, never recorded.
  Either way the loop writes a checkpoint of the last accepted state and raises
  :class:`~rothe.errors.RunInterrupted` (exit status 128 + signal: 130, 143, 129, 131).
  SIGHUP is what a dropped SSH session sends: the run stops like on SIGTERM, and standard
  output and error, if they are a terminal (now gone), are sent to ``/dev/null`` so that
  writing the results and the last messages cannot fail on it. SIGQUIT (Ctrl-\\) stops like
  SIGTERM; a second one dumps core at once, as usual.
- **SIGUSR1** asks for a checkpoint *now* (:func:`checkpoint_requested`): the loop writes one at
  the next step boundary and the run goes on. Batch schedulers send it before a time limit
  (SLURM ``--signal=USR1@300``), so that the kill at the limit loses little.

A handler never touches files or solver state, so a signal cannot leave anything half-updated.
The second stop signal is not deferred:

- ``hard_second=True`` (the command line): after the first stop signal SIGINT, SIGTERM and
  SIGQUIT get the system default, so a second one ends the process at once, even inside a long
  factorization. Files stay consistent because every output is written atomically
  (:mod:`rothe.io.atomic`); at worst a hidden temporary file is left, which the next run removes.
- ``hard_second=False`` (the Python API): the handlers that were installed before are restored,
  so in an interactive session a second Ctrl-C raises ``KeyboardInterrupt`` as usual.

A repeated SIGHUP never escalates (a hang-up often comes twice: from the kernel and from the
shell): after the first stop signal it is ignored.

**Abandoning a step** (:func:`check`, :class:`StepAbandoned`): code that runs for long inside a
step calls :func:`check` between its iterations. Inside the loop's :func:`abandonable` region
(one attempt: the step and its landing retries, the decision and, after an acceptance, the
adapt step; never the recording, the checkpoint or the set-up) a recorded stop signal makes it
raise :class:`StepAbandoned`, a ``BaseException`` so that the ``except Exception`` of a solver
that turns errors into a failed step lets it through; anywhere else :func:`check` does nothing.
The loop then puts its statistics and the controller back as they were before the attempt and
calls the stepper's ``abandon(state)`` (if it has one), which must undo what the abandoned
attempt changed in the stepper (a refactorization, a warm-start hint, counters, a mesh refined
in the attempt) back to where ``begin_attempt(state)`` found it, so that the checkpoint of the
last accepted state resumes exactly like the uninterrupted run (docs/robustness.md, *Signals*).

Handlers can only be installed from the main thread; elsewhere (e.g. a Dask worker thread)
:func:`interruptible` does nothing and runs are stopped the usual way.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import queue
import signal
import stat
import sys
import threading

#: signals that stop a run (the first is deferred to a step boundary or a check())
SIGNALS = tuple(
    getattr(signal, name)
    for name in ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT")
    if hasattr(signal, name)
)
#: the signal that asks for a checkpoint now (the run goes on)
CHECKPOINT_SIGNALS = tuple(getattr(signal, name) for name in ("SIGUSR1",) if hasattr(signal, name))
_HUP = getattr(signal, "SIGHUP", None)
_active: _Guard | None = None
_checkpoint_now = False  # SIGUSR1 arrived and no checkpoint was written since


class StepAbandoned(BaseException):
    """Raised by :func:`check` inside a step when a stop signal arrived: the evolve loop
    abandons the step under way (it is never accepted) and stops with RunInterrupted.

    A ``BaseException``: solvers that catch ``Exception`` to report a failed step let it
    through. Code between :func:`check` and the loop must not swallow it."""

    def __init__(self, signum: int):
        super().__init__(f"step abandoned on {signal_name(signum)}")
        self.signum = int(signum)


class _Guard:
    def __init__(self, hard_second: bool):
        self.hard_second = hard_second
        self.received: int | None = None  # the first stop signal this process received
        self.abandonable = 0  # depth of abandonable() regions
        self.previous: dict[int, object] = {}
        # many processes (agree()): what the last agreement made common to all of them
        self.collective = False
        self.agreed: int | None = None
        self.checkpoint_agreed = False

    @property
    def signum(self) -> int | None:
        """The stop signal the run acts on: the received one, or on many processes the agreed
        one (:func:`agree`)."""
        return self.agreed if self.collective else self.received

    def handler(self, signum, frame):  # noqa: ARG002 - signal API
        if signum in CHECKPOINT_SIGNALS:
            _ask_for_checkpoint(signum, frame)
            return
        if signum == _HUP:
            _detach_terminal()
        if self.received is not None:  # only SIGHUP comes here again (ignored, see below)
            return
        self.received = signum
        for sig in SIGNALS:
            if sig == _HUP:
                signal.signal(sig, self.handler)  # a repeated hang-up: nothing more to do
            elif self.hard_second:
                signal.signal(sig, signal.SIG_DFL)
            else:
                prev = self.previous.get(sig)
                signal.signal(sig, prev if prev is not None else signal.SIG_DFL)


def _detach_terminal() -> None:
    """After a hang-up: standard output and error that are a terminal (a character device other
    than /dev/null) go to /dev/null, so that writes to the vanished terminal (EIO) cannot stop
    the run from writing its results. Files and pipes (a log, nohup) are left alone."""
    try:
        null = os.open(os.devnull, os.O_WRONLY)
    except OSError:
        return
    try:
        null_dev = os.fstat(null).st_rdev
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(OSError, ValueError, AttributeError):
                fd = stream.fileno()
                st = os.fstat(fd)
                if stat.S_ISCHR(st.st_mode) and st.st_rdev != null_dev:
                    with contextlib.suppress(OSError, ValueError):
                        stream.flush()
                    os.dup2(null, fd)
    finally:
        os.close(null)


class interruptible:
    """Context manager: stop signals set the flag that :func:`requested` reports, SIGUSR1 the
    one :func:`checkpoint_requested` reports (module docstring).

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
        for sig in SIGNALS + CHECKPOINT_SIGNALS:
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
    """The number of the stop signal received inside the active guard, or None."""
    return None if _active is None else _active.signum


def _ask_for_checkpoint(signum, frame):  # noqa: ARG001 - signal API
    global _checkpoint_now
    _checkpoint_now = True


def keep_checkpoint_requests() -> None:
    """For the whole process (the command line calls it first): SIGUSR1 never ends it -- its
    default action -- but is kept as a request that the next run's loop honours at its first
    step boundary (it may arrive while the run is still being set up, or between the runs of a
    sweep). Main thread only; elsewhere a no-op."""
    if threading.current_thread() is not threading.main_thread():
        return
    for sig in CHECKPOINT_SIGNALS:
        signal.signal(sig, _ask_for_checkpoint)


def checkpoint_requested() -> bool:
    """Whether SIGUSR1 arrived since the last call inside a guard (the request is taken: a
    second call returns False until the next SIGUSR1); on many processes, whether the last
    :func:`agree` found one on any process."""
    global _checkpoint_now
    guard = _active
    if guard is None:
        return False
    if guard.collective:
        asked, guard.checkpoint_agreed = guard.checkpoint_agreed, False
        return asked
    if not _checkpoint_now:
        return False
    _checkpoint_now = False
    return True


@contextlib.contextmanager
def abandonable():
    """The region in which :func:`check` may abandon the work under way (the evolve loop puts
    the step and its landing retries in it)."""
    guard = _active
    if guard is None:
        yield
        return
    guard.abandonable += 1
    try:
        yield
    finally:
        guard.abandonable -= 1


def check() -> None:
    """Raise :class:`StepAbandoned` if a stop signal arrived and the code runs inside an
    :func:`abandonable` region (a step of the evolve loop); else do nothing (cheap: call it
    between iterations).

    Where the families call it: after every iteration of the RIS inner solver (the step's
    solve and the relaxation of a transferred state in the adapt step), after every Newton
    iteration of an ELD step with nonlinear damping and between the refine-and-resolve rounds
    of an ELD step with space adaptivity; and while a sparse LU factorization of a step runs
    (:func:`splu`, :func:`call`). So an interruption takes effect within one iteration, not
    after the whole step."""
    guard = _active
    if guard is not None and guard.signum is not None and guard.abandonable > 0:
        raise StepAbandoned(guard.signum)


def _in_a_step() -> bool:
    """Inside an :func:`abandonable` region of an active guard, in the main thread."""
    guard = _active
    return (
        guard is not None
        and guard.abandonable > 0
        and threading.current_thread() is threading.main_thread()
    )


def call(fn):
    """``fn()``, made abandonable: a long call into compiled code that releases the GIL (a
    sparse LU factorization: SuperLU does) cannot itself call :func:`check`. Inside an
    :func:`abandonable` region of an active guard, ``fn`` runs in the one worker thread of this
    module while this thread waits for it and calls :func:`check` every :data:`POLL_SECONDS`
    (and once when it is done), so a stop signal abandons the step within that time instead of
    after the call (measured: a 25 s LU of a 3D RIS step, docs/robustness.md). The abandoned
    call finishes in the background and its result is dropped; ``fn`` must therefore change
    nothing but its return value. Anywhere else (no guard, outside a step, not the main
    thread): ``fn()`` as is. The result is the same either way (the same computation, bit for
    bit). For SuperLU use :func:`splu`: its memory must also be released in the worker."""
    if not _in_a_step():
        return fn()
    job = _Worker.get().submit(fn)
    while True:
        finished = job.done.wait(POLL_SECONDS)
        try:
            check()
        except StepAbandoned:
            if not finished:
                _leave_running(job)
            raise
        if finished:
            break
    if job.error is not None:
        raise job.error
    value, job.value = job.value, None
    return value


def splu(A, **kwargs):
    """``scipy.sparse.linalg.splu(A, **kwargs)``, abandonable inside a step (:func:`call`).

    The factorization is made in the worker thread and, when its last reference goes, released
    there too: scipy's SuperLU keeps the books of its memory per thread and frees a block only
    in the thread that allocated it. Released elsewhere, the factors leaked (``ris-front
    --adapt-space`` grew by 40 MB/s to 10 GB in 4 minutes, where it used to stay at 260 MB).
    The returned object has SuperLU's ``solve`` (and its other attributes)."""
    # heavy: imported when first needed (start-up time of the command line)
    from scipy.sparse.linalg import splu as scipy_splu

    if not _in_a_step():
        return scipy_splu(A, **kwargs)
    return call(lambda: _WorkerLU(scipy_splu(A, **kwargs)))


class _WorkerLU:
    """A SuperLU factorization made in the worker thread, released there (:func:`splu`)."""

    def __init__(self, lu):
        self._lu = lu

    def solve(self, rhs, trans="N"):
        """SuperLU's solve."""
        return self._lu.solve(rhs, trans)

    def __getattr__(self, name):
        if name == "_lu":  # not set (yet): no recursion
            raise AttributeError(name)
        return getattr(self._lu, name)

    def __del__(self):
        lu = self.__dict__.pop("_lu", None)
        # at interpreter exit the module's globals may already be gone (None): the process
        # frees everything then anyway
        worker = globals().get("_Worker")
        if lu is not None and worker is not None:
            worker.release(lu)


class _Job:
    """One call run by the worker: ``fn``, then ``value`` or ``error``, then ``done``."""

    def __init__(self, fn):
        self.fn = fn
        self.done = threading.Event()
        self.value = None
        self.error: BaseException | None = None

    def run(self) -> None:
        """Run ``fn`` (in the worker thread)."""
        try:
            self.value = self.fn()
        except BaseException as exc:  # noqa: BLE001 - handed to the waiting thread
            self.error = exc
        finally:
            self.fn = None
            self.done.set()


class _Worker:
    """The one worker thread of :func:`call` (started when first needed, stopped at
    interpreter exit): runs the calls one after another and drops the objects handed to
    :meth:`release`, so that what a call made is also freed in its thread."""

    _instance: _Worker | None = None

    def __init__(self):
        self.jobs: queue.SimpleQueue = queue.SimpleQueue()
        self.stopped = False
        self.thread = threading.Thread(target=self._run, name="rothe-abandonable-call", daemon=True)
        self.thread.start()
        atexit.register(self.stop)

    @classmethod
    def get(cls) -> _Worker:
        """The worker (started on first use)."""
        if cls._instance is None:
            cls._instance = _Worker()
        return cls._instance

    def submit(self, fn) -> _Job:
        """Run ``fn()`` in the worker thread; returns its job."""
        job = _Job(fn)
        self.jobs.put(job)
        return job

    @classmethod
    def release(cls, obj) -> None:
        """Drop ``obj`` in the worker thread (here, once the worker has stopped: at exit)."""
        worker = cls._instance
        if worker is not None and not worker.stopped:
            worker.jobs.put(obj)

    def _run(self) -> None:
        while True:
            item = self.jobs.get()
            if item is None:
                return
            if isinstance(item, _Job):
                item.run()
            del item  # an object handed to release(): its last reference goes here

    def stop(self) -> None:
        """At interpreter exit (after :func:`_at_exit`): stop the worker once it is idle."""
        self.stopped = True
        self.jobs.put(None)
        self.thread.join(timeout=60)


#: how often :func:`call` looks for a stop signal while its worker runs
POLL_SECONDS = 0.05
_abandoned: list[_Job] = []  # abandoned calls (the worker may still run them)
_exit_status: int | None = None  # what the command line returns (will_exit_with)


def _leave_running(job: _Job) -> None:
    """Remember an abandoned call (once: the handler at interpreter exit)."""
    if not _abandoned:
        atexit.register(_at_exit)
    _abandoned.append(job)


def will_exit_with(status: int) -> None:
    """(The command line, with the status it returns to the interpreter.) If a call abandoned
    by a stop signal (:func:`call`) still runs when the interpreter exits, the process ends with
    ``status`` at once (standard output and error flushed first) instead of waiting for it."""
    global _exit_status
    _exit_status = int(status)


def _at_exit() -> None:
    """At interpreter exit, with an abandoned call still running: a SuperLU factorization in
    the worker would run into the interpreter's finalization (measured, Python 3.11:
    ``Exception ignored in <stdout>``, exit status 120). The command line
    (:func:`will_exit_with`) ends the process at once with its status, results and checkpoint
    written; the Python API waits for the call (the rest of one factorization)."""
    running = [job for job in _abandoned if not job.done.is_set()]
    if not running:
        return
    if _exit_status is None:
        for job in running:
            job.done.wait()
        return
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(_exit_status)


def signal_name(signum: int) -> str:
    """``'SIGINT'``, ``'SIGTERM'``, ... for a signal number (``'signal <n>'`` if unknown)."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def agree(reduce) -> None:
    """Runs on many processes: make the signals that reached any process everybody's, at the
    same point of every process's loop (the distributed backend calls it on every process at
    the loop's stop test, :mod:`rothe.eld.distributed`).

    ``reduce(values) -> values``: the elementwise maximum of a list of ints over the processes
    (an allreduce). From the first call on, inside the active guard, :func:`requested`,
    :func:`check` and :func:`checkpoint_requested` report only what an agreement made common:
    a signal that reaches one process while the others are already past their last agreement
    (e.g. while this process waits in that very allreduce) waits for the next one. Reading the
    process's own flag instead would let that process alone stop, or alone write a
    checkpoint, and leave the others waiting in a collective operation for ever. Outside a
    guard: nothing (no collective call either, so every process must be in the same case)."""
    global _checkpoint_now
    guard = _active
    if guard is None:
        return
    guard.collective = True
    asked, _checkpoint_now = _checkpoint_now, False
    stop, checkpoint = reduce([guard.received or 0, int(asked)])
    if stop and guard.agreed is None:
        guard.agreed = int(stop)
    guard.checkpoint_agreed = guard.checkpoint_agreed or bool(checkpoint)
