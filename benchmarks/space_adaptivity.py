"""Space-adaptive vs uniform meshes at equal error, per family (issue 8).

    python benchmarks/space_adaptivity.py [--quick] [--family eld|eld3d|ris|all]

ELD (:func:`eld`): ``rothe run eld-pulse``'s problem (:func:`rothe.eld.examples.pulse_problem`:
the rectangle [0, 2] x [0, 1], P2, the left side pushed by a short pulse localized around
y = 1/2, a wave front crossing the body), BDF2 with the same uniform step tau for every run.
Runs: uniform meshes n = 4, 8, 16, ... cells across (the bisection hierarchy's uniform
refinements of the n = 4 mesh: every mesh of the benchmark is nested in the reference mesh;
quick: up to n = 32; full: until one run takes ``UNIFORM_SECONDS``, at most n = 128), adaptive
runs (``SpaceAdaptivity``, adapt after every ``PULSE_ADAPT_EVERY``-th step with ELD's default
band, refine_fraction 0.5, coarsen_fraction 0.05, at most as fine as the reference) for several
``space_tol``, and a
reference on the uniform mesh one refinement finer than the finest compared one (P2: its own L2
error is about 1/8 of the finest compared one's), all in this run. Error: the largest over the
output times t = 0.1, 0.2, ..., T of the L2 error of u against the reference, relative to
the largest L2 norm of the reference's u:

    err = max_k ||I u_h(t_k) - u_ref(t_k)||_L2 / max_k ||u_ref(t_k)||_L2,

with I the P2 interpolation onto the reference mesh (exact: every mesh here is nested in the
reference mesh), and the same in the energy norm of the state, (u.K u + rho v.M v)^(1/2) (the
norm the indicator estimates, the scale of the time step control and of the ledger):

    err_E = max_k ||(I u_h - u_ref, I v_h - v_ref)(t_k)||_E / max_k ||(u_ref, v_ref)(t_k)||_E.

With the same tau everywhere the time error is common to all runs and the
comparison is one of the spatial discretizations. Work: dofs summed over the solves (the dofs of
the mesh each step is computed on; a step refined and solved again counts every solve);
seconds are wall seconds of building the problem and the run (2 shared cores: noisy; solver
'auto': LU up to 200k unknowns, AMG above);
``peak MB`` is the process's peak resident memory after the run (monotone; the runs go from
small to large and the reference last). The error evaluation after the runs (the nested P2
interpolation :func:`interpolate_to` of every kept mesh to the reference's dofs) is not in that
column.

The last lines of the family: ``eld: work ratio adaptive/uniform at equal error: X`` and
``eld: seconds ratio adaptive/uniform at equal error: Y``, X = summed dofs (Y = seconds) of the
adaptive run with the smallest energy error inside the range of the uniform errors, divided by
the summed dofs (seconds) the uniform meshes need for that error (log-log interpolation between
the two uniform runs around it); the two lines marked ``(L2 of u)`` give the same for the L2
error of u, from a second adaptive series whose indicator estimates the L2 norm of u
(``SpaceAdaptivity(norm="l2")``, ``adaptive-l2`` in the table; a family without that series
takes them from the energy-norm runs). Those four lines come last, exactly in the issue's
format; the lines before them name the runs the ratios come from and give the CPU-seconds and
peak-memory ratios and the energy-norm series' L2 ratios.

ELD 3D (:func:`eld3d`, the family :data:`ELD3D`): ``rothe run eld-pulse-3d``'s problem
(:func:`rothe.eld.examples.pulse_3d_problem`: the unit cube, P2, the face x = 0 pushed around
its centre), the same table with tau = 0.02, T = 0.5 (quick: 0.3): uniform meshes n = 2, 4, 8,
16 cubes across (three bisection generations halve h; quick: up to n = 8), the reference n = 32
(823 875 dofs, AMG; quick: n = 16), adaptive runs with adapt_every 2. Every run is made in a
fresh process (multiprocessing, spawn), so that its peak memory is its own: ``peak MB`` is
the child's peak resident size (:func:`peak_mb`: VmHWM, interpreter and imports included,
about 140 MB), ``dMB`` the same
minus the child's peak just before the problem is built; the line
``eld3d: peak memory ratio adaptive/uniform at equal error`` compares ``peak MB``
(interpolated log-log in the error like the seconds) and gives the ``dMB`` ratio in brackets.
Both families run through the same code (:func:`pulse_family`, :class:`PulseFamily`).

RIS: ``space_adaptivity_ris.run_ris_family`` (the unique front ``ris-front-unique``; its docstring
states the error norm and the work measure), printed by ``ris`` below.
"""

