"""Space-adaptive vs uniform meshes at equal error, per family (issue 8).

    python benchmarks/space_adaptivity.py [--quick] [--family eld|ris|all]

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
(``SpaceAdaptivity(norm="l2")``); a last line gives the energy-norm series' L2 ratios.

RIS: ``space_adaptivity_ris.run_ris_family`` (the unique front ``ris-front-unique``; its docstring
states the error norm and the work measure), printed by ``ris`` below.
"""

from __future__ import annotations

import argparse
import math
import resource
import time

import numpy as np

#: the finest uniform run of the full benchmark takes at least this long (issue 18) ...
UNIFORM_SECONDS = 30.0
#: ... or is this many refinements of the n = 4 mesh (the reference, one finer, has 1.05M dofs)
MAX_UNIFORM_LEVEL = 5
#: the adaptive runs adapt after every 4th step of 0.01, every 0.04 time units (eld-pulse: 6
#: steps of 0.005); the band is the default, c_p tau adapt_every
PULSE_ADAPT_EVERY = 4


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def p2_basis(lam):
    """The six P2 basis functions of a triangle at barycentric coordinates lam (3, ...) in
    scikit-fem's local order: vertices 0, 1, 2, then the edges (0, 1), (1, 2), (0, 2)."""
    l0, l1, l2 = lam
    return np.stack(
        [
            l0 * (2 * l0 - 1),
            l1 * (2 * l1 - 1),
            l2 * (2 * l2 - 1),
            4 * l0 * l1,
            4 * l1 * l2,
            4 * l0 * l2,
        ]
    )


def interpolate_to(points, cells, degree, ref):
    """The sparse P2 interpolation from the mesh (points (nv, 2), cells (nc, 3)), nested in the
    reference mesh, to the reference's scalar dofs (``ref``: its VectorSpace). Exact for nested
    meshes: every reference cell lies in one cell of the coarser mesh, found from the
    reference cell's barycentre (matplotlib's trapezoid-map point location, O(log n) per point,
    no dense temporaries: scikit-fem's ``probes`` took 2.4 GB at a 66k-dof reference), and the
    reference cell's six nodes take the coarse cell's P2 interpolant there."""
    import scipy.sparse as sp
    from matplotlib.tri import Triangulation
    from skfem import MeshTri

    from rothe.fem.elasticity import VectorSpace

    assert degree == 2
    mesh = MeshTri(np.ascontiguousarray(points.T), np.ascontiguousarray(cells.T))
    coarse = VectorSpace(mesh, 2)
    cp, ct = np.asarray(mesh.p), np.asarray(mesh.t)
    finder = Triangulation(cp[0], cp[1], ct.T).get_trifinder()
    rmesh = ref.mesh
    rp, rt = np.asarray(rmesh.p), np.asarray(rmesh.t)
    red = ref.element_dofs  # (6, n_ref_cells)
    # each reference dof once: one reference cell that has it (the last one numpy assigns)
    first = np.full(ref.n_scalar, -1, dtype=np.int64)
    first[red.ravel()] = np.tile(np.arange(red.shape[1]), 6)
    rows, cols, vals = [], [], []
    chunk = 200_000
    for lo in range(0, red.shape[1], chunk):
        rc = np.arange(lo, min(lo + chunk, red.shape[1]))
        bary = rp[:, rt[:, rc]].mean(axis=1)
        c = finder(bary[0], bary[1])
        if np.any(c < 0):
            raise RuntimeError("a reference cell outside the mesh: not nested")
        X = cp[:, ct[:, c]]  # (2, 3, n)
        J = np.stack([X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]], axis=1)  # (2, 2, n): columns
        Jinv = np.linalg.inv(np.moveaxis(J, -1, 0))  # (n, 2, 2)
        for k in range(6):
            dof = red[k, rc]
            own = first[dof] == rc  # this cell writes the row of this dof
            if not own.any():
                continue
            x = ref.doflocs[:, dof[own]] - X[:, 0][:, own]
            ab = np.einsum("nij,jn->in", Jinv[own], x)
            lam = np.stack([1.0 - ab[0] - ab[1], ab[0], ab[1]])
            if lam.min(initial=0.0) < -1e-9:  # a reference node outside its cell's coarse cell
                raise RuntimeError("the mesh is finer than the reference somewhere: not nested")
            phi = p2_basis(lam)  # (6, n)
            rows.append(np.repeat(dof[own][None, :], 6, axis=0).ravel())
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


