"""What a run did, in numbers (rothe.ris.summary): the summary of a run, the work ratios of a
comparison against the uniform scheme, the equidistribution bound, and which branch a run took
(viscous jumps against single catch-up steps)."""

from __future__ import annotations

import numpy as np
import pytest

from rothe import run_ris
from rothe.io.trajectory import Trajectory
from rothe.ris.examples import example_7_1, example_7_2
from rothe.ris.summary import (
    COMPARE_KEYS,
    catch_up_steps,
    compare_rows,
    describe_branch,
    equidistribution_bound,
    finest_uniform_bound,
    format_jump_times,
    ris_summary,
    uniform_work_at_error,
    viscous_jumps,
)
from rothe.stepping.controllers import Adaptive


def test_ris_summary_of_a_run():
    traj = run_ris(example_7_1(), Adaptive(1e-3, tau=0.1)).trajectory
    s = ris_summary(traj, "ris-1d", {"extra": 1})
    res = traj["I1"] + traj["I2"]
    assert s["example"] == "ris-1d" and s["control"] == "adaptive" and s["tol"] == 1e-3
    assert s["accepted_steps"] == len(traj) and s["inner_solves"] == traj.stats.inner_solves
    assert s["max_residual"] == float(res.max()) and s["sum_residual"] == float(res.sum())
    assert s["min_I2"] == float(traj["I2"].min()) and s["t_final"] == traj["t"][-1]
    assert s["landing"] == traj.meta["landing"] and s["status"] == "completed"
    assert s["extra"] == 1
    empty = Trajectory(meta={"control": "uniform"})  # a run that failed at its first step
    empty.append(s=0.0, t=0.0, energy=1.0)
    e = ris_summary(empty, "x")
    assert e["accepted_steps"] == 0 and e["max_residual"] == 0.0 and e["max_kkt_residual"] == 0.0


def test_equidistribution_bound_over_pair_means():
    """Equal residuals: the bound is 1 (no sequence beats equal steps); a residual that
    alternates between two levels at a fixed density (the period-2 oscillation) is averaged
    over pairs, so it too gives 1; a density that varies gives less."""
    assert equidistribution_bound(np.full(10, 2e-3)) == pytest.approx(1.0)
    assert equidistribution_bound(np.tile([1e-3, 3e-3], 20)) == pytest.approx(1.0)
    I = np.r_[np.zeros(10), np.full(10, 1e-3)]
    J = 0.5 * (I[1:] + I[:-1])
    assert equidistribution_bound(I) == pytest.approx(np.sum(np.sqrt(J)) ** 2 / (19 * J.sum()))
    assert equidistribution_bound(I) < 0.6
    assert equidistribution_bound([1e-3]) is None and equidistribution_bound(np.zeros(5)) is None


def test_finest_uniform_bound_and_the_fit_of_uniform_work():
    rows = [
        {
            "control": "uniform",
            "status": "completed",
            "tau0": 0.01,
            "equidistribution_bound": 0.6,
            "error_linf": 1e-2,
            "inner_solves": 100,
        },
        {
            "control": "uniform",
            "status": "completed",
            "tau0": 0.001,
            "equidistribution_bound": 0.5,
            "error_linf": 1e-3,
            "inner_solves": 1000,
        },
        {"control": "regime", "status": "completed", "tau0": 0.1},
    ]
    assert finest_uniform_bound(rows) == (0.001, 0.5)
    assert finest_uniform_bound(rows[2:]) is None
    fit = uniform_work_at_error(rows)
    assert fit(1e-2) == pytest.approx(100) and fit(3e-3) == pytest.approx(1000 / 3)
    assert uniform_work_at_error(rows[:1]) is None


def test_compare_rows_null_outside_the_uniform_range():
    def row(control, G, acc, tau0=0.1, tol=1e-4):
        return {
            "control": control,
            "tol": tol,
            "tau0": tau0,
            "accepted_steps": acc,
            "rejected_steps": 0,
            "inner_solves": acc,
            "newton_iterations": 2 * acc,
            "wall_time_s": 0.01 * acc,
            "max_residual": G / acc,
            "sum_residual": G,
            "status": "completed",
        }

    rows = [
        row("regime", 0.5, 10),
        row("regime", 0.05, 50),
        row("regime", 2.0, 5),
        row("uniform", 1.0, 100, tau0=0.01, tol=None),
        row("uniform", 0.1, 1000, tau0=0.001, tol=None),
    ]
    out = compare_rows(rows)
    # G = 0.5 between 1.0 (100 steps) and 0.1 (1000): log-log gives 100 * 2 = 200 steps
    assert out[0]["ratio_steps"] == pytest.approx(10 / 200)
    assert out[0]["ratio_seconds"] == pytest.approx(0.1 / 2.0)
    assert out[1]["ratio_steps"] is None and out[2]["ratio_solves"] is None  # outside the range
    assert out[3]["ratio_steps"] is None and out[3]["tol"] is None and out[3]["tau"] == 0.01
    # a run that produced nothing (a lost task): its status only, nulls in compare.json
    lost = {"control": "regime", "tol": 1e-5, "tau0": 0.1, "status": "lost: worker died"}
    out = compare_rows(rows + [lost])
    assert list(out[-1]) == list(out[0]) and out[-1]["solves"] is None
    assert out[-1]["ratio_solves"] is None and out[0]["ratio_steps"] == pytest.approx(10 / 200)
    assert tuple(out[0]) == COMPARE_KEYS


