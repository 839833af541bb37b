"""Elastodynamics at a million unknowns: rothe against the FEniCSx (dolfinx 0.5) peer script.

    python benchmarks/eld_peers.py              # full table (N = 44: 1,075,275 dofs; ~1 hour)
    python benchmarks/eld_peers.py --quick      # small sizes, one repeat (a few minutes)
    python benchmarks/eld_peers.py --repeats 1 --skip-p2 --skip-agreement

The problem is the ``eld-beam`` cantilever (3D, E = 1000, nu = 0.3, rho = 1, Rayleigh damping
a = 0, b = 0.002, the end x = 0 moved by G(t) = (0, 0, A (1 - cos(2 pi t/0.5))/2), A = 0.1), on
the identical tetrahedral mesh (rothe builds it with ``meshes.box``; the peer reads the same
arrays exported by the peer's ``export_beam_mesh.py``) with the same time steps (implicit Euler,
tau = 0.01). Every run is its own process, so that its peak resident memory (``ru_maxrss`` of
the child, from ``os.wait4``) is its own; tools alternate within each repeat, so that the load
of a shared machine falls on both; each time is the minimum over the repeats, and the ratios
rothe/peer are taken from those minima, measured in the same run.

Cases (all P1 unless said otherwise):
- AMG, N = 44 (4N x N x N cubes, 1,075,275 dofs), 10 steps: rothe's regularized and original
  forms, pyamg smoothed aggregation (BSR, rigid-body modes), CG to 1e-8 (the original form's
  constraint condensed, so that its system is the peer's), against the peer's strong Dirichlet
  with CG + GAMG (rigid-body near-null space), rtol 1e-8; both start CG from 2u^{j-1} - u^{j-2}.
- LU, N = 16 (56,355 dofs), 10 steps: rothe regularized and original form (the original form
  condensed onto the free dofs, see rothe.eld.system) with SuperLU, against the peer's strong
  Dirichlet and its bordered KKT with MUMPS.
- P2 at N = 22 (1,075,275 dofs): rothe only (the peer's script builds P1 only).
- agreement, N = 16, 200 steps (T = 2): the reaction at the moved end, sum over the constrained
  dofs of the residual (peer, strong Dirichlet) against -int lambda ds (rothe), step by step.

Columns: mesh s (building the mesh: rothe generates it and its facets, the peer distributes the
given arrays), assembly s (function space, sparsity, M, K and the step matrix: rothe's A_II,
the peer's A with the Dirichlet rows), setup s (AMG hierarchy or LU factorization, including
pyamg's coarse-level factorization that it would otherwise do in the first step), 1st step s
(from the end of the setup to the end of step 1; rothe's includes the initial state with the
consistent initial acceleration, one CG with M), s/step (mean of steps 2..n), CG its/step,
total s, peak MB, reaction z at T.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
TAU = 0.01
PEER_PYTHON = "/usr/bin/python3"


# -- the rothe child -----------------------------------------------------------------------------


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


class _PeakSampler:
    """Resident memory sampled every 20 ms, with the maximum since the last checkpoint."""

    def __init__(self):
        self.peak = 0.0
        self._stop = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop:
            self.peak = max(self.peak, _rss_mb())
            time.sleep(0.02)

    def checkpoint(self) -> tuple[float, float]:
        now = _rss_mb()
        peak, self.peak = max(self.peak, now), now
        return round(now), round(peak)


def rothe_child(
    n: int,
    degree: int,
    form: str,
    solver: str,
    steps: int,
    data: str,
    rtol: float,
    save: str | None,
    tau: float = TAU,
) -> dict:
    """One rothe run in this process; returns the measurements (printed as one JSON line)."""
    import pyamg  # noqa: F401  (imported before the clocks start, as the peer imports dolfinx)
    import skfem  # noqa: F401

    from rothe.eld import (
        DirichletData,
        ELDProblem,
        ELDStepper,
        Material,
        Original,
        RayleighDamping,
        Regularized,
    )
    from rothe.eld.data import DATA_MODES
    from rothe.eld.examples import EndMotion
    from rothe.fem import mesh as meshes
    from rothe.io.trajectory import Trajectory
    from rothe.stepping.controllers import FixedStepController, Uniform
    from rothe.stepping.evolve import evolve

    sampler = _PeakSampler()
    memory = {}
    out = {"tool": "rothe", "n": n, "degree": degree, "form": form, "solver": solver, "data": data}
    t0 = time.perf_counter()
    mesh = meshes.box(4 * n, n, n, 4.0, 1.0, 1.0)
    out["mesh_s"] = time.perf_counter() - t0
    memory["mesh"] = sampler.checkpoint()

    t0 = time.perf_counter()
    motion = EndMotion(0.1, 0.5)
    problem = ELDProblem(
        mesh,
        Material.from_young(1000.0, 0.3, 1.0, dim=3),
        degree=degree,
        damping=RayleighDamping(0.0, 0.002),
        dirichlet={"left": DirichletData(motion.G, motion.G_dot, motion.G_ddot)},
        T=steps * tau,
        name="eld-beam",
    )
    t_problem = time.perf_counter() - t0
    memory["problem (space, M, K, constraint)"] = sampler.checkpoint()
    out["ndofs"] = problem.space.ndofs
    out["numba"] = problem.space.compiled_assembly

    stamps = []

    def observer(state, result):
        if result is None:  # the initial state (recorded with lambda(0)): not a step
            return
        stamps.append((time.perf_counter(), result.counters.get("krylov_iterations", 0)))

    t0 = time.perf_counter()
    stepper = ELDStepper(
        problem,
        form=Regularized() if form == "regularized" else Original(),
        control=Uniform(tau),
        data=DATA_MODES[data](),
        solver=solver,
        store_fields=False,
        observer=observer,
        linear_rtol=rtol,
    )
    t_stepper = time.perf_counter() - t0
    memory["stepper (step matrix, solver setup)"] = sampler.checkpoint()
    stats = stepper.system.solver.stats
    out["setup_s"] = stats.setup_seconds
    out["assembly_s"] = t_problem + (t_stepper - stats.setup_seconds)
    out["kind"] = stepper.system.kind
    ml = getattr(stepper.system.solver, "_ml", None)
    if ml is not None:
        out["amg_levels"] = len(ml.levels)
        out["amg_operator_complexity"] = float(ml.operator_complexity())

    # the uniform-step part of rothe.eld.prepare_eld_run, timed: the initial state (with the
    # consistent initial acceleration) counts into the first step
    traj = Trajectory()
    t0 = time.perf_counter()
    state = stepper.initial_state()
    stepper.record_initial(traj, state)
    evolve(
        stepper,
        FixedStepController.uniform(stepper.tau, stepper.n_steps),
        state,
        traj,
        tau_min=1e-300,
    )
    t_end = time.perf_counter()
    memory["time steps"] = sampler.checkpoint()
    times = [s for s, _ in stamps]
    out["first_step_s"] = times[0] - t0
    out["per_step_after_first_s"] = (times[-1] - times[0]) / max(len(times) - 1, 1)
    out["steps_s"] = t_end - t0
    out["n_steps"] = len(times)
    out["krylov_its_per_step"] = sum(c for _, c in stamps) / len(stamps)
    out["krylov_its"] = [c for _, c in stamps]
    out["total_s"] = out["mesh_s"] + t_problem + t_stepper + out["steps_s"]
    reaction = np.array(traj["reaction_left"])
    out["reaction_final"] = reaction[-1].tolist()
    out["balance_residual_max"] = float(np.max(np.abs(traj["balance_residual"])))
    out["memory_mb"] = {k: {"rss": v[0], "peak": v[1]} for k, v in memory.items()}
    if save:
        np.savez(save, t=np.arange(1, len(reaction) + 1) * tau, reaction=reaction)
    return out


# -- running children ----------------------------------------------------------------------------


def run_child(cmd: list[str], cwd: Path | None = None) -> dict:
    """Run a child process and return its JSON line plus ``peak_mb`` = its ru_maxrss.

    A leading ``ENV=VALUE`` word of ``cmd`` is set in the child's environment."""
    env = dict(os.environ)
    while cmd and "=" in cmd[0] and not cmd[0].startswith("/"):
        key, value = cmd[0].split("=", 1)
        env[key] = value
        cmd = cmd[1:]
    proc = subprocess.Popen(
        cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
    )
    out_chunks: list[str] = []
    err_chunks: list[str] = []

    def drain(stream, chunks):
        chunks.append(stream.read())

    # drain both pipes while os.wait4 waits for the child and returns its own rusage
    readers = [
        threading.Thread(target=drain, args=(proc.stdout, out_chunks)),
        threading.Thread(target=drain, args=(proc.stderr, err_chunks)),
    ]
    for r in readers:
        r.start()
    _, status, usage = os.wait4(proc.pid, 0)
    for r in readers:
        r.join()
    proc.returncode = os.waitstatus_to_exitcode(status)
    stdout, stderr = "".join(out_chunks), "".join(err_chunks)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{stderr[-3000:]}")
    line = [ln for ln in stdout.splitlines() if ln.startswith("{")][-1]
    row = json.loads(line)
    row["peak_mb"] = usage.ru_maxrss / 1024.0  # kilobytes on Linux
    return row


