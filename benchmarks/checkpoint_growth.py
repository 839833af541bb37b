"""What checkpointing an adaptive run writes (issue 21: checkpoint.npz stored every mesh of the
series and was rewritten every interval, O(K^2) bytes in total).

Runs one ``rothe run`` command (default: ris-front with space adaptivity, a checkpoint every
0.3 s so that a short run writes about a thousand of them) and reports the bytes the process
wrote (``wchar`` of /proc/<pid>/io: everything it passed to write(), results included), the
largest ``checkpoint.npz`` seen while it ran, and the checkpoint directory at the end::

    PYTHONPATH=src python benchmarks/checkpoint_growth.py [--src DIR] [-- rothe run options]

``--src`` runs another source tree (e.g. an older commit's ``src``) for the comparison. Linux only
(/proc).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = [
    "run",
    "ris-front",
    "--adapt-space",
    "--n",
    "8",
    "--max-dofs",
    "400",
    "--tol",
    "1e-3",
    "--checkpoint-every",
    "0.3",
]


def measure(src: Path, argv: list[str], out: Path, keep: bool) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src))
    cmd = [
        sys.executable,
        "-m",
        "rothe.cli.main",
        *argv,
        "--out",
        str(out),
        "--quiet",
        "--no-plots",
    ] + (["--keep-checkpoint"] if keep else [])
    proc = subprocess.Popen(cmd, env=env)
    main = out / "checkpoint" / "checkpoint.npz"
    wchar = peak = 0
    while proc.poll() is None:
        try:
            with open(f"/proc/{proc.pid}/io") as f:
                for line in f:
                    if line.startswith("wchar"):
                        wchar = int(line.split()[1])
        except OSError:
            pass
        try:
            peak = max(peak, main.stat().st_size)
        except OSError:
            pass
        time.sleep(0.05)
    summary = json.loads((out / "summary.json").read_text())
    ckpt = out / "checkpoint"
    return {
        "exit": proc.returncode,
        "accepted_steps": summary.get("accepted_steps"),
        "written_MB": wchar / 1e6,
        "peak_checkpoint_npz_MB": peak / 1e6,
        "checkpoint_dir_MB": sum(p.stat().st_size for p in ckpt.iterdir()) / 1e6,
        "files_in_checkpoint_dir": len(list(ckpt.iterdir())),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--src", default=str(ROOT / "src"), help="source tree to run")
    parser.add_argument("rest", nargs=argparse.REMAINDER, help="-- then the rothe command")
    opts = parser.parse_args()
    argv = [a for a in opts.rest if a != "--"] or DEFAULT
    src = Path(opts.src).resolve()
    keep = src == (ROOT / "src").resolve()  # an older rothe keeps the checkpoint anyway
    with tempfile.TemporaryDirectory(prefix="rothe-ckpt-growth-") as tmp:
        result = measure(src, argv, Path(tmp) / "run", keep)
    print(json.dumps({"src": str(src), "command": " ".join(argv), **result}, indent=1))
    return 0 if result["exit"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
