"""The examples of docs/eld.md run as printed."""

import re
from pathlib import Path

import numpy as np

DOC = Path(__file__).resolve().parents[2] / "docs" / "eld.md"


def _blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", DOC.read_text(), re.S)


def test_the_own_problem_example_of_the_docs_runs(tmp_path, capsys):
    text = DOC.read_text()
    section = text[text.index("## Your own problem") :]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    assert "rothe-out/my-strip" in code
    code = code.replace("rothe-out/my-strip", str(tmp_path / "my-strip"))
    # the figures are tested elsewhere; here they would cost more than the run
    assert 'name="strip")' in code
    code = code.replace('name="strip")', 'name="strip", figures=False)')
    namespace: dict = {}
    exec(compile(code, str(DOC), "exec"), namespace)  # noqa: S102 - our own documentation
    traj, problem = namespace["traj"], namespace["problem"]
    assert traj["t"][-1] == 1.0 and traj.stats.accepted_steps > 10
    scale = np.abs(traj["energy"]).max() + np.abs(traj["work"]).max()
    assert np.abs(traj["balance_residual"]).max() <= 1e-12 * scale
    for name in ("trajectory.npz", "strip.xdmf", "strip_multiplier.xdmf"):
        assert (tmp_path / "my-strip" / name).is_file(), name
    assert problem.load_quadrature == 4
    assert "strip.xdmf" in capsys.readouterr().out


def test_the_quick_start_and_the_space_adaptivity_examples_run(capsys):
    blocks = [b for b in _blocks() if "my-strip" not in b]
    assert len(blocks) == 2
    quick, adaptive = ({}, {})
    exec(compile(blocks[0], str(DOC), "exec"), quick)  # noqa: S102 - our own documentation
    assert "'error_lam_l2'" in capsys.readouterr().out
    errors = quick["mms_errors"](quick["exact"], quick["result2"])
    assert errors["error_u_l2"] < 1e-2 and quick["result2"].statistics.accepted_steps > 10
    assert quick["result"].trajectory.stats.accepted_steps == 100
    exec(compile(blocks[1], str(DOC), "exec"), adaptive)  # noqa: S102 - our own documentation
    result, meshes = adaptive["result"], adaptive["meshes"]
    assert meshes.adaptations and len(meshes.series) > 1
    assert meshes.kept["u"][-1].size == result.problem.space.ndofs
    assert result.state.mesh_id == result.trajectory["mesh_id"][-1]