def rothe_cmd(
    n,
    degree=1,
    form="regularized",
    solver="amg",
    steps=10,
    data="points",
    rtol=1e-8,
    save=None,
    tau=TAU,
) -> list[str]:
    cmd = [
        "nice",
        sys.executable,
        str(Path(__file__).resolve()),
        "--child",
        "--n",
        str(n),
        "--degree",
        str(degree),
        "--form",
        form,
        "--solver",
        solver,
        "--steps",
        str(steps),
        "--data",
        data,
        "--rtol",
        str(rtol),
        "--tau",
        str(tau),
    ]
    if save:
        cmd += ["--save", str(save)]
    return cmd


def peer_cmd(peer_dir: Path, n, mode, steps=10, save=None) -> list[str]:
    cmd = [
        "nice",
        PEER_PYTHON,
        str(peer_dir / "eld_beam_dolfinx.py"),
        "--n",
        str(n),
        "--mode",
        mode,
        "--tau",
        str(TAU),
        "--steps",
        str(steps),
    ]
    if save:
        cmd += ["--save", str(save)]
    return cmd


def find_peer_dir(given: str | None) -> Path | None:
    candidates = [
        given,
        os.environ.get("ROTHE_PEER_ANCHORS"),
        REPO.parent / "shared/anchors",
        REPO.parent.parent / "shared/anchors",
        "/work/shared/anchors",
    ]
    for c in candidates:
        if c and (Path(c) / "eld_beam_dolfinx.py").is_file():
            return Path(c)
    return None