from __future__ import annotations

import argparse
import math
import pickle
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: the finest uniform run of the full benchmark takes at least this long (issue 18) ...
UNIFORM_SECONDS = 30.0
#: ... or is this many refinements of the n = 4 mesh (the reference, one finer, has 1.05M dofs)
MAX_UNIFORM_LEVEL = 5


def peak_mb() -> float:
    """This process's peak resident memory in MB (:func:`rothe.cli.common.peak_memory_mb`:
    VmHWM, not ``ru_maxrss``, which a spawned child inherits from its parent: the parent of this
    benchmark holds the runs' records and the reference mesh hierarchy, which inflated the
    adaptive runs' peaks by about 110 MB)."""
    from rothe.cli.common import peak_memory_mb  # the children import rothe after the spawn

    return peak_memory_mb()


@dataclass(frozen=True)
class PulseFamily:
    """One family of the pulse benchmark: the body, the step, the runs and how they are run.

    ``dim`` 2: the rectangle [0, 2] x [0, 1] of ``n0`` x 2 ``n0`` squares (eld-pulse), 3: the
    cube of ``n0``^3 cubes of six tetrahedra (eld-pulse-3d); a uniform level refines it d
    bisection generations (h halves). ``subprocess``: every run in a fresh process (spawn),
    its peak memory the child's peak resident size (:func:`peak_mb`: the whole process,
    interpreter and imports included) and the same above the child's peak just before the
    problem is built (``peak MB`` / ``dMB``); otherwise in this process (peak monotone over
    the runs)."""

    name: str
    dim: int
    n0: int
    tau: float
    T: tuple  # (quick, full)
    tols: tuple  # (quick, full)
    adapt_every: int
    quick_level: int  # the finest uniform level of --quick
    max_level: int  # ... of the full benchmark (unless UNIFORM_SECONDS is reached first)
    keep: float = 0.1  # output times every keep
    subprocess: bool = False
    #: (quick, full) tolerances of the L2-norm series (SpaceAdaptivity(norm='l2')): the L2
    #: lines come from it; empty: from the energy-norm series
    tols_l2: tuple = ((), ())


#: 2D: eld-pulse's problem; the adaptive runs adapt after every 4th step of 0.01, every 0.04
#: time units (eld-pulse: 6 steps of 0.005); the band is the default, c_p tau adapt_every
ELD2D = PulseFamily(
    "eld",
    2,
    4,
    0.01,
    (0.6, 0.8),
    ((5e-3, 3e-3, 2e-3), (5e-3, 3e-3, 2e-3, 1.2e-3, 8e-4, 5e-4)),
    4,
    3,
    MAX_UNIFORM_LEVEL,
    tols_l2=((6e-4, 3e-4), (6e-4, 3e-4, 1.5e-4, 8e-5, 5e-5)),
)
#: 3D: eld-pulse-3d's problem on the unit cube. tau = 0.02 (5 steps across the pulse: the
#: time error is large but common to every run, the comparison is one of the spatial
#: discretizations) because the reference (level 4: 824k P2 dofs, AMG) costs ~ 50 s a step
#: on 2 loaded cores (1259 s for 25 steps, docs/adaptivity.md);
#: adapt after every 2nd step (band c_p tau 2 = 0.08)
ELD3D = PulseFamily(
    "eld3d",
    3,
    2,
    0.02,
    (0.3, 0.5),
    ((1.5e-2, 1e-2, 6e-3), (1.2e-2, 8e-3, 6e-3, 4.5e-3)),
    2,
    2,
    3,
    subprocess=True,
    tols_l2=((6e-3, 3e-3), (6e-3, 3e-3, 1.5e-3, 8e-4)),
)


