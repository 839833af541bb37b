"""What a RIS run did, in numbers: its summary, the work ratios of a comparison, its branch.

* :func:`ris_summary`: the fields of summary.json of one run (steps, solves, residuals, landing);
* the work of a run against the uniform scheme's at the same global residual
  G = sum_k (I1^k + I2^k) (:func:`compare_rows`, :func:`uniform_work_interpolant`) and the
  equidistribution bound no step sequence can beat (:func:`equidistribution_bound`);
* which stationary branch a run followed (:func:`describe_branch`): the viscous jumps of the
  BV solution (maximal intervals of s on which t^ stands still, :func:`viscous_jumps`) as
  distinct from single catch-up steps (:func:`catch_up_steps`).

Everything here reads a :class:`~rothe.io.trajectory.Trajectory` (and summary rows); nothing
runs a step.
"""

from __future__ import annotations

import math

import numpy as np

from ..io.trajectory import Trajectory
from .fem_problem import FERISProblem


def ris_summary(traj: Trajectory, example: str, extra: dict | None = None) -> dict:
    """The summary.json fields of one RIS trajectory (README, "Where results go").

    Parameters
    ----------
    traj : Trajectory
        The run's trajectory (``RISResult.trajectory``, or the one a failed run carries).
    example : str
        The name written as ``example``.
    extra : dict, optional
        Fields added last (they override the computed ones).

    Returns
    -------
    dict
        steps, solves, Newton iterations, t and s at the end, ``landing``,
        max_k(I1 + I2) (``max_residual``), sum_k(I1 + I2) (``sum_residual``), min I2,
        the largest KKT residual and multiplier, the final energy, wall time and status.
    """
    st = traj.stats

    def steps(key):  # a run that failed at its first step has no step series at all
        return traj[key] if key in traj else np.zeros(0)

    I1, I2 = steps("I1"), steps("I2")
    res = I1 + I2 if len(I1) else np.zeros(0)
    meta = traj.meta
    summary = {
        "example": example,
        "control": meta.get("control"),
        "tol": meta.get("tol"),
        "tau0": meta.get("tau0"),
        "accepted_steps": st.accepted_steps,
        "rejected_steps": st.rejected_steps,
        "inner_solves": st.inner_solves,
        "newton_iterations": st.newton_iterations,
        "fb_steps": st.fb_steps,
        "linear_factorizations": st.linear_factorizations,
        "landing_retries": st.landing_retries,
        "t_final": float(traj["t"][-1]),
        # how the run ended: on T within 1e-10 max(1, T), or at S (rothe.ris.run)
        "landing": meta.get("landing"),
        "s_final": float(traj["s"][-1]),
        "max_residual": float(res.max()) if res.size else 0.0,
        "sum_residual": float(res.sum()) if res.size else 0.0,
        "min_I2": float(I2.min()) if I2.size else 0.0,
        "max_kkt_residual": float(steps("kkt").max()) if len(traj) else 0.0,
        "max_multiplier": float(steps("lam").max()) if len(traj) else 0.0,
        "energy_final": float(traj["energy"][-1]),
        "wall_time_s": st.wall_time_s,
        "status": "completed",
    }
    summary.update(extra or {})
    return summary


# -- work against residual: the ratios of compare ris-2d (issue 12) ---------------------------

#: the keys of a row of compare.json, in this order
COMPARE_KEYS = (
    "control",
    "tol",
    "tau",
    "accepted",
    "rejected",
    "solves",
    "newton",
    "seconds",
    "local_residual",
    "global_residual",
    "ratio_steps",
    "ratio_solves",
    "ratio_seconds",
)


def equidistribution_bound(residuals) -> float | None:
    """(sum_k sqrt(J_k))^2 / (M sum_k J_k) over the pair means J_k = (I_k + I_{k+1}) / 2 of the
    residuals I_k = I1^k + I2^k of a uniform run (M = N - 1 pairs).

    A lower bound for the accepted steps of *any* step sequence, as a fraction of the uniform
    run's, at the same global residual G, when the residual of a step is I = C(s) tau^2 with a
    density C(s) that the steps do not change (Lemma 5.3): by Cauchy-Schwarz,
    (sum_k sqrt(I_k))^2 <= N sum_k I_k = N G, and sum_k sqrt(I_k) = sum_k sqrt(C(s_k)) tau_k
    ~ int sqrt(C) ds is the same for every sequence; equality holds when all I_k are equal. For a
    uniform run, sqrt(C_k) tau = sqrt(I_k), so its own steps give C. Pair means, because in slip
    the time increments carry a period-2 oscillation, dt_k = tau - v dt_{k-1} (neutral in
    Example 7.1, v = 1): single residuals alternate between two levels at a fixed density --
    there I1 = L dt_k (dt_{k-1} + dt_k) / 2, whose sum over a pair does not depend on the phase --
    and Cauchy-Schwarz over the raw steps would give a bound no step sequence reaches (0.19
    instead of the 0.375 of Example 7.1). None without residual.
    """
    I = np.maximum(np.asarray(residuals, dtype=float), 0.0)
    if I.size < 2 or I.sum() <= 0.0:
        return None
    J = 0.5 * (I[1:] + I[:-1])
    return float(np.sum(np.sqrt(J)) ** 2 / (J.size * J.sum()))