def eld(quick: bool) -> float | None:
    from rothe.eld import BDF2, run_eld
    from rothe.eld.examples import pulse_problem, rectangle
    from rothe.fem.adapt import AdaptiveMesh, SpaceAdaptivity
    from rothe.stepping.controllers import Uniform

    T, tau = (0.6, 0.01) if quick else (0.8, 0.01)
    n0 = 4
    # uniform refinements of the n0 mesh: quick a fixed set; full until one run takes
    # UNIFORM_SECONDS (the finest must take that long, issue 18), at most MAX_UNIFORM_LEVEL
    # (the reference is one level finer: 1.05M dofs at level 6)
    tols = (5e-3, 3e-3, 2e-3) if quick else (5e-3, 3e-3, 2e-3, 1.2e-3, 8e-4, 5e-4)
    # the L2 lines come from runs whose indicator estimates the L2 norm of u (norm='l2':
    # eta_K h_K / h_0, SpaceAdaptivity.norm), the energy lines from the energy-norm runs
    tols_l2 = (6e-4, 3e-4) if quick else (6e-4, 3e-4, 1.5e-4, 8e-5, 5e-5)
    every = round(0.1 / tau)
    base = dict(control=Uniform(tau), scheme=BDF2(), keep_every=every)

    def mesh_at(level):  # the bisection hierarchy's uniform meshes: all nested
        amesh = AdaptiveMesh(rectangle(2 * n0, n0))
        if level:
            amesh.uniform(2 * level)  # two bisection generations halve h
        return amesh.mesh

    print(
        f"ELD pulse: P2, BDF2, tau = {tau:g}, T = {T:g}, outputs every {every} steps; "
        f"uniform meshes: n = {n0} refined 0, 1, ... times "
        + ("(0..3)" if quick else f"until a run takes {UNIFORM_SECONDS:g} s")
        + f"; adaptive: adapt_every {PULSE_ADAPT_EVERY}, the band c_p tau adapt_every, at most "
        "as fine as the reference (nested in it); seconds: "
        "building the problem and the run (solver 'auto': LU up to 200k unknowns, AMG above)"
    )

    runs = []

    def run(label, level, space):
        t0 = time.perf_counter()
        problem = pulse_problem(T=T, mesh=mesh_at(level))
        result = run_eld(problem, adapt=space, **base)
        secs = time.perf_counter() - t0
        traj = result.trajectory
        if space is None:
            mesh = problem.space.mesh
            states = [(mesh.p.T, mesh.t.T, u, v) for u, v in zip(traj["u"], traj["v"], strict=True)]
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
            "times": traj["kept_t"],
            "dofs": dofs,
            "final": final,
            "max": int(np.max(traj["ndofs"])) if "ndofs" in traj else final,
            "steps": len(traj["t"]) - 1,
            "seconds": secs,
            "peak": peak_mb(),
            "balance": float(np.max(np.abs(traj["balance_residual"]))),
        }
        runs.append(rec)
        return rec

    level = 0
    while True:
        r = run(f"uniform n={n0 * 2**level}", level, None)
        print(f"  ({r['label']}: {r['seconds']:.1f} s)", flush=True)
        if (quick and level >= 3) or (
            not quick and (r["seconds"] >= UNIFORM_SECONDS or level >= MAX_UNIFORM_LEVEL)
        ):
            break
        level += 1
    ref_level = level + 1
    max_dofs = AdaptiveMesh(mesh_at(ref_level)).ndofs(2, 2)
    for norm, series in (("energy", tols), ("l2", tols_l2)):
        for tol in series:
            r = run(
                f"adaptive{'-l2' if norm == 'l2' else ''} tol={tol:g}",
                0,
                SpaceAdaptivity(
                    space_tol=tol,
                    refine_fraction=0.5,
                    coarsen_fraction=0.05,
                    max_dofs=max_dofs,
                    adapt_every=PULSE_ADAPT_EVERY,
                    max_level=2 * ref_level,
                    norm=norm,
                ),
            )
            print(f"  ({r['label']}: {r['seconds']:.1f} s)", flush=True)
    ref = run(f"reference n={n0 * 2**ref_level}", ref_level, None)
    print(f"  (reference, {max_dofs} dofs: {ref['seconds']:.1f} s)", flush=True)

    ref_problem = pulse_problem(T=T, mesh=mesh_at(ref_level))
    ref_space = ref_problem.space
    K, Mv, rho = ref_problem.K, ref_problem.M, ref_problem.material.rho
    M = ref_space.scalar_mass()

    def l2(U):  # U (n_scalar, 2)
        return math.sqrt(float(sum(U[:, c] @ (M @ U[:, c]) for c in range(2))))

    def energy(U, V):  # (u.K u + rho v.M v)^(1/2), interleaved vector dofs
        u, v = U.ravel(), V.ravel()
        return math.sqrt(float(u @ (K @ u) + rho * v @ (Mv @ v)))

    ref_states = [(u.reshape(-1, 2), v.reshape(-1, 2)) for (_, _, u, v) in ref["states"]]
    ref_l2 = max(l2(U) for U, _ in ref_states)
    ref_energy = max(energy(U, V) for U, V in ref_states)
    for r in runs[:-1]:
        cache, worst, worst_e = {}, 0.0, 0.0
        for k, (p, c, u, v) in enumerate(r["states"]):
            key = (p.shape, c.shape, float(p.sum()), int(c.sum()))
            if key not in cache:
                cache[key] = interpolate_to(p, c, 2, ref_space)
            U, V = cache[key] @ u.reshape(-1, 2), cache[key] @ v.reshape(-1, 2)
            worst = max(worst, l2(U - ref_states[k][0]))
            worst_e = max(worst_e, energy(U - ref_states[k][0], V - ref_states[k][1]))
        r["error"] = worst / ref_l2
        r["error_energy"] = worst_e / ref_energy

    print(
        f"  {'run':<22} {'steps':>5} {'dofs final':>10} {'dofs max':>9} {'dofs summed':>12} "
        f"{'rel. L2 err':>11} {'rel. E err':>10} {'seconds':>8} {'peak MB':>8} "
        f"{'balance':>9}"
    )
    for r in runs:
        err = (
            f"{r['error']:11.3e} {r['error_energy']:10.3e}"
            if "error" in r
            else f"{'(ref)':>11} {'(ref)':>10}"
        )
        print(
            f"  {r['label']:<22} {r['steps']:>5} {r['final']:>10} {r['max']:>9} "
            f"{r['dofs']:>12} {err} {r['seconds']:>8.1f} {r['peak']:>8.0f} "
            f"{r['balance']:>9.1e}"
        )

    def ratio_at_equal_error(key: str, title: str, prefix: str):
        uniform = [(r[key], r["dofs"]) for r in runs if r["label"].startswith("uniform")]
        useconds = [(r[key], r["seconds"]) for r in runs if r["label"].startswith("uniform")]
        best = None
        print(f"  at equal {title}:")
        for r in runs:
            if not r["label"].startswith(prefix):
                continue
            w = log_interp_work(r[key], uniform)
            s = log_interp_work(r[key], useconds)
            ratio = None if w is None else r["dofs"] / w
            sratio = None if s is None else r["seconds"] / s
            print(
                f"    {r['label']:<22} uniform dofs summed at equal error: "
                + (
                    "outside the uniform range"
                    if w is None
                    else f"{w:12.0f}  ratio {ratio:.3f}  (seconds ratio {sratio:.3f})"
                )
            )
            if ratio is not None and sratio is not None and (best is None or r[key] < best[0]):
                best = (r[key], ratio, sratio, r["label"])
        return best

    best_l2 = ratio_at_equal_error("error", "L2 error of u, L2-norm indicator", "adaptive-l2 ")
    best_l2e = ratio_at_equal_error("error", "L2 error of u, energy-norm indicator", "adaptive ")
    best = ratio_at_equal_error("error_energy", "energy error of (u, v)", "adaptive ")

    def fmt(b, k):
        return "n/a (no adaptive error inside the uniform range)" if b is None else f"{b[k]:.3f}"

    def who(b):
        return "" if b is None else f" ({b[3]}, error {b[0]:.3g})"

    print("eld: work ratio adaptive/uniform at equal error: " + fmt(best, 1) + who(best))
    print("eld: seconds ratio adaptive/uniform at equal error: " + fmt(best, 2) + who(best))
    print(
        "eld: work ratio adaptive/uniform at equal error (L2 of u): "
        + fmt(best_l2, 1)
        + who(best_l2)
    )
    print(
        "eld: seconds ratio adaptive/uniform at equal error (L2 of u): "
        + fmt(best_l2, 2)
        + who(best_l2)
    )
    print(
        "  (the energy-norm runs in L2 of u: work ratio "
        + fmt(best_l2e, 1)
        + ", seconds ratio "
        + fmt(best_l2e, 2)
        + who(best_l2e)
        + ")"
    )
    return None if best is None else best[1]


def ris(quick: bool) -> float | None:
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from space_adaptivity_ris import run_ris_family

    return run_ris_family(quick)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller sizes (< 3 min)")
    parser.add_argument("--family", default="all", choices=("eld", "ris", "all"))
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    if args.family in ("eld", "all"):
        eld(args.quick)
    if args.family in ("ris", "all"):
        ris(args.quick)
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