def _traj(taus, dts):
    tr = Trajectory()
    tr.append(s=0.0, t=0.0)
    s = t = 0.0
    for tau, dt in zip(taus, dts, strict=True):
        s, t = s + tau, t + dt
        tr.append(s=s, t=t, tau=tau)
    return tr


def test_viscous_jumps_catch_up_and_round_off_steps():
    # stick (t' = 1), a long jump (t' = 0) with a round-off step inside, slip, then a short
    # step with t' = 0 after a longer one: a catch-up, not a jump
    taus = [0.1, 0.1, 0.2, 1e-17, 0.2, 0.1, 0.05, 0.02, 0.05]
    dts = [0.1, 0.1, 0.0, 0.0, 0.0, 0.06, 0.03, 0.0, 0.03]
    tr = _traj(taus, dts)
    jumps = viscous_jumps(tr)
    assert len(jumps) == 1
    assert jumps[0]["t"] == pytest.approx(0.2) and jumps[0]["steps"] == 2
    assert jumps[0]["s_end"] - jumps[0]["s_start"] == pytest.approx(0.4)
    assert catch_up_steps(tr) == 1
    # a relaxation at the start (z0 not stationary) counts when it spans more than one step
    assert viscous_jumps(_traj([0.1, 0.1, 0.1], [0.0, 0.0, 0.1]))[0]["steps"] == 2
    assert viscous_jumps(_traj([0.1, 0.1], [0.0, 0.1])) == []
    assert viscous_jumps(_traj([], [])) == [] and catch_up_steps(_traj([], [])) == 0


def test_single_steps_with_dt_zero_are_not_jumps():
    """The disk mesh of issue 10 reported 318 jumps where t^(s) has one plateau: in slip the
    time increments carry a period-2 oscillation at a fixed tau (dt = tau, 0, tau, 0, ...) and
    single steps after a halving of tau spend their length catching up. None is a jump."""
    tau = 0.0001234567  # s_k - s_{k-1} then differs from tau by round-off, either way
    taus = [0.1, 0.1, 0.1, 0.1] + [2 * tau] * 3 + [tau] * 400
    dts = [0.1, 0.0, 0.0, 0.0] + [tau] * 3 + [0.9 * tau, 0.0] * 200
    tr = _traj(taus, dts)
    jumps = viscous_jumps(tr)
    assert [j["steps"] for j in jumps] == [3]  # the plateau after the first step only
    assert catch_up_steps(tr) == 200
    # two steps with t' = 0 that together are no longer than the step before: a catch-up
    assert viscous_jumps(_traj([0.2, 0.05, 0.05, 0.1], [0.2, 0.0, 0.0, 0.1])) == []


def test_format_jump_times_lists_the_first_few():
    jumps = [{"t": 0.1 * k} for k in range(1, 8)]
    assert format_jump_times([]) == "none"
    assert format_jump_times(jumps[:2]) == "0.1, 0.2"
    assert format_jump_times(jumps) == "0.1, 0.2, 0.3, 0.4, 0.5 (+2 more)"
    assert format_jump_times(jumps, shown=2, sep=",") == "0.1,0.2 (+5 more)"


def test_describe_branch_of_example_7_2():
    p = example_7_2(6)
    traj = run_ris(p, Adaptive(1e-3)).trajectory
    b = describe_branch(p, traj)
    assert b["n_viscous_jumps"] == len(b["viscous_jumps"]) == 1
    assert 0.16 < b["viscous_jumps"][0]["t"] < 0.19
    assert b["z_max"] == 0.0 and b["z_min"] < -1.3 and b["z_mean"] < 0
    assert b["energy_final"] == traj["energy"][-1]
    assert b["branch"].startswith("z <= 0, z in [")
    assert "1 viscous jump(s) at t = 0.1" in b["branch"]
    assert b["catch_up_steps"] == catch_up_steps(traj)
