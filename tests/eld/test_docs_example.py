"""The own-problem example of docs/eld.md runs as printed."""

import re
from pathlib import Path

import numpy as np

DOC = Path(__file__).resolve().parents[2] / "docs" / "eld.md"


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
