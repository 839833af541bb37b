"""Issue 21: bad inputs and faults that were mishandled, as one harness of command lines.

Every case is ``(files, argv, exit status, the one line on stderr)``: ``{x}`` in argv or in the
line is the path of file ``x`` that the case's set-up writes into the test's directory. A user
error is one line ``rothe: error: <option>: got <value>, ...``, exit status 2, and nothing is run
(the ``--out`` folder is not created). ``benchmarks/bad_inputs.py`` runs the same list as
subprocesses and counts the cases handled.
"""

from __future__ import annotations

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

#: (argv, exit status, stderr line); the command line gets --out {out} --quiet --no-plots
CASES = [
    (["run", "ris-2d", "--mesh", "{nan.vtu}"], 2,
     "rothe: error: --mesh: got '{nan.vtu}', has a non-finite node coordinate (nan), "
     "coordinates must be finite"),
    (["run", "ris-2d", "--mesh", "{inf.vtu}"], 2,
     "rothe: error: --mesh: got '{inf.vtu}', has a non-finite node coordinate (inf), "
     "coordinates must be finite"),
    (["run", "ris-2d", "--mesh", "{huge.vtu}"], 2,
     "rothe: error: --mesh: got '{huge.vtu}', has node coordinates up to 1e+200 in magnitude, "
     "must be at most 1e+100 (squared lengths and volumes would overflow; rescale the mesh)"),
    *[(["run", name, "--out", out], 2,
       f"rothe: error: --out: got {out!r}, must name a directory (omit --out for "
       f"rothe-out/{name})")
      for name in ("ris-1d", "ris-2d", "ris-3d", "ris-front", "eld-mms", "eld-beam")
      for out in ("", " ")],
    (["compare", "ris-1d", "--out", ""], 2,
     "rothe: error: --out: got '', must name a directory (omit --out for "
     "rothe-out/compare-ris-1d)"),
    # refused by the ELD run after the session took OUT/checkpoint/.lock: nothing is left
    (["run", "eld-mms", "--tau", "0.3"], 2,
     "rothe: error: --tau: got 0.3, must divide T = 1 into equal steps (T/tau = 3.33333)"),
]


def materialize(tmp_path, text: str) -> str:
    for name in FILES:
        text = text.replace("{" + name + "}", str(tmp_path / name))
    return text.replace("{out}", str(tmp_path / "out"))


def case_id(case) -> str:
    argv = case[0]
    return " ".join(argv)[:60]


@pytest.mark.parametrize("argv, status, line", CASES, ids=[case_id(c) for c in CASES])
def test_bad_input_is_one_line(tmp_path, capsys, monkeypatch, argv, status, line):
    monkeypatch.chdir(tmp_path)  # the default rothe-out/<name> would appear here
    for name, write in FILES.items():
        if any("{" + name + "}" in a for a in argv):
            write(tmp_path / name)
    argv = [materialize(tmp_path, a) for a in argv]
    if "sweep" not in argv[:1]:
        argv += ["--quiet", "--no-plots"]
    if not any(a.startswith("--out") for a in argv):
        argv += ["--out", str(tmp_path / "out")]
    code = main(argv)
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.strip().splitlines() == [materialize(tmp_path, line)]
    assert code == status
    if status == 2:
        assert not (tmp_path / "out").exists() and not (tmp_path / "rothe-out").exists()
