"""The signal guard of a run (rothe.stepping.interrupt), deterministically, in child processes:
the first SIGINT/SIGTERM is only recorded; the second ends the process at once on the command
line (hard_second=True) and raises KeyboardInterrupt in the Python API (hard_second=False)."""

import signal
import subprocess
import sys
import textwrap

import pytest

CHILD = textwrap.dedent("""
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
        [sys.executable, "-c", CHILD, str(int(first)), str(int(second)), mode],
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
