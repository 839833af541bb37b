"""Issue 21's bad inputs as a command-line harness: every case of tests/cli/test_bad_input.py,
plus damaged checkpoints given to ``rothe resume``, run as separate ``rothe`` processes.

A case is handled when the process exits with the expected status, prints exactly the expected
line on stderr (one line, no traceback) and, for a refusal (exit 2), leaves no ``--out``
folder. Prints one line per case and the count::

    PYTHONPATH=src python benchmarks/bad_inputs.py [--only TEXT] [--skip TEXT] [--src DIR]
        [--timeout SECONDS]

``--src`` runs another source tree (e.g. an older commit's ``src``, to count what it handled);
a case that runs longer than ``--timeout`` is killed and counted as not handled. (Do not run
``--workers 1000`` against a tree without the worker check: it starts 1000 processes.)
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _cases_module():
    path = ROOT / "tests" / "cli" / "test_bad_input.py"
    spec = importlib.util.spec_from_file_location("bad_input_cases", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


SRC = ROOT / "src"
TIMEOUT = 600.0


def _rothe(argv, cwd):
    env = dict(os.environ, PYTHONPATH=str(SRC))
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "rothe.cli.main", *argv],
        cwd=cwd,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        _, err = proc.communicate(timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, 9)  # the run and anything it started
        proc.communicate()
        return None, f"still running after {TIMEOUT:g} s (killed)", time.perf_counter() - t0
    return proc.returncode, err, time.perf_counter() - t0


def _doctored_checkpoints(work: Path) -> list[tuple[str, list[str], int, str]]:
    """An interrupted ris-1d checkpoint, edited three ways (as the fuzzer did)."""
    base = work / "ckpt"
    code, err, _ = _rothe(
        ["run", "ris-1d", "--tol", "1e-3", "--no-plots", "--quiet", "--out", str(base)]
        + (["--keep-checkpoint"] if SRC == ROOT / "src" else []),
        work,
    )
    assert code == 0, err  # an older rothe keeps the checkpoint anyway
    main = base / "checkpoint" / "checkpoint.npz"
    cases = []
    for name in ("no state", "shorter z", "z is a string"):
        d = work / name.replace(" ", "-")
        shutil.copytree(base, d)
        path = d / "checkpoint" / "checkpoint.npz"
        with np.load(path) as f:
            data = {k: f[k] for k in f.files}
        header = json.loads(data.pop("__checkpoint__").tobytes())
        header["status"] = "interrupted"  # resumable (the status is not sealed)
        stepper = header["state"]["stepper"]
        if name == "no state":
            del header["state"]
            line = (
                f"rothe: error: {path.relative_to(work)}: not a readable checkpoint (no "
                "'state' entry)"
            )
        else:
            if name == "shorter z":
                ref = stepper["z"]["__array__"]
                data[ref] = data[ref][:-1]
            else:
                stepper["z"] = "hello"
            line = (
                f"rothe: error: --resume {path.relative_to(work)}: not a readable "
                "checkpoint (its state differs from what rothe wrote: edited or damaged "
                "after it was written)"
            )
        np.savez(path, __checkpoint__=np.frombuffer(json.dumps(header).encode(), np.uint8), **data)
        cases.append((f"resume, checkpoint with {name}", ["resume", d.name, "--quiet"], 2, line))
    assert main.exists()
    return cases


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default=None, help="run the cases whose name contains this")
    parser.add_argument("--skip", default=None, help="skip the cases whose name contains this")
    parser.add_argument("--src", default=None, help="the source tree to run (default ./src)")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per case")
    opts = parser.parse_args()
    global SRC, TIMEOUT
    SRC = Path(opts.src).resolve() if opts.src else SRC
    TIMEOUT = opts.timeout
    mod = _cases_module()
    handled = total = 0
    with tempfile.TemporaryDirectory(prefix="rothe-bad-inputs-") as tmp:
        work = Path(tmp)
        for name, write in mod.FILES.items():
            write(work / name)
        cases = []
        for argv, status, line in mod.CASES:
            argv = [mod.materialize(work, a) for a in argv]
            if argv[0] == "sweep":
                argv += ["--no-plots"] + ([] if "--workers" in argv else ["--workers", "1"])
            else:
                argv += ["--quiet", "--no-plots"]
            if "--out" not in argv:
                argv += ["--out", str(work / "out")]
            cases.append((" ".join(argv)[:90], argv, status, mod.materialize(work, line)))
        cases += _doctored_checkpoints(work)
        for name, argv, status, line in cases:
            if (opts.only and opts.only not in name) or (opts.skip and opts.skip in name):
                continue
            shutil.rmtree(work / "out", ignore_errors=True)
            code, err, seconds = _rothe(argv, work)
            lines = err.strip().splitlines()
            ok = (
                code == status
                and lines == [line]
                and "Traceback" not in err
                and (status != 2 or not (work / "out").exists())
            )
            total += 1
            handled += ok
            print(f"{'ok ' if ok else 'BAD'} {seconds:5.1f} s  exit {code!s:>4}  {name}")
            if not ok:
                print(f"      expected exit {status}: {line}\n      got: {err.strip()[-600:]}")
    print(
        f"{handled} of {total} bad inputs handled (one line, the right exit status, nothing "
        "left behind)"
    )
    return 0 if handled == total else 1


if __name__ == "__main__":
    sys.exit(main())