def peer_available() -> tuple[bool, str]:
    if shutil.which(PEER_PYTHON) is None:
        return False, f"{PEER_PYTHON} not found"
    probe = subprocess.run(
        [PEER_PYTHON, "-c", "import dolfinx; print(dolfinx.__version__)"],
        capture_output=True,
        text=True,
    )
    if probe.returncode != 0:
        return False, f"{PEER_PYTHON} -c 'import dolfinx' failed: " + (
            probe.stderr.strip().splitlines() or ["?"]
        )[-1]
    return True, "dolfinx " + probe.stdout.strip()


def export_mesh(peer_dir: Path, work: Path, n: int) -> None:
    if not (work / "meshes" / f"beam_n{n}.npz").is_file():
        subprocess.run(
            [sys.executable, str(peer_dir / "export_beam_mesh.py"), str(n)],
            cwd=work,
            check=True,
            capture_output=True,
        )


# -- the table -----------------------------------------------------------------------------------


def best(rows: list[dict]) -> dict:
    """Minimum over repeats of every timing; memory and its counts: the maximum."""
    out = dict(rows[-1])
    for key in (
        "mesh_s",
        "assembly_s",
        "setup_s",
        "first_step_s",
        "per_step_after_first_s",
        "total_s",
        "steps_s",
    ):
        if key in out:
            out[key] = min(r[key] for r in rows)
    out["peak_mb"] = max(r["peak_mb"] for r in rows)
    out["repeats"] = len(rows)
    return out


