"""Issue 21: bad inputs and faults that were mishandled, as one harness of command lines.

Every case is ``(files, argv, exit status, the one line on stderr)``: ``{x}`` in argv or in the
line is the path of file ``x`` that the case's set-up writes into the test's directory. A user
error is one line ``rothe: error: <option>: got <value>, ...``, exit status 2, and nothing is run
(the ``--out`` folder is not created). ``benchmarks/bad_inputs.py`` runs the same list as
subprocesses and counts the cases handled.
"""

from __future__ import annotations

import errno
import os
import pathlib

import meshio
import numpy as np
import pytest

from rothe.cli.main import main
from rothe.fem.mesh import unit_square


def _square(scale=1.0, bad=None):
    def write(path):
        ref = unit_square(3)
        pts = np.c_[ref.p.T, np.zeros(ref.p.shape[1])] * scale
        if bad is not None:
            pts[4, 0] = bad
        meshio.write(path, meshio.Mesh(pts, [("triangle", ref.t.T)]))

    return write


#: file name -> writer(path)
FILES = {
    "good.vtu": _square(),
    "nan.vtu": _square(bad=np.nan),
    "inf.vtu": _square(bad=np.inf),
    "huge.vtu": _square(scale=1e200),
}

CORES = len(os.sched_getaffinity(0))
TOLS = ",".join(f"{x:.6g}" for x in np.geomspace(1e-2, 1e-5, 60))
TAUS = ",".join(f"{x:.6g}" for x in np.geomspace(0.5, 0.01, 90))

#: (argv, exit status, stderr line); a run gets --quiet --no-plots, and --out {out} unless the
#: case gives one; the files are in the current directory (relative names work)
CASES = [
    (
        ["run", "ris-2d", "--mesh", "{nan.vtu}"],
        2,
        "rothe: error: --mesh: got '{nan.vtu}', has a non-finite node coordinate (nan), "
        "coordinates must be finite",
    ),
    (
        ["run", "ris-2d", "--mesh", "{inf.vtu}"],
        2,
        "rothe: error: --mesh: got '{inf.vtu}', has a non-finite node coordinate (inf), "
        "coordinates must be finite",
    ),
    (
        ["run", "ris-2d", "--mesh", "{huge.vtu}"],
        2,
        "rothe: error: --mesh: got '{huge.vtu}', has node coordinates up to 1e+200 in magnitude, "
        "must be at most 1e+100 (squared lengths and volumes would overflow; rescale the mesh)",
    ),
    *[
        (
            ["run", name, "--out", out],
            2,
            f"rothe: error: --out: got {out!r}, must name a directory (omit --out for "
            f"rothe-out/{name})",
        )
        for name in (
            "ris-1d",
            "ris-2d",
            "ris-3d",
            "ris-front",
            "ris-front-unique",
            "eld-mms",
            "eld-beam",
        )
        for out in ("", " ")
    ],
    (
        ["compare", "ris-1d", "--out", ""],
        2,
        "rothe: error: --out: got '', must name a directory (omit --out for "
        "rothe-out/compare-ris-1d)",
    ),
    # sweeps: every run's input files before the first run; the worker count and the number of
    # runs before any cluster starts
    (
        ["sweep", "run", "ris-2d", "--param", "mesh=good.vtu,nonexistent.msh", "--out", "{out}"],
        2,
        "rothe: error: sweep run mesh=nonexistent.msh: --mesh: got 'nonexistent.msh', no such file",
    ),
    (
        ["sweep", "run", "ris-2d", "--param", "mesh=good.vtu,nan.vtu", "--out", "{out}"],
        2,
        "rothe: error: sweep run mesh=nan.vtu: --mesh: got 'nan.vtu', has a non-finite node "
        "coordinate (nan), coordinates must be finite",
    ),
    (
        ["sweep", "run", "ris-2d", "--param", "tol=1e-2,1e-3", "--mesh", ".", "--out", "{out}"],
        2,
        "rothe: error: sweep run tol=1e-2: --mesh: got '.', is a directory, must be a file",
    ),
    (
        [
            "sweep",
            "run",
            "ris-1d",
            "--param",
            "tol=1e-3,1e-4",
            "--workers",
            "1000",
            "--out",
            "{out}",
        ],
        2,
        f"rothe: error: --workers: got 1000, must be at most {CORES} (the cores this process may "
        "use; a worker runs one single-threaded run, more workers than cores only share them; "
        "--scheduler runs on a larger cluster)",
    ),
    (
        [
            "sweep",
            "run",
            "ris-1d",
            "--param",
            f"tol={TOLS}",
            "--param",
            f"tau={TAUS}",
            "--out",
            "{out}",
        ],
        2,
        "rothe: error: --param: 5400 runs (60 tol x 90 tau), more than 1000: pass --yes to start "
        "them all",
    ),
    (
        ["sweep", "run", "ris-1d", "--param", "tol=1e-3", "--out", ""],
        2,
        "rothe: error: --out: got '', must name a directory (omit --out for "
        "rothe-out/sweep-ris-1d)",
    ),
    (
        ["sweep", "run", "ris-1d", "--param", "tol=1e-3", "--out", "/proc/sweep"],
        2,
        "rothe: error: --out: got '/proc/sweep', cannot create or write files in this directory "
        "([Errno 2] No such file or directory)",
    ),
    # refused by the ELD run after the session took OUT/checkpoint/.lock: nothing is left
    (
        ["run", "eld-mms", "--tau", "0.3"],
        2,
        "rothe: error: --tau: got 0.3, must divide T = 1 into equal steps (T/tau = 3.33333)",
    ),
    # an option the run does not read: the original form (2.7) has no lifting
    *[
        (
            ["run", "eld-mms", "--lifting", lifting, "--form", "original"],
            2,
            f"rothe: error: --lifting: got {lifting!r}, is used by --form regularized only (the "
            "original form (2.7) has no lifting)",
        )
        for lifting in ("harmonic", "nodal")
    ],
    # compare: no controls left to compare with uniform
    *[
        (
            ["compare", "ris-2d", "--controls", controls],
            2,
            f"rothe: error: --controls: got {controls!r}, must name at least one of adaptive, "
            "order2, regime (uniform always runs)",
        )
        for controls in ("", " , ")
    ],
    # a study checks what every run would refuse before its cluster starts (each run failed on
    # its own after a Dask cluster had started, exit 1 without an error line)
    (
        ["study", "eld-convergence", "--tau0", "0.3"],
        2,
        "rothe: error: --tau0: got 0.3, must divide T = 1 into equal steps (T/tau = 3.33333)",
    ),
    (
        ["study", "eld-convergence", "--tau0", "1e300"],
        2,
        "rothe: error: --tau0: got 1e+300, must be < rho/d0 = 2 (Lemma 3.2: unique solvability "
        "of the Euler steps)",
    ),
    (
        ["study", "eld-convergence", "--degree", "5"],
        2,
        "rothe: error: --degree: got 5, must be 1 or 2",
    ),
    (
        ["study", "eld-convergence", "--rho", "-1"],
        2,
        "rothe: error: --rho: got -1, must be > 0",
    ),
    (
        ["study", "eld-convergence", "--scheme", "bdf2", "--data", "means"],
        2,
        "rothe: error: --data: got 'means', with scheme bdf2 must be points or differenced (step "
        "means are first-order data: they sit O(tau) away from t_j)",
    ),
]


