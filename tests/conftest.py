"""Helpers and fixtures shared by the test folders: ``run_cli`` (the command line in this process),
gmsh files written by the test itself (no binaries), a signal sent at the k-th step attempt or at
the k-th call of any method (inside a step), and the bit-for-bit comparison of trajectories
(checkpoint/resume tests).

Test modules import the plain helpers with ``from ..conftest import run_cli`` (pytest's importlib
mode makes ``tests`` a package)."""

from __future__ import annotations

import importlib.util
import os
import signal
from pathlib import Path

import meshio
import numpy as np
import pytest
from skfem import MeshTet, MeshTri

from rothe.cli.main import main
from rothe.errors import RunInterrupted
from rothe.io.checkpoint import CheckpointOptions, load_checkpoint
from rothe.io.trajectory import is_timing_array


def run_cli(capsys, *argv):
    """``rothe *argv`` in this process: (exit status, stdout, stderr)."""
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def load_gmsh_text():
    path = Path(__file__).parent / "fem" / "gmsh_text.py"
    spec = importlib.util.spec_from_file_location("rothe_tests_gmsh_text", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def write_gmsh_body(
    path, dim=2, nx=8, ny=4, length=2.0, height=1.0, split=None, x0=0.0, split_axis=0
):
    """A box [x0, x0 + length] x [0, height]^(dim-1) of nx x ny (x ny) cells written by meshio
    as a gmsh 2.2 file with physical groups: the facets ``inlet`` (x = x0), ``outlet`` (x = x0 +
    length), ``wall`` (the rest); the cells ``core`` (centroid x < split; with ``split_axis``
    1: centroid y < split, a layer along the length) and ``shell`` (the rest; none without
    ``split``). Returns the path."""
    xs, ys = np.linspace(x0, x0 + length, nx + 1), np.linspace(0, height, ny + 1)
    m = MeshTri.init_tensor(xs, ys) if dim == 2 else MeshTet.init_tensor(xs, ys, ys)
    facets = m.facets[:, m.boundary_facets()]
    mid = m.p[:, facets].mean(axis=1)
    tags = np.where(np.isclose(mid[0], x0), 1, np.where(np.isclose(mid[0], x0 + length), 2, 3))
    centroid = m.p[split_axis, m.t].mean(axis=0)
    volume = np.where(centroid < (np.inf if split is None else split), 4, 5)
    points = np.vstack([m.p, np.zeros((3 - dim, m.p.shape[1]))]).T
    kinds = ("line", "triangle") if dim == 2 else ("triangle", "tetra")
    groups = {"inlet": 1, "outlet": 2, "wall": 3, "core": 4, "shell": 5}
    meshio.Mesh(
        points,
        [(kinds[0], facets.T), (kinds[1], m.t.T)],
        cell_data={"gmsh:physical": [tags, volume], "gmsh:geometrical": [tags, volume]},
        field_data={k: np.array([v, dim - 1 if v <= 3 else dim]) for k, v in groups.items()},
    ).write(path, file_format="gmsh22", binary=False)
    return path


@pytest.fixture(scope="session")
def gmsh_text():
    return load_gmsh_text()


@pytest.fixture
def signal_at_attempt(monkeypatch):
    """``signal_at_attempt(StepperClass, k, sig)``: the k-th call of ``step`` (counted from now)
    sends ``sig`` to this process before stepping; returns the call counter (a list)."""

    def install(cls, k: int, sig=signal.SIGINT):
        original = cls.__dict__.get("_rothe_original_step", cls.step)
        monkeypatch.setattr(cls, "_rothe_original_step", original, raising=False)
        calls = [0]

        def step(self, state, tau, s_end=None):
            calls[0] += 1
            if calls[0] == k:
                os.kill(os.getpid(), sig)
            return original(self, state, tau, s_end)

        monkeypatch.setattr(cls, "step", step)
        return calls

    return install


@pytest.fixture
def signal_at_call(monkeypatch):
    """``signal_at_call(cls, name, k, sig)``: the k-th call of the method ``cls.name`` (counted
    from now, whatever its arguments) sends ``sig`` to this process before it runs; returns the
    call counter (a list). A signal in the middle of a step: e.g. the k-th iteration of the RIS
    inner solver (``BallStepSolver.step``) or the k-th Newton solve of an ELD step."""

    def install(cls, name: str, k: int, sig=signal.SIGINT):
        key = f"_rothe_original_{name}"
        original = cls.__dict__.get(key, getattr(cls, name))
        monkeypatch.setattr(cls, key, original, raising=False)
        calls = [0]

        def method(self, *args, **kwargs):
            calls[0] += 1
            if calls[0] == k:
                os.kill(os.getpid(), sig)
            return original(self, *args, **kwargs)

        monkeypatch.setattr(cls, name, method)
        return calls

    return install


def assert_same_trajectory(a, b, skip=("meta",)):
    """Equal arrays (np.array_equal) for every series and statistic but the wall times."""
    if hasattr(a, "files"):  # two np.load results
        keys_a = {k for k in a.files if k not in skip and not is_timing_array(k)}
        keys_b = {k for k in b.files if k not in skip and not is_timing_array(k)}
        assert keys_a == keys_b
        bad = [k for k in sorted(keys_a) if not np.array_equal(a[k], b[k])]
    else:
        assert set(a.keys()) == set(b.keys())
        bad = [k for k in a.keys() if not np.array_equal(a[k], b[k])]
        assert a.stats.untimed() == b.stats.untimed()
    assert not bad, f"differ: {bad}"


def interrupted_thrice(
    make_run,
    stepper_cls,
    signal_at_attempt,
    ckpt,
    sig=signal.SIGINT,
    attempts=(5, 40, 90),
    runs=None,
):
    """Run, interrupted at the given step attempts (counted per session); each time resumed
    from the checkpoint it left; then run to the end. Checks what every stop left: the signal,
    the checkpoint, the partial result (every accepted step recorded, t = 0 included) and, for
    a sequence of runs, ``runs``: the index of the run under way at each stop."""
    resume = None
    for i, k in enumerate(attempts):
        signal_at_attempt(stepper_cls, k, sig)
        with pytest.raises(RunInterrupted) as info:
            make_run(checkpoint=CheckpointOptions(ckpt, every_seconds=0.01), resume=resume)
        exc = info.value
        assert exc.signum == sig and exc.exit_status == 128 + sig
        assert exc.checkpoint == ckpt and exc.trajectory is not None
        assert exc.where["accepted_steps"] == exc.trajectory.stats.accepted_steps
        assert len(exc.trajectory["t"]) == exc.trajectory.stats.accepted_steps + 1
        assert load_checkpoint(ckpt).status == "interrupted"
        if runs is not None:
            assert load_checkpoint(ckpt).state["run"]["index"] == runs[i]
        resume = ckpt
    signal_at_attempt(stepper_cls, 10**9)  # no more signals
    return make_run(resume=ckpt)