HEAD = (
    f"{'case':<22} {'tool':<26} {'dofs':>9} {'mesh s':>7} {'assembly s':>10} {'setup s':>8} "
    f"{'1st step s':>10} {'s/step':>7} {'CG its':>6} {'total s':>8} {'peak MB':>8} "
    f"{'reaction z at T':>16}"
)


def fmt_row(case: str, label: str, r: dict) -> str:
    its = r.get("krylov_its_per_step")
    its = f"{its:6.1f}" if its else f"{'-':>6}"
    return (
        f"{case:<22} {label:<26} {r['ndofs']:>9d} {r['mesh_s']:>7.2f} {r['assembly_s']:>10.2f} "
        f"{r['setup_s']:>8.2f} {r['first_step_s']:>10.2f} {r['per_step_after_first_s']:>7.2f} "
        f"{its} {r['total_s']:>8.1f} {r['peak_mb']:>8.0f} {r['reaction_final'][2]:>16.10f}"
    )


def fmt_ratio(case: str, label: str, a: dict, b: dict) -> str:
    def q(key):
        return a[key] / b[key] if b[key] > 0 else float("nan")

    return (
        f"{case:<22} {label:<26} {'':>9} {q('mesh_s'):>7.2f} {q('assembly_s'):>10.2f} "
        f"{q('setup_s'):>8.2f} {q('first_step_s'):>10.2f} {q('per_step_after_first_s'):>7.2f} "
        f"{'':>6} {q('total_s'):>8.2f} {a['peak_mb'] / b['peak_mb']:>8.2f}"
    )


def timing_case(case, rothe_runs, peer_runs, repeats, work, peer_dir, rows):
    """rothe_runs/peer_runs: [(label, cmd)]; alternate tools within every repeat."""
    results = {label: [] for label, _ in rothe_runs + peer_runs}
    for rep in range(repeats):
        order = rothe_runs + peer_runs if rep % 2 == 0 else peer_runs + rothe_runs
        for label, cmd in order:
            print(f"  [{case}] repeat {rep + 1}/{repeats}: {label}", file=sys.stderr, flush=True)
            results[label].append(run_child(cmd, cwd=work))
    bests = {label: best(rs) for label, rs in results.items()}
    for label, r in bests.items():
        rows.append({"case": case, "label": label, **r})
    return bests


WINDOWS = (
    ("t <= 0.05", lambda t: t <= 0.05 + 1e-9),
    ("0.05 < t <= 0.45", lambda t: (t > 0.05 + 1e-9) & (t <= 0.45 + 1e-9)),
    ("0.45 < t <= 0.6", lambda t: (t > 0.45 + 1e-9) & (t <= 0.6 + 1e-9)),
    ("t > 0.6", lambda t: t > 0.6 + 1e-9),
)


def _windows(t, diff, tau) -> list[float]:
    """max of diff over the time windows (G'' jumps at t = 0 and t = t_move = 0.5), and the
    time integral of diff divided by T."""
    out = [float(diff[w(t)].max()) if np.any(w(t)) else float("nan") for _, w in WINDOWS]
    return out + [float(np.sum(diff) * tau / t[-1])]