#: work measures of a run (key of its summary row) and the ratio they enter in compare.json
WORK_RATIOS = (
    ("accepted_steps", "ratio_steps"),
    ("inner_solves", "ratio_solves"),
    ("wall_time_s", "ratio_seconds"),
)


def uniform_work_interpolant(rows, work: str, key: str = "sum_residual"):
    """Work of the uniform scheme at a given global residual, interpolated log-log between the
    two uniform runs whose residuals bracket it; None outside their range (no extrapolation).

    Returns a callable residual -> work or None, or None if fewer than two uniform runs completed.
    """
    u = sorted(
        (r[key], r[work])
        for r in rows
        if r["control"] == "uniform"
        and r.get("status", "completed") == "completed"
        and r.get(key, 0) > 0
        and r.get(work, 0) > 0
    )
    if len(u) < 2:
        return None
    x = np.log([g for g, _ in u])
    y = np.log([w for _, w in u])

    def work_at(residual: float) -> float | None:
        if not residual > 0:
            return None
        lx = math.log(residual)
        # a residual equal to the smallest/largest uniform one (to round-off) is in range
        if lx < x[0] - 1e-12 or lx > x[-1] + 1e-12:
            return None
        return float(np.exp(np.interp(lx, x, y)))

    return work_at


def compare_rows(rows) -> list[dict]:
    """The rows of compare.json (keys :data:`COMPARE_KEYS`, in that order) from summary rows.

    ``ratio_steps``, ``ratio_solves``, ``ratio_seconds``: the run's accepted steps, inner solves
    and seconds divided by the uniform scheme's at the same global residual sum_k(I1 + I2)
    (:func:`uniform_work_interpolant`); null for the uniform rows, for a residual outside the
    uniform runs' range, and for a run that did not complete.
    """
    interp = {ratio: uniform_work_interpolant(rows, work) for work, ratio in WORK_RATIOS}
    out = []
    for r in rows:
        uniform = r["control"] == "uniform"
        # a run that produced nothing (an error, a lost task) has its status only: nulls
        row = {
            "control": r["control"],
            "tol": None if uniform else r["tol"],
            "tau": r["tau0"],
            "accepted": r.get("accepted_steps"),
            "rejected": r.get("rejected_steps"),
            "solves": r.get("inner_solves"),
            "newton": r.get("newton_iterations"),
            "seconds": r.get("wall_time_s"),
            "local_residual": r.get("max_residual"),
            "global_residual": r.get("sum_residual"),
        }
        for work, ratio in WORK_RATIOS:
            fn = interp[ratio]
            base = None
            if (
                not uniform
                and fn is not None
                and r.get("status", "completed") == "completed"
                and work in r
            ):
                base = fn(r["sum_residual"])
            row[ratio] = None if base is None else r[work] / base
        assert tuple(row) == COMPARE_KEYS
        out.append(row)
    return out


def finest_uniform_bound(rows) -> tuple[float, float] | None:
    """(tau, bound) of the completed uniform run with the smallest step, or None.

    The rows are those of a comparison whose uniform rows hold ``equidistribution_bound``."""
    u = [
        r
        for r in rows
        if r["control"] == "uniform"
        and r["status"] == "completed"
        and r.get("equidistribution_bound") is not None
    ]
    if not u:
        return None
    r = min(u, key=lambda r: r["tau0"])
    return r["tau0"], r["equidistribution_bound"]


def uniform_work_at_error(rows, key="error_linf"):
    """Fit log(inner solves) = a + b log(error) over the completed uniform rows; returns a
    callable (None with fewer than two such rows)."""
    u = [
        r for r in rows if r["control"] == "uniform" and r.get("status", "completed") == "completed"
    ]
    if len(u) < 2:
        return None
    x = np.log([r[key] for r in u])
    y = np.log([r["inner_solves"] for r in u])
    b, a = np.polyfit(x, y, 1)
    return lambda err: float(np.exp(a + b * np.log(err)))


# -- which stationary branch a run followed -----------------------------------------------------


def _zero_dt_runs(traj, rel: float):
    """(starts, ends, tiny) of the maximal runs of accepted steps with t_k - t_{k-1} <= rel tau_k.

    Steps of round-off size (tau_k <= 1e-12 max(1, s_k), e.g. a step that closes the gap to a
    grid point of an earlier nested run) say nothing about t^': they continue whatever the step
    before them was and never start a run on their own.
    """
    t, s, tau = traj["t"], traj["s"], traj["tau"]
    jump = np.diff(t) <= rel * tau
    tiny = tau <= 1e-12 * np.maximum(1.0, s[1:])
    last_real = np.maximum.accumulate(np.where(~tiny, np.arange(len(tau)), -1))
    jump = np.where(last_real >= 0, jump[np.maximum(last_real, 0)], False)
    edges = np.diff(np.concatenate([[0], jump.astype(int), [0]]))
    return np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0], tiny


