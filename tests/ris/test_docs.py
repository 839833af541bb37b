"""The Python examples of README.md, docs/ris.md and docs/ris_fem.md run as printed (on smaller
grids where the printed one would cost tens of seconds)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def _blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(encoding="utf-8"), re.S)


def _run(code: str, path: Path, tmp_path, monkeypatch, shrink=()) -> dict:
    for big, small in shrink:
        assert big in code, big
        code = code.replace(big, small)
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(code, str(path), "exec"), namespace)  # noqa: S102 - our own documentation
    return namespace


@pytest.mark.skipif(not (ROOT / "docs").is_dir(), reason="docs/ is not in this installation")
def test_the_readme_examples_run(tmp_path, monkeypatch, capsys):
    path = ROOT / "README.md"
    own, fem = [b for b in _blocks(path) if "run_ris" in b]
    ns = _run(own, path, tmp_path, monkeypatch)
    traj = ns["result"].trajectory
    assert abs(traj["t"][-1] - 1.0) <= 1e-10 and (tmp_path / "my-run.npz").is_file()
    assert str(ns["result"].statistics.accepted_steps) in capsys.readouterr().out
    ns = _run(fem, path, tmp_path, monkeypatch, shrink=[("unit_square(32)", "unit_square(6)")])
    assert abs(ns["traj"]["t"][-1] - 1.0) <= 1e-10 and ns["traj"].meta["control"] == "order2"
    # issue 21: the example says what it computed (it ran 87 s and printed nothing)
    steps = ns["result"].statistics.accepted_steps
    assert f"{steps} steps to t = 1: z in [" in capsys.readouterr().out


@pytest.mark.skipif(not (ROOT / "docs").is_dir(), reason="docs/ is not in this installation")
def test_the_examples_of_docs_ris_md_run(tmp_path, monkeypatch):
    path = ROOT / "docs" / "ris.md"
    ns = _run(_blocks(path)[0], path, tmp_path, monkeypatch)
    assert ns["result"].trajectory.meta["control"] == "adaptive"
    assert [r.control.tol for r in ns["runs"]] == [1e-2, 1e-3]


@pytest.mark.skipif(not (ROOT / "docs").is_dir(), reason="docs/ is not in this installation")
def test_the_examples_of_docs_ris_fem_md_run(tmp_path, monkeypatch):
    path = ROOT / "docs" / "ris_fem.md"
    quick, adapted = [b for b in _blocks(path) if "run_ris" in b]
    ns = _run(
        quick, path, tmp_path, monkeypatch, shrink=[("example_7_2(n=40)", "example_7_2(n=6)")]
    )
    assert ns["z_nodes"].shape == (49,) and ns["mine"].n == 31**2
    ns = _run(
        adapted, path, tmp_path, monkeypatch, shrink=[("example_front(8)", "example_front(4)")]
    )
    result = ns["result"]
    assert len(result.meshes.ids) > 1 and np.max(result.trajectory["n_dofs"]) <= 400
    assert result.statistics.seconds["refine"] > 0