def pulse_mesh(family: PulseFamily, level: int):
    """The family's uniform mesh of ``level`` (the bisection hierarchy's: all nested)."""
    from rothe.eld.examples import block, rectangle
    from rothe.fem.adapt import AdaptiveMesh

    n0 = family.n0
    base = rectangle(2 * n0, n0) if family.dim == 2 else block(n0, n0, n0)
    amesh = AdaptiveMesh(base)
    if level:
        amesh.uniform(family.dim * level)  # d bisection generations halve h
    return amesh


def pulse_of(family: PulseFamily, T: float, mesh):
    from rothe.eld.examples import pulse_3d_problem, pulse_problem

    return pulse_problem(T=T, mesh=mesh) if family.dim == 2 else pulse_3d_problem(T=T, mesh=mesh)


def pulse_run(family: PulseFamily, T: float, label: str, level: int, space: dict | None) -> dict:
    """One run of the family: building the problem and the run timed (wall seconds), the kept
    states (points, cells, u, v), work = dofs summed over the solves (the dofs of the mesh each
    step is computed on; a step refined and solved again counts every solve)."""
    from rothe.eld import BDF2, run_eld
    from rothe.fem.adapt import SpaceAdaptivity
    from rothe.stepping.controllers import Uniform

    mesh = pulse_mesh(family, level).mesh
    base_mb = peak_mb()
    t0, c0 = time.perf_counter(), time.process_time()
    problem = pulse_of(family, T, mesh)
    result = run_eld(
        problem,
        adapt=None if space is None else SpaceAdaptivity(**space),
        control=Uniform(family.tau),
        scheme=BDF2(),
        keep_every=round(family.keep / family.tau),
    )
    secs, cpu = time.perf_counter() - t0, time.process_time() - c0
    traj = result.trajectory
    if space is None:
        m = problem.space.mesh
        states = [(m.p.T, m.t.T, u, v) for u, v in zip(traj["u"], traj["v"], strict=True)]
        dofs = problem.space.ndofs * (len(traj["t"]) - 1)
        final = problem.space.ndofs
    else:
        sp_ = result.meshes
        states = [
            (*sp_.series.mesh(m), u, v)
            for m, u, v in zip(traj["kept_mesh_id"], sp_.kept["u"], sp_.kept["v"], strict=True)
        ]
        dofs = int(np.sum(traj["step_dofs"]))  # every solve, the redone ones too
        final = int(traj["ndofs"][-1])
    rec = {
        "label": label,
        "states": states,
        "times": np.asarray(traj["kept_t"]),
        "dofs": dofs,
        "final": final,
        "max": int(np.max(traj["ndofs"])) if "ndofs" in traj else final,
        "steps": len(traj["t"]) - 1,
        "seconds": secs,
        "cpu": cpu,
        "peak": peak_mb(),
        "dpeak": peak_mb() - base_mb,
        "balance": float(np.max(np.abs(traj["balance_residual"]))),
    }
    # seconds per phase over the run (step, adapt and inside them factor, solve, estimate,
    # mark, refine, rebuild, transfer: the stepper's timers, trajectory.stats.seconds)
    rec["phases"] = dict(result.statistics.seconds)
    return rec


def run_family_member(family: PulseFamily, *args) -> dict:
    """:func:`pulse_run` in this process, or in a fresh spawned one (``family.subprocess``)."""
    if not family.subprocess:
        return pulse_run(family, *args)
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(pulse_run, family, *args).result()