def materialize(tmp_path, text: str) -> str:
    for name in FILES:
        text = text.replace("{" + name + "}", str(tmp_path / name))
    return text.replace("{out}", str(tmp_path / "out"))


def case_id(case) -> str:
    argv = case[0]
    return " ".join(argv)[:60]


def prepare(tmp_path, monkeypatch, argv) -> list[str]:
    """Write the files into tmp_path (the current directory) and complete the command line."""
    monkeypatch.chdir(tmp_path)  # the default rothe-out/<name> would appear here
    for name, write in FILES.items():
        write(tmp_path / name)
    argv = [materialize(tmp_path, a) for a in argv]
    if argv[0] == "sweep":
        argv += ["--no-plots", "--workers", "1"] if "--workers" not in argv else ["--no-plots"]
    else:
        argv += ["--quiet", "--no-plots"]
    if "--out" not in argv:
        argv += ["--out", str(tmp_path / "out")]
    return argv


@pytest.mark.parametrize("argv, status, line", CASES, ids=[case_id(c) for c in CASES])
def test_bad_input_is_one_line(tmp_path, capsys, monkeypatch, argv, status, line):
    argv = prepare(tmp_path, monkeypatch, argv)
    code = main(argv)
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.strip().splitlines() == [materialize(tmp_path, line)]
    assert code == status
    if status == 2:
        assert not (tmp_path / "out").exists() and not (tmp_path / "rothe-out").exists()


def test_sweep_out_on_a_read_only_file_system_is_one_line(tmp_path, capsys, monkeypatch):
    """An OSError (EROFS) from mkdir was a traceback, after the cluster had started."""
    argv = prepare(
        tmp_path, monkeypatch, ["sweep", "run", "ris-1d", "--param", "tol=1e-3", "--out", "{out}"]
    )
    real_mkdir = pathlib.Path.mkdir

    def mkdir(self, *args, **kwargs):
        if self.name == "out":
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))
        return real_mkdir(self, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "mkdir", mkdir)
    assert main(argv) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"rothe: error: --out: got '{tmp_path / 'out'}', cannot create or write files in this "
        "directory ([Errno 30] Read-only file system)"
    ]