def agreement(work: Path, peer_dir: Path | None, n: int, steps: int) -> list[str]:
    """Reaction at the moved end, step by step, rothe's forms against the peer's strong
    Dirichlet (LU on both sides so that only the formulation differs), and the difference of
    the two rothe forms at tau and tau/2."""
    lines = []
    runs = {
        "regularized (data points)": rothe_cmd(
            n, solver="direct", steps=steps, save=work / "agree_reg.npz"
        ),
        "regularized (differenced)": rothe_cmd(
            n, solver="direct", steps=steps, data="differenced", save=work / "agree_diff.npz"
        ),
        "original": rothe_cmd(
            n, form="original", solver="direct", steps=steps, save=work / "agree_orig.npz"
        ),
    }
    for label, cmd in runs.items():
        print(f"  [agreement] rothe {label}", file=sys.stderr, flush=True)
        run_child(cmd, cwd=work)
    head = f"{'':<34}" + "".join(f"{name:>18}" for name, _ in WINDOWS) + f"{'int dt / T':>12}"
    if peer_dir is not None:
        print("  [agreement] peer direct", file=sys.stderr, flush=True)
        run_child(
            peer_cmd(peer_dir, n, "direct", steps=steps, save=work / "agree_peer.npz"), cwd=work
        )
        peer = np.load(work / "agree_peer.npz")
        Rp, t = peer["reaction"][:, 2], peer["t"]
        scale = float(np.max(np.abs(Rp)))
        lines.append(
            f"reaction z at the moved end, N = {n}, {steps} steps (T = {steps * TAU:g}), "
            f"LU on both sides; |R_rothe - R_peer| / max_t |R_peer| "
            f"(max_t |R_peer| = {scale:.4f}), max over"
        )
        lines.append(head)
        for label, name in (
            ("regularized (data points)", "agree_reg.npz"),
            ("regularized (differenced)", "agree_diff.npz"),
            ("original", "agree_orig.npz"),
        ):
            R = np.load(work / name)["reaction"][:, 2]
            parts = _windows(t, np.abs(R - Rp) / scale, TAU)
            lines.append(
                f"{'rothe ' + label:<34}"
                + "".join(f"{x:>18.2e}" for x in parts[:-1])
                + f"{parts[-1]:>12.2e}"
            )
    else:
        lines.append("(peer skipped: rothe's forms against each other only)")
        scale = float(np.max(np.abs(np.load(work / "agree_orig.npz")["reaction"][:, 2])))
    # both are first order in tau: their difference is O(tau) except at the steps where the
    # boundary acceleration G'' jumps (t = 0 and t = 0.5), where the differenced acceleration of
    # the original form / strong Dirichlet lags by half the jump for one step
    lines.append("rothe regularized - original, same norm, at tau and tau/2:")
    lines.append(head)
    rows = []
    for tau in (TAU, TAU / 2):
        k = int(round(steps * TAU / tau))
        files = {}
        for form in ("regularized", "original"):
            files[form] = work / f"halving_{form}_{k}.npz"
            print(f"  [agreement] rothe {form}, tau = {tau:g}", file=sys.stderr, flush=True)
            run_child(
                rothe_cmd(n, form=form, solver="direct", steps=k, save=files[form], tau=tau),
                cwd=work,
            )
        a, b = (np.load(files[f]) for f in ("regularized", "original"))
        rows.append(
            _windows(a["t"], np.abs(a["reaction"][:, 2] - b["reaction"][:, 2]) / scale, tau)
        )
        lines.append(
            f"{f'tau = {tau:g}':<34}"
            + "".join(f"{x:>18.2e}" for x in rows[-1][:-1])
            + f"{rows[-1][-1]:>12.2e}"
        )
    lines.append(
        f"{'ratio':<34}"
        + "".join(f"{x / y:>18.2f}" for x, y in zip(rows[0][:-1], rows[1][:-1], strict=True))
        + f"{rows[0][-1] / rows[1][-1]:>12.2f}"
    )
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, one repeat")
    parser.add_argument("--repeats", type=int, default=None, help="default 3 (quick: 1)")
    parser.add_argument("--n-amg", type=int, default=None, help="AMG case size N (default 44)")
    parser.add_argument("--n-lu", type=int, default=None, help="LU case size N (default 16)")
    parser.add_argument("--n-p2", type=int, default=None, help="P2 case size N (default 22)")
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--agreement-steps", type=int, default=None, help="default 200")
    parser.add_argument("--skip-p2", action="store_true")
    parser.add_argument("--skip-lu", action="store_true")
    parser.add_argument("--skip-amg", action="store_true")
    parser.add_argument("--skip-agreement", action="store_true")
    parser.add_argument("--no-peer", action="store_true")
    parser.add_argument(
        "--skip-original-amg", action="store_true", help="AMG case: rothe's regularized form only"
    )
    parser.add_argument(
        "--numpy-too",
        action="store_true",
        help="AMG case: also rothe with the numpy assembly (ROTHE_NO_NUMBA=1)",
    )
    parser.add_argument("--peer-dir", default=None, help="folder of eld_beam_dolfinx.py")
    parser.add_argument("--out", default=str(REPO / "rothe-out" / "eld_peers"))
    # child mode (one rothe run)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--n", type=int, default=8, help=argparse.SUPPRESS)
    parser.add_argument("--degree", type=int, default=1, help=argparse.SUPPRESS)
    parser.add_argument("--form", default="regularized", help=argparse.SUPPRESS)
    parser.add_argument("--solver", default="amg", help=argparse.SUPPRESS)
    parser.add_argument("--data", default="points", help=argparse.SUPPRESS)
    parser.add_argument("--rtol", type=float, default=1e-8, help=argparse.SUPPRESS)
    parser.add_argument("--save", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--tau", type=float, default=TAU, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(
            json.dumps(
                rothe_child(
                    args.n,
                    args.degree,
                    args.form,
                    args.solver,
                    args.steps,
                    args.data,
                    args.rtol,
                    args.save,
                    args.tau,
                )
            )
        )
        return 0

    quick = args.quick
    repeats = args.repeats or (1 if quick else 3)
    n_amg = args.n_amg or (8 if quick else 44)
    n_lu = args.n_lu or (6 if quick else 16)
    n_p2 = args.n_p2 or (4 if quick else 22)
    agree_steps = args.agreement_steps or (70 if quick else 200)
    work = Path(args.out).resolve()
    work.mkdir(parents=True, exist_ok=True)

    peer_dir = None
    if args.no_peer:
        print("peer: skipped (--no-peer)")
    else:
        ok, why = peer_available()
        peer_dir = find_peer_dir(args.peer_dir) if ok else None
        if not ok:
            print(f"peer: skipped ({why}); install with `apt-get install python3-dolfinx`")
        elif peer_dir is None:
            print("peer: skipped (eld_beam_dolfinx.py not found; pass --peer-dir)")
        else:
            print(f"peer: {why}, {peer_dir / 'eld_beam_dolfinx.py'}")
    sizes = [
        n
        for n, skip in ((n_amg, args.skip_amg), (n_lu, args.skip_lu), (n_lu, args.skip_agreement))
        if not skip
    ]
    if peer_dir is not None:
        for n in sorted(set(sizes)) + [4]:
            export_mesh(peer_dir, work, n)
        # warm-up: dolfinx compiles its forms on first use (cached afterwards), rothe's numba
        # kernels likewise; neither belongs in the timings
        print("  warm-up", file=sys.stderr, flush=True)
        for mode in ("gamg", "direct", "kkt"):
            run_child(peer_cmd(peer_dir, 4, mode, steps=2), cwd=work)
    run_child(rothe_cmd(4, steps=2), cwd=work)
    run_child(rothe_cmd(3, degree=2, steps=2), cwd=work)

    rows: list[dict] = []
    table: list[str] = [HEAD, "-" * len(HEAD)]
    ratio_lines: list[str] = []
    if not args.skip_amg:
        case = f"P1 N={n_amg} AMG"
        rothe_runs = [("rothe regularized, pyamg", rothe_cmd(n_amg, steps=args.steps))]
        if not args.skip_original_amg:
            # the peer's system (constraint condensed = strong Dirichlet): the reactions agree
            # to the CG tolerance, at the same cost as the regularized form
            rothe_runs.append(
                ("rothe original, pyamg", rothe_cmd(n_amg, form="original", steps=args.steps))
            )
        if args.numpy_too:
            rothe_runs.append(
                (
                    "rothe reg., pyamg, no numba",
                    ["ROTHE_NO_NUMBA=1"] + rothe_cmd(n_amg, steps=args.steps),
                )
            )
        peer_runs = (
            [("peer strong, GAMG", peer_cmd(peer_dir, n_amg, "gamg", args.steps))]
            if peer_dir
            else []
        )
        b = timing_case(case, rothe_runs, peer_runs, repeats, work, peer_dir, rows)
        for label, r in b.items():
            table.append(fmt_row(case, label, r))
        if peer_dir:
            ratio_lines.append(
                fmt_ratio(
                    case, "rothe / peer", b["rothe regularized, pyamg"], b["peer strong, GAMG"]
                )
            )
            if "rothe original, pyamg" in b:
                ratio_lines.append(
                    fmt_ratio(
                        case,
                        "rothe orig. / peer",
                        b["rothe original, pyamg"],
                        b["peer strong, GAMG"],
                    )
                )
    if not args.skip_lu:
        case = f"P1 N={n_lu} LU"
        rothe_runs = [
            ("rothe regularized, SuperLU", rothe_cmd(n_lu, solver="direct", steps=args.steps)),
            (
                "rothe original, SuperLU",
                rothe_cmd(n_lu, form="original", solver="direct", steps=args.steps),
            ),
        ]
        peer_runs = (
            [
                ("peer strong, MUMPS", peer_cmd(peer_dir, n_lu, "direct", args.steps)),
                ("peer KKT, MUMPS", peer_cmd(peer_dir, n_lu, "kkt", args.steps)),
            ]
            if peer_dir
            else []
        )
        b = timing_case(case, rothe_runs, peer_runs, repeats, work, peer_dir, rows)
        for label, r in b.items():
            table.append(fmt_row(case, label, r))
        if peer_dir:
            ratio_lines.append(
                fmt_ratio(
                    case,
                    "rothe reg. / peer strong",
                    b["rothe regularized, SuperLU"],
                    b["peer strong, MUMPS"],
                )
            )
            ratio_lines.append(
                fmt_ratio(
                    case,
                    "rothe orig. / peer KKT",
                    b["rothe original, SuperLU"],
                    b["peer KKT, MUMPS"],
                )
            )
    if not args.skip_p2:
        case = f"P2 N={n_p2} AMG"
        b = timing_case(
            case,
            [("rothe regularized, pyamg", rothe_cmd(n_p2, degree=2, steps=args.steps))],
            [],
            1,
            work,
            peer_dir,
            rows,
        )
        for label, r in b.items():
            table.append(fmt_row(case, label, r))
        table.append(f"{case:<22} peer: not run (its script builds P1 spaces only)")
    print()
    print(
        f"eld-beam, implicit Euler, tau = {TAU}, {args.steps} steps; times: min of "
        f"{repeats} (P2: 1); peak: max"
    )
    print("\n".join(table))
    if ratio_lines:
        print()
        print("ratios (same run)")
        print("\n".join(ratio_lines))
    for r in rows:
        if r["tool"] == "rothe" and "memory_mb" in r:
            print(
                f"\nrothe memory, {r['case']} ({r['label']}; RSS after / peak during, MB): "
                + "; ".join(f"{k} {v['rss']}/{v['peak']}" for k, v in r["memory_mb"].items())
            )
    if not args.skip_agreement:
        print()
        for line in agreement(work, peer_dir, n_lu, agree_steps):
            print(line)
    (work / "results.json").write_text(json.dumps(rows, indent=1, default=str))
    print(f"\nresults: {work / 'results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