def locate_cells(p: np.ndarray, t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The cell of the simplex mesh (p (d, nv), t (d+1, nc)) that contains each point of x
    (d, m): candidates are the cells with the nearest centroids (a k-d tree, 8, then 32, 128
    for points not yet found, then every cell), the one with the largest smallest barycentric
    coordinate is taken. No dense point-by-cell temporaries (scikit-fem's ``probes`` took
    2.4 GB at a 66k-dof reference)."""
    from scipy.spatial import cKDTree

    d = p.shape[0]
    X0 = p[:, t[0]]  # (d, nc)
    J = np.stack([p[:, t[k + 1]] - X0 for k in range(d)], axis=1)  # (d, d, nc): columns
    Jinv = np.linalg.inv(np.moveaxis(J, -1, 0))  # (nc, d, d)
    tree = cKDTree(p[:, t].mean(axis=1).T)
    found = np.full(x.shape[1], -1, dtype=np.int64)
    todo = np.arange(x.shape[1])
    for k in (8, 32, 128):
        for lo in range(0, todo.size, 20_000):
            pts = todo[lo : lo + 20_000]
            _, cand = tree.query(x[:, pts].T, k=min(k, t.shape[1]))  # (m, k)
            cand = cand.reshape(len(pts), -1)
            rel = x[:, pts][:, :, None] - X0[:, cand]  # (d, m, k)
            ab = np.einsum("mkij,jmk->imk", Jinv[cand], rel)
            lam_min = np.minimum(1.0 - ab.sum(axis=0), ab.min(axis=0))  # (m, k)
            best = np.argmax(lam_min, axis=1)
            ok = lam_min[np.arange(len(pts)), best] >= -1e-9
            found[pts[ok]] = cand[np.arange(len(pts)), best][ok]
        todo = np.flatnonzero(found < 0)
        if todo.size == 0:
            return found
    # a strongly graded mesh (3D: up to 12 generations between neighbours) can hide a large
    # cell behind more than 128 nearer small ones: the few points left try every cell
    for i in todo:
        rel = x[:, i][:, None] - X0  # (d, nc)
        ab = np.einsum("cij,jc->ic", Jinv, rel)
        lam_min = np.minimum(1.0 - ab.sum(axis=0), ab.min(axis=0))
        c = int(np.argmax(lam_min))
        if lam_min[c] < -1e-9:
            raise RuntimeError("a point outside the mesh: not nested")
        found[i] = c
    return found


def interpolate_to(points, cells, degree, ref):
    """The sparse P2 interpolation from the mesh (points (nv, d), cells (nc, d+1)), nested in
    the reference mesh, to the reference's scalar dofs (``ref``: its VectorSpace), d = 2 or 3.
    Exact for nested meshes: every reference cell lies in one cell of the coarser mesh, found
    from the reference cell's barycentre (:func:`locate_cells`), and the reference cell's
    nodes take the coarse cell's P2 interpolant there (the P2 basis at barycentric coordinates,
    :func:`rothe.fem.topology.lagrange_values`)."""
    import scipy.sparse as sp
    from skfem import MeshTet, MeshTri

    from rothe.fem.elasticity import VectorSpace
    from rothe.fem.topology import lagrange_values

    assert degree == 2
    d = points.shape[1]
    mesh = (MeshTri if d == 2 else MeshTet)(
        np.ascontiguousarray(points.T), np.ascontiguousarray(cells.T)
    )
    coarse = VectorSpace(mesh, 2)
    cp, ct = np.asarray(mesh.p), np.asarray(mesh.t)
    rmesh = ref.mesh
    rp, rt = np.asarray(rmesh.p), np.asarray(rmesh.t)
    red = ref.element_dofs  # (n_local, n_ref_cells)
    n_local = red.shape[0]
    # each reference dof once: one reference cell that has it (the last one numpy assigns)
    first = np.full(ref.n_scalar, -1, dtype=np.int64)
    first[red.ravel()] = np.tile(np.arange(red.shape[1]), n_local)
    rows, cols, vals = [], [], []
    chunk = 200_000
    for lo in range(0, red.shape[1], chunk):
        rc = np.arange(lo, min(lo + chunk, red.shape[1]))
        c = locate_cells(cp, ct, rp[:, rt[:, rc]].mean(axis=1))
        X = cp[:, ct[:, c]]  # (d, d+1, n)
        J = np.stack([X[:, k + 1] - X[:, 0] for k in range(d)], axis=1)  # (d, d, n): columns
        Jinv = np.linalg.inv(np.moveaxis(J, -1, 0))  # (n, d, d)
        for k in range(n_local):
            dof = red[k, rc]
            own = first[dof] == rc  # this cell writes the row of this dof
            if not own.any():
                continue
            x = ref.doflocs[:, dof[own]] - X[:, 0][:, own]
            ab = np.einsum("nij,jn->in", Jinv[own], x)
            lam = np.concatenate([1.0 - ab.sum(axis=0, keepdims=True), ab])
            if lam.min(initial=0.0) < -1e-9:  # a reference node outside its cell's coarse cell
                raise RuntimeError("the mesh is finer than the reference somewhere: not nested")
            phi = lagrange_values(lam, 2)  # (n_local, n)
            rows.append(np.repeat(dof[own][None, :], n_local, axis=0).ravel())
            cols.append(coarse.element_dofs[:, c[own]].ravel())
            vals.append(phi.ravel())
    R = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=(ref.n_scalar, coarse.n_scalar),
    )
    R.data[np.abs(R.data) < 1e-14] = 0.0
    R.eliminate_zeros()
    return R


def log_interp_work(err, uniform):
    """Summed dofs the uniform runs need for error ``err`` (log-log between neighbours), or
    None outside their range. ``uniform``: [(error, work)], any order."""
    pts = sorted(uniform)  # by error
    for (e0, w0), (e1, w1) in zip(pts, pts[1:], strict=False):
        if e0 <= err <= e1:
            if e1 == e0:
                return min(w0, w1)
            s = (math.log(err) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(w0) + s * (math.log(w1) - math.log(w0)))
    return None


def relative_errors(runs: list, ref: dict, ref_problem, dim: int) -> None:
    """Sets ``error`` (L2 of u) and ``error_energy`` of every run but the reference (the
    module docstring's err and err_E) against ``ref``."""
    ref_space = ref_problem.space
    K, Mv, rho = ref_problem.K, ref_problem.M, ref_problem.material.rho
    M = ref_space.scalar_mass()

    def l2(U):  # U (n_scalar, d)
        return math.sqrt(float(sum(U[:, c] @ (M @ U[:, c]) for c in range(dim))))

    def energy(U, V):  # (u.K u + rho v.M v)^(1/2), interleaved vector dofs
        u, v = U.ravel(), V.ravel()
        return math.sqrt(float(u @ (K @ u) + rho * v @ (Mv @ v)))

    ref_states = [(u.reshape(-1, dim), v.reshape(-1, dim)) for (_, _, u, v) in ref["states"]]
    ref_l2 = max(l2(U) for U, _ in ref_states)
    ref_energy = max(energy(U, V) for U, V in ref_states)
    for r in runs:
        if r is ref:
            continue
        cache, worst, worst_e = {}, 0.0, 0.0
        for k, (p, c, u, v) in enumerate(r["states"]):
            key = (p.shape, c.shape, float(p.sum()), int(c.sum()))
            if key not in cache:
                cache[key] = interpolate_to(p, c, 2, ref_space)
            U, V = cache[key] @ u.reshape(-1, dim), cache[key] @ v.reshape(-1, dim)
            worst = max(worst, l2(U - ref_states[k][0]))
            worst_e = max(worst_e, energy(U - ref_states[k][0], V - ref_states[k][1]))
        r["error"] = worst / ref_l2
        r["error_energy"] = worst_e / ref_energy


def print_runs(runs: list, memory_delta: bool) -> None:
    """The table of the runs (errors: ``(ref)`` for the reference)."""
    print(
        f"  {'run':<22} {'steps':>5} {'dofs final':>10} {'dofs max':>9} {'dofs summed':>12} "
        f"{'rel. L2 err':>11} {'rel. E err':>10} {'seconds':>8} {'CPU s':>7} {'peak MB':>8} "
        + (f"{'dMB':>7} " if memory_delta else "")
        + f"{'balance':>9}"
    )
    for r in runs:
        err = (
            f"{r['error']:11.3e} {r['error_energy']:10.3e}"
            if "error" in r
            else f"{'(ref)':>11} {'(ref)':>10}"
        )
        print(
            f"  {r['label']:<22} {r['steps']:>5} {r['final']:>10} {r['max']:>9} "
            f"{r['dofs']:>12} {err} {r['seconds']:>8.1f} {r.get('cpu', math.nan):>7.1f} "
            f"{r['peak']:>8.0f} "
            + (f"{r['dpeak']:>7.0f} " if memory_delta else "")
            + f"{r['balance']:>9.1e}"
        )


def print_phases(runs: list) -> None:
    """Seconds per phase of every run (the stepper's timers: step, adapt, record and inside
    them factor, solve, estimate, mark, refine, rebuild, transfer)."""
    print("  seconds per phase:")
    for r in runs:
        parts = ", ".join(f"{k} {v:.1f}" for k, v in sorted(r["phases"].items()) if v >= 0.05)
        print(f"    {r['label']:<22} {parts}")


def ratio_at_equal_error(
    runs: list, key: str, title: str, memory: bool = False, series: str = "adaptive "
):
    """Per adaptive run of ``series`` (the label's prefix: ``"adaptive "`` the energy-norm
    runs, ``"adaptive-l2 "`` the L2-norm runs): the uniform runs' summed dofs (seconds, peak
    memory) at its error ``key`` (log-log interpolation, :func:`log_interp_work`) and the
    ratios; returns (error, dofs ratio, seconds ratio, label, memory ratio, memory-above-
    baseline ratio, CPU seconds ratio or None) of the adaptive run with the smallest error
    inside the uniform range, or None. CPU seconds (the process's, all threads) are what a
    loaded machine disturbs least: the wall seconds of one run varied 2-5x with the load."""
    uniform = [r for r in runs if r["label"].startswith("uniform")]
    with_cpu = all("cpu" in u for u in uniform)

    def at(r, what):
        return log_interp_work(r[key], [(u[key], u[what]) for u in uniform])

    best = None
    print(f"  at equal {title}:")
    for r in runs:
        if not r["label"].startswith(series):
            continue
        w, s = at(r, "dofs"), at(r, "seconds")
        ratio = None if w is None else r["dofs"] / w
        sratio = None if s is None else r["seconds"] / s
        cratio = None
        if with_cpu and "cpu" in r and w is not None:
            cratio = r["cpu"] / at(r, "cpu")
        mratio = dratio = None
        if memory and w is not None:
            mratio = r["peak"] / at(r, "peak")
            dratio = r["dpeak"] / at(r, "dpeak")
        print(
            f"    {r['label']:<22} uniform dofs summed at equal error: "
            + (
                "outside the uniform range"
                if w is None
                else f"{w:12.0f}  ratio {ratio:.3f}  (seconds ratio {sratio:.3f}"
                + ("" if cratio is None else f", CPU seconds ratio {cratio:.3f}")
                + ("" if mratio is None else f", peak memory ratio {mratio:.3f}")
                + ")"
            )
        )
        if ratio is not None and sratio is not None and (best is None or r[key] < best[0]):
            best = (r[key], ratio, sratio, r["label"], mratio, dratio, cratio)
    return best


def print_ratio_lines(name: str, best, best_l2, memory: bool = False, best_l2e=None) -> None:
    """The family's last lines (issue 18): what the ratios come from, the CPU-seconds and
    peak-memory ratios, then, last, the issue's four lines exactly: ``<name>: work ratio
    adaptive/uniform at equal error: X``, the seconds ratio, and both again marked ``(L2 of
    u)``; ``best_l2e``: the energy-norm series in L2 of u when the L2 lines come from an
    L2-norm series."""

    def fmt(b, k):
        return "n/a (no adaptive error inside the uniform range)" if b is None else f"{b[k]:.3f}"

    def who(b):
        return "n/a" if b is None else f"{b[3]}, error {b[0]:.3g}"

    print(f"{name}: the ratios at equal energy error are those of {who(best)}")
    print(f"{name}: the ratios in L2 of u are those of {who(best_l2)}")
    if best_l2e is not None:
        print(
            f"{name}: the energy-norm runs in L2 of u: work ratio {fmt(best_l2e, 1)}, seconds "
            f"ratio {fmt(best_l2e, 2)} ({who(best_l2e)})"
        )
    if best is not None and best[6] is not None:
        print(f"{name}: CPU seconds ratio adaptive/uniform at equal error: {fmt(best, 6)}")
    if memory:
        extra = "" if best is None else f" (above the process's start: {best[5]:.3f})"
        print(f"{name}: peak memory ratio adaptive/uniform at equal error: {fmt(best, 4)}{extra}")
    print(f"{name}: work ratio adaptive/uniform at equal error: {fmt(best, 1)}")
    print(f"{name}: seconds ratio adaptive/uniform at equal error: {fmt(best, 2)}")
    print(f"{name}: work ratio adaptive/uniform at equal error (L2 of u): {fmt(best_l2, 1)}")
    print(f"{name}: seconds ratio adaptive/uniform at equal error (L2 of u): {fmt(best_l2, 2)}")


def pulse_family(family: PulseFamily, quick: bool, cache: str | None = None) -> float | None:
    """The adaptive-vs-uniform table of a pulse family (module docstring); ``cache``: a
    directory for the runs' records (``--cache``)."""
    T = family.T[0] if quick else family.T[1]
    tols = family.tols[0] if quick else family.tols[1]
    tols_l2 = family.tols_l2[0] if quick else family.tols_l2[1]
    d, n0 = family.dim, family.n0
    what = f"n = {n0}" if d == 2 else f"n = {n0} cubes across"
    print(
        f"{family.name} pulse: {d}D, P2, BDF2, tau = {family.tau:g}, T = {T:g}, outputs every "
        f"{family.keep:g}; uniform meshes: {what} refined 0, 1, ... times "
        + (
            f"(0..{family.quick_level})"
            if quick
            else f"until a run takes {UNIFORM_SECONDS:g} s (at most {family.max_level})"
        )
        + f"; adaptive: adapt_every {family.adapt_every}, the band c_p tau adapt_every, at "
        "most as fine as the reference (nested in it); seconds: building the problem and the "
        "run (solver 'auto': LU up to "
        + (
            "200k unknowns, AMG above"
            if d == 2
            else "30k unknowns, AMG above; the adaptive runs' meshes: LU up to 1.5k, above it "
            "Jacobi-CG up to CFL c_p tau_eff / h_min 2, AMG above"
        )
        + ")"
        + ("; every run in its own process" if family.subprocess else "")
    )
    runs = []

    def run(label, level, space):
        # with --cache DIR every record is kept on disk and a kept one is not run again
        # (the error evaluation can be redone without the runs)
        path = None if cache is None else Path(cache) / f"{family.name}-{quick:d}-{label}.pkl"
        if path is not None and path.is_file():
            r = pickle.loads(path.read_bytes())
        else:
            r = run_family_member(family, T, label, level, space)
            if path is not None:
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_bytes(pickle.dumps(r, protocol=pickle.HIGHEST_PROTOCOL))
        runs.append(r)
        print(f"  ({label}: {r['seconds']:.1f} s, peak {r['peak']:.0f} MB)", flush=True)
        return r

    level = 0
    while True:
        r = run(f"uniform n={n0 * 2**level}", level, None)
        if (quick and level >= family.quick_level) or (
            not quick and (r["seconds"] >= UNIFORM_SECONDS or level >= family.max_level)
        ):
            break
        level += 1
    ref_level = level + 1
    max_dofs = pulse_mesh(family, ref_level).ndofs(2, d)
    for norm, series in (("energy", tols), ("l2", tols_l2)):
        for tol in series:
            run(
                f"adaptive{'-l2' if norm == 'l2' else ''} tol={tol:g}",
                0,
                dict(
                    space_tol=tol,
                    refine_fraction=0.5,
                    coarsen_fraction=0.05,
                    max_dofs=max_dofs,
                    adapt_every=family.adapt_every,
                    max_level=d * ref_level,
                    norm=norm,
                ),
            )
    ref = run(f"reference n={n0 * 2**ref_level}", ref_level, None)
    t0 = time.perf_counter()
    relative_errors(runs, ref, pulse_of(family, T, pulse_mesh(family, ref_level).mesh), d)
    print(f"  (errors against the reference: {time.perf_counter() - t0:.0f} s)")
    print_runs(runs, family.subprocess)
    print_phases(runs)
    best_l2e = ratio_at_equal_error(runs, "error", "L2 error of u", family.subprocess)
    best_l2 = best_l2e
    if tols_l2:
        best_l2 = ratio_at_equal_error(
            runs, "error", "L2 error of u, L2-norm series", family.subprocess, "adaptive-l2 "
        )
    best = ratio_at_equal_error(runs, "error_energy", "energy error of (u, v)", family.subprocess)
    print_ratio_lines(family.name, best, best_l2, family.subprocess, best_l2e if tols_l2 else None)
    return None if best is None else best[1]


def eld(quick: bool, cache: str | None = None) -> float | None:
    return pulse_family(ELD2D, quick, cache)


def eld3d(quick: bool, cache: str | None = None) -> float | None:
    return pulse_family(ELD3D, quick, cache)


def ris(quick: bool) -> float | None:
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from space_adaptivity_ris import run_ris_family

    return run_ris_family(quick)


def phases_of_one_run(family: PulseFamily, tol: float) -> None:
    """One adaptive run of the full benchmark's family (space_tol ``tol``, energy norm), in this
    process (3D: in a fresh one, as in the benchmark, so that its peak is the run's own): its
    wall and CPU seconds and the seconds per phase per step (the per-phase table of
    docs/adaptivity.md; ``--phases TOL``). CPU seconds are what a loaded machine disturbs
    least."""
    T = family.T[1]
    ref_level = family.max_level + 1  # the full benchmark's reference (3D: n = 32, 2D: 256)
    space = dict(
        space_tol=tol,
        refine_fraction=0.5,
        coarsen_fraction=0.05,
        max_dofs=pulse_mesh(family, ref_level).ndofs(2, family.dim),
        adapt_every=family.adapt_every,
        max_level=family.dim * ref_level,
        norm="energy",
    )
    # in a fresh process for the 3D family, like the benchmark's runs: its peak is the run's
    # own (this process built the reference-level hierarchy for max_dofs, 183 MB in 3D)
    r = run_family_member(family, T, f"adaptive tol={tol:g}", 0, space)
    cpu = r["cpu"]
    steps = r["steps"]
    print(
        f"{family.name} adaptive tol={tol:g}: {steps} steps, wall {r['seconds']:.2f} s, CPU "
        f"{cpu:.2f} s, dofs summed {r['dofs']}, balance "
        f"{r['balance']:.1e}, peak {r['peak']:.0f} MB ({r['dpeak']:.0f} MB above the peak "
        "before the problem was built)"
    )
    print(
        "  seconds per step (wall): "
        + ", ".join(f"{k} {v / steps:.3f}" for k, v in sorted(r["phases"].items()))
    )


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller sizes (< 3 min)")
    parser.add_argument("--family", default="all", choices=("eld", "eld3d", "ris", "all"))
    parser.add_argument(
        "--cache",
        default=None,
        help="ELD: keep every run's record in this directory and reuse kept ones",
    )
    parser.add_argument(
        "--phases",
        type=float,
        default=None,
        metavar="TOL",
        help="only one adaptive run of the family (space_tol TOL) in this process: its phases",
    )
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    if args.phases is not None:
        fam = {"eld": ELD2D, "eld3d": ELD3D}.get(args.family)
        if fam is None:
            parser.error(f"--phases: got --family {args.family}, must be eld or eld3d")
        if not args.phases > 0:
            parser.error(f"--phases: got {args.phases:g}, must be > 0")
        phases_of_one_run(fam, args.phases)
        return
    if args.family in ("eld", "all"):
        eld(args.quick, args.cache)
    if args.family in ("eld3d", "all"):
        eld3d(args.quick, args.cache)
    if args.family in ("ris", "all"):
        ris(args.quick)
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