def viscous_jumps(traj, rel: float = 1e-8) -> list[dict]:
    """Viscous jumps of a run, as ``{"t": t, "s_start": s, "s_end": s, "steps": k}``.

    A viscous jump is a maximal interval of s on which t^ is constant (t_k - t_{k-1} <=
    rel * tau_k: the ball constraint is active, the state moves while physical time stands
    still) that spans **more than one step** and is longer in s than the step before it.

    Not counted (see :func:`catch_up_steps`): a single step with t^' = 0, and a run shorter in s
    than the step before it. After a step of length tau in rate-independent slip, z_k is
    stationary at t_{k-1}, so it lags the equilibrium of t_k by up to about tau; a following
    step that is no longer (after tau is halved by a rejection, one that lands on T or on a
    nested grid point, or the neutral period-2 oscillation of the time increments in slip,
    dt_k = tau - dt_{k-1}) is then spent on catching up, with t^' = 0 and lambda > 0. Such
    steps vanish with the step size; a viscous jump of the BV solution does not.
    """
    if len(traj) == 0:
        return []
    t, s, tau = traj["t"], traj["s"], traj["tau"]
    starts, ends, tiny = _zero_dt_runs(traj, rel)
    out = []
    for a, b in zip(starts, ends, strict=True):
        steps = int(np.count_nonzero(~tiny[a:b]))
        if steps < 2:
            continue
        before = np.nonzero(~tiny[:a])[0]
        if before.size and s[b] - s[a] <= tau[before[-1]] * (1 + 1e-9):
            continue
        out.append({"t": float(t[a]), "s_start": float(s[a]), "s_end": float(s[b]), "steps": steps})
    return out


#: viscous jumps listed in the one-line ``branch`` summary and the compare table (all of them
#: are in summary.json)
JUMPS_SHOWN = 5


def format_jump_times(jumps, shown: int = JUMPS_SHOWN, sep: str = ", ") -> str:
    """'t1, t2, ...' for the first ``shown`` jumps, then '(+k more)'; 'none' if there is none."""
    if not jumps:
        return "none"
    text = sep.join(f"{j['t']:.4g}" for j in jumps[:shown])
    if len(jumps) > shown:
        text += f" (+{len(jumps) - shown} more)"
    return text


def catch_up_steps(traj, rel: float = 1e-8) -> int:
    """Number of steps with t^' = 0 that :func:`viscous_jumps` does not count as a jump."""
    if len(traj) == 0:
        return 0
    starts, ends, tiny = _zero_dt_runs(traj, rel)
    in_runs = sum(int(np.count_nonzero(~tiny[a:b])) for a, b in zip(starts, ends, strict=True))
    return in_runs - sum(j["steps"] for j in viscous_jumps(traj, rel))


def nodal_volumes(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Lumped P1 mass m_i = int phi_i = sum of |K| / (d + 1) over the cells at node i."""
    points, cells = np.asarray(points, dtype=float), np.asarray(cells)
    d = points.shape[1]
    edges = points[cells[:, 1:]] - points[cells[:, :1]]  # (nc, d, d)
    vol = np.abs(np.linalg.det(edges)) / math.factorial(d)
    return np.bincount(
        cells.ravel(), weights=np.repeat(vol / (d + 1), d + 1), minlength=len(points)
    )


def describe_branch(problem: FERISProblem, traj) -> dict:
    """Energy, range and mean of the final state and the viscous jumps: which branch a run took.

    Several stationary points exist (g is a double well): the run reports where it ended --
    the sign of z (g is even, so z -> -z maps branches onto each other), its range and int z --
    and when it jumped. A one-line ``branch`` string summarizes it.
    """
    z = traj["z"][-1]
    jumps = viscous_jumps(traj)
    m_all = problem.m_all
    if getattr(traj, "meshes", None) is not None:  # space adaptivity: the last state's mesh
        m_all = nodal_volumes(*traj.meshes.mesh(traj["z_mesh_id"][-1]))
    mean = float(m_all @ z) / float(m_all.sum())
    zmin, zmax = float(z.min()), float(z.max())
    sign = "z <= 0" if zmax <= 1e-12 else ("z >= 0" if zmin >= -1e-12 else "z changes sign")
    energy = float(traj["energy"][-1])
    jt = format_jump_times(jumps)
    catch = catch_up_steps(traj)
    return {
        "energy_final": energy,
        "z_min": zmin,
        "z_max": zmax,
        "z_mean": mean,
        "n_viscous_jumps": len(jumps),
        "viscous_jumps": jumps,
        "catch_up_steps": catch,
        "branch": (
            f"{sign}, z in [{zmin:.4g}, {zmax:.4g}], mean {mean:.4g}, energy {energy:.6g}, "
            f"{len(jumps)} viscous jump(s) at t = {jt}"
            + (f" (+{catch} catch-up step(s) with t' = 0)" if catch else "")
        ),
    }
