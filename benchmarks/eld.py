"""Elastodynamics (Altmann 2015): cost per step against one back-substitution, Newton iterations
with nonlinear damping, the 3D cantilever at more than a million unknowns, and (issue 9) adaptive
against uniform BDF2, numerical dissipation of Euler and BDF2, the cantilever's reactions, and the
BDF2 start.

    python benchmarks/eld.py                 # all parts (the 1.07M-dof beam takes ~3 minutes)
    python benchmarks/eld.py --part steps    # 2D/3D per-step costs only
    python benchmarks/eld.py --part beam --beam-n 44 --beam-steps 5
    python benchmarks/eld.py --part adaptive      # adaptive vs uniform BDF2 on a fast ramp
    python benchmarks/eld.py --part dissipation   # E(T)/E(0), Euler vs BDF2
    python benchmarks/eld.py --part reactions     # eld-beam: reactions, dissipation, meshes
    python benchmarks/eld.py --part start         # BDF2 starts: largest multiplier error
    python benchmarks/eld.py --quick              # small per-step costs and seconds per run
                                                  # (before/after comparisons, ~1 minute)

Part "adaptive": :func:`rothe.eld.ramp_problem` (unit square, P2, n = 4: the left side moved by
0.1 (1 + tanh((t - 0.5)/0.005))/2, Rayleigh b = 0.01, T = 1), regularized form. Reference: uniform
BDF2 with tau = 2^-14 on the same mesh. Error: the energy norm (rho|e_v|_M^2 + |e_u|_K^2)^{1/2}
of the difference to the reference, relative to the reference's largest energy norm, at T and
as the maximum over the run's own states (reference values between its steps by cubic Hermite
interpolation in time with its u and v). Uniform BDF2 with 2^5 ... 2^13 steps; adaptive BDF2 at
tol = 1e-3 ... 1e-6. "steps at equal error": the uniform step count with the same error,
interpolated log-log between the two uniform runs around it; the ratio counts every solve of the
adaptive run (accepted + rejected). Target (issue 9): ratio <= 1/3.

Part "dissipation": the manufactured problem's square, material and initial data u(0), u'(0), P1,
n = 16, no damping, no loads, `left` held at G = u(0) for all t: E(T)/E(0) at T = 1.

Part "steps": the manufactured solution (P2 on an n x n square) and a small cantilever (P1, LU),
linear Rayleigh damping and the nonlinear damping D v = b K v - d0 M v + d_nl N(v), both forms.
Per run: steps, factorizations, back-substitutions per step, Newton iterations per step, seconds
per step, the median time of one back-substitution with the *same* factorization (measured in
the same run, after it), and their ratio. Targets (issue 5): linear damping one factorization
for the whole run and time per step <= 3 back-substitutions; nonlinear damping <= 4 Newton
iterations per step on average.

Part "beam": the 3D cantilever (E = 1000, nu = 0.3, rho = 1, held end moved by G(t)) with
n cells across and 4n along (n = 44: 1,075,275 unknowns), regularized form, Rayleigh damping,
pyamg smoothed aggregation with the rigid-body modes as near-null space and CG to 1e-8.
Runs in a subprocess so that its peak memory (ru_maxrss) is its own. Target: under 8 GB.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import numpy as np

from rothe.eld import (
    BDF2,
    DirichletData,
    ELDProblem,
    ImplicitEuler,
    NoDamping,
    NonlinearDamping,
    Original,
    RayleighDamping,
    Regularized,
    beam_problem,
    mms_errors,
    mms_problem,
    ramp_problem,
    run_eld,
)
from rothe.eld.studies import fitted_rate
from rothe.fem import mesh as meshes
from rothe.stepping.controllers import Adaptive, Uniform

#: the command-line names of the forms and schemes of the tables
FORMS = {"regularized": Regularized(), "original": Original()}
SCHEMES = {"euler": ImplicitEuler(), "bdf2": BDF2()}


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def step_row(label, problem, form, tau, scheme="euler"):
    result = run_eld(
        problem, form=FORMS[form], control=Uniform(tau), scheme=SCHEMES[scheme], store_fields=False
    )
    traj = result.trajectory
    system = result.stepper.system
    n = system.size
    backsolve = system.solver.time_backsolve(n, repeats=30)
    st = traj.stats
    steps = st.accepted_steps
    per_step = st.wall_time_s / steps
    info = traj.meta["linear_solver"]
    return {
        "case": label if scheme == "euler" else f"{label}, BDF2",
        "form": form,
        "unknowns": n,
        "steps": steps,
        "factorizations": info["factorizations"],
        "backsolves_per_step": info["backsolves"] / steps,
        "newton_per_step": st.newton_iterations / steps,
        "seconds_per_step": per_step,
        "backsolve_seconds": backsolve,
        "ratio": per_step / backsolve,
    }


def part_steps(n2d: int, n3d: int, tau: float) -> list[dict]:
    rows = []
    rayleigh_2d, nonlinear_2d = RayleighDamping(0.1, 0.01), NonlinearDamping(0.01, 0.5, 1.0)
    rayleigh_3d, nonlinear_3d = RayleighDamping(0.0, 0.002), NonlinearDamping(0.002, 0.5, 1.0)
    cases = [
        (f"2D P2 n={n2d}, Rayleigh", lambda: mms_problem(n2d, 2, damping=rayleigh_2d)[0]),
        (f"2D P2 n={n2d}, nonlinear", lambda: mms_problem(n2d, 2, damping=nonlinear_2d)[0]),
        (f"3D P1 beam n={n3d}, Rayleigh", lambda: beam_problem(n3d, damping=rayleigh_3d, T=1.0)),
        (f"3D P1 beam n={n3d}, nonlinear", lambda: beam_problem(n3d, damping=nonlinear_3d, T=1.0)),
    ]
    for label, build in cases:
        problem = build()
        schemes = ("euler", "bdf2") if "Rayleigh" in label else ("euler",)
        for scheme in schemes:
            for form in ("regularized", "original"):
                rows.append(step_row(label, problem, form, tau, scheme))
                print_rows(rows[-1:], header=len(rows) == 1)
    return rows


def print_rows(rows, header=True):
    if header:
        head = (
            f"{'case':<36} {'form':<12} {'unknowns':>9} {'steps':>6} {'factor.':>7} "
            f"{'backsolves/step':>15} {'newton/step':>11} {'s/step':>9} {'s/backsolve':>11} "
            f"{'ratio':>6}"
        )
        print(head)
        print("-" * len(head))
    for r in rows:
        print(
            f"{r['case']:<36} {r['form']:<12} {r['unknowns']:>9d} {r['steps']:>6d} "
            f"{r['factorizations']:>7d} {r['backsolves_per_step']:>15.2f} "
            f"{r['newton_per_step']:>11.2f} {r['seconds_per_step']:>9.2e} "
            f"{r['backsolve_seconds']:>11.2e} {r['ratio']:>6.2f}",
            flush=True,
        )


def beam_child(n: int, steps: int) -> dict:
    """One beam run; returns the measurements (called in a subprocess)."""
    tau = 0.01
    t0 = time.perf_counter()
    problem = beam_problem(n, damping=RayleighDamping(0.0, 0.002), T=steps * tau)
    t_assembly = time.perf_counter() - t0
    t0 = time.perf_counter()
    result = run_eld(
        problem, control=Uniform(tau), solver="amg", store_fields=False, linear_rtol=1e-8
    )
    traj = result.trajectory
    t_total = time.perf_counter() - t0
    info = traj.meta["linear_solver"]
    st = traj.stats
    return {
        "n": n,
        "unknowns": problem.space.ndofs,
        "free_unknowns": int(result.stepper.system.I.size),
        "tetrahedra": int(problem.space.mesh.t.shape[1]),
        "steps": st.accepted_steps,
        "assembly_seconds": t_assembly,
        "amg_setup_seconds": info["setup_seconds"],
        "run_seconds": t_total,
        "seconds_per_step": st.wall_time_s / st.accepted_steps,
        "cg_iterations_per_step": info["krylov_iterations"] / st.accepted_steps,
        "peak_memory_mb": peak_mb(),
        "balance_residual_max": float(abs(traj["balance_residual"]).max()),
        "reaction_left_final": traj["reaction_left"][-1].tolist(),
    }


def part_beam(n: int, steps: int) -> dict:
    cmd = [sys.executable, __file__, "--beam-child", str(n), str(steps)]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    row = json.loads(out.strip().splitlines()[-1])
    head = (
        f"{'unknowns':>10} {'tets':>9} {'steps':>5} {'assembly s':>10} {'AMG setup s':>11} "
        f"{'s/step':>8} {'CG its/step':>11} {'peak MB':>8}"
    )
    print(head)
    print("-" * len(head))
    print(
        f"{row['unknowns']:>10d} {row['tetrahedra']:>9d} {row['steps']:>5d} "
        f"{row['assembly_seconds']:>10.1f} {row['amg_setup_seconds']:>11.1f} "
        f"{row['seconds_per_step']:>8.2f} {row['cg_iterations_per_step']:>11.1f} "
        f"{row['peak_memory_mb']:>8.0f}"
    )
    print(
        f"energy balance residual max {row['balance_residual_max']:.2e}; reaction at the held "
        f"end at t = {steps * 0.01:g}: {row['reaction_left_final']}"
    )
    return row


# -- adaptive against uniform BDF2 ----------------------------------------------------------------


class _Reference:
    """A fine uniform run: errors of other runs at their own times (cubic Hermite in time)."""

    def __init__(self, problem, k: int):
        self.problem = problem
        self.h = 2.0**-k
        t0 = time.perf_counter()
        ref = run_eld(problem, control=Uniform(self.h), scheme=BDF2()).trajectory
        self.seconds = time.perf_counter() - t0
        self.t, self.u, self.v = ref["kept_t"], ref["u"], ref["v"]
        self.scale = max(self.norm(u, v) for u, v in zip(self.u, self.v, strict=True))

    def norm(self, u, v):
        p = self.problem
        return float(np.sqrt(p.material.rho * v @ (p.M @ v) + u @ (p.K @ u)))

    def at(self, t):
        h = self.h
        k = min(int(np.floor(t / h)), len(self.t) - 2)
        s = (t - self.t[k]) / h
        if s == 0.0:
            return self.u[k], self.v[k]
        u0, u1, v0, v1 = self.u[k], self.u[k + 1], self.v[k], self.v[k + 1]
        h00, h10, h01, h11 = (
            2 * s**3 - 3 * s**2 + 1,
            s**3 - 2 * s**2 + s,
            -2 * s**3 + 3 * s**2,
            s**3 - s**2,
        )
        u = h00 * u0 + h10 * h * v0 + h01 * u1 + h11 * h * v1
        d00, d10, d01, d11 = (
            (6 * s**2 - 6 * s) / h,
            3 * s**2 - 4 * s + 1,
            (-6 * s**2 + 6 * s) / h,
            3 * s**2 - 2 * s,
        )
        v = d00 * u0 + d10 * v0 + d01 * u1 + d11 * v1
        return u, v

    def errors(self, traj):
        errs = []
        for t, u, v in zip(traj["kept_t"], traj["u"], traj["v"], strict=True):
            ur, vr = self.at(t)
            errs.append(self.norm(u - ur, v - vr) / self.scale)
        return errs[-1], max(errs)


def _equal_error_steps(err, uniform):
    """Uniform steps with error err, interpolated log-log between the uniform runs around it."""
    pts = sorted((r["error"], r["steps"]) for r in uniform)
    for (e_lo, n_lo), (e_hi, n_hi) in zip(pts, pts[1:], strict=False):
        if e_lo <= err <= e_hi:
            w = (np.log(err) - np.log(e_hi)) / (np.log(e_lo) - np.log(e_hi))
            return float(np.exp(np.log(n_hi) + w * (np.log(n_lo) - np.log(n_hi))))
    return None


def part_adaptive(n: int, kref: int, tols) -> dict:
    problem = ramp_problem(n, 2)
    ref = _Reference(problem, kref)
    print(
        f"ramp problem, P2, n = {n} ({problem.space.ndofs} dofs), regularized form; reference: "
        f"uniform BDF2 with tau = 2^-{kref} ({ref.seconds:.1f} s)"
    )
    rows = []
    for k in range(5, 14):
        t0 = time.perf_counter()
        traj = run_eld(problem, control=Uniform(2.0**-k), scheme=BDF2()).trajectory
        sec = time.perf_counter() - t0
        eT, emax = ref.errors(traj)
        rows.append(
            {
                "run": f"uniform 2^-{k}",
                "accepted": traj.stats.accepted_steps,
                "rejected": 0,
                "solves": traj.stats.inner_solves,
                "error_T": eT,
                "error_max": emax,
                "seconds": sec,
                "tau_min": 2.0**-k,
                "tau_max": 2.0**-k,
            }
        )
    for tol in tols:
        t0 = time.perf_counter()
        traj = run_eld(problem, scheme=BDF2(), control=Adaptive(tol, tau=0.01)).trajectory
        sec = time.perf_counter() - t0
        eT, emax = ref.errors(traj)
        rows.append(
            {
                "run": f"adaptive tol={tol:g}",
                "accepted": traj.stats.accepted_steps,
                "rejected": traj.stats.rejected_steps,
                "solves": traj.stats.inner_solves,
                "error_T": eT,
                "error_max": emax,
                "seconds": sec,
                "tau_min": float(traj["tau"].min()),
                "tau_max": float(traj["tau"].max()),
            }
        )
    uni = [r for r in rows if r["run"].startswith("uniform")]
    head = (
        f"{'run':<22} {'accepted':>8} {'rejected':>8} {'solves':>7} {'error at T':>11} "
        f"{'max error':>10} {'tau min':>9} {'tau max':>9} {'seconds':>8} "
        f"{'ratio (max)':>11} {'ratio (T)':>10} {'s-ratio':>10}"
    )
    print(head)
    print("-" * len(head))
    ratios_max, ratios_T = [], []
    for r in rows:
        extra = ""
        if r["run"].startswith("adaptive"):
            n_max = _equal_error_steps(
                r["error_max"], [dict(error=u["error_max"], steps=u["solves"]) for u in uni]
            )
            n_T = _equal_error_steps(
                r["error_T"], [dict(error=u["error_T"], steps=u["solves"]) for u in uni]
            )
            s_max = _equal_error_steps(
                r["error_max"], [dict(error=u["error_max"], steps=u["seconds"]) for u in uni]
            )
            r["ratio_max"] = None if n_max is None else r["solves"] / n_max
            r["ratio_T"] = None if n_T is None else r["solves"] / n_T
            r["seconds_ratio_max"] = None if s_max is None else r["seconds"] / s_max
            ratios_max.append(r["ratio_max"])
            ratios_T.append(r["ratio_T"])
            extra = "".join(
                " " + (f"{x:>10.3f}" if x is not None else f"{'outside':>10}")
                for x in (r["ratio_max"], r["ratio_T"], r["seconds_ratio_max"])
            )
        print(
            f"{r['run']:<22} {r['accepted']:>8d} {r['rejected']:>8d} {r['solves']:>7d} "
            f"{r['error_T']:>11.3e} {r['error_max']:>10.3e} {r['tau_min']:>9.2e} "
            f"{r['tau_max']:>9.2e} {r['seconds']:>8.2f}{extra}",
            flush=True,
        )
    good = [x for x in ratios_max if x is not None]
    goodT = [x for x in ratios_T if x is not None]
    print(
        "ratio = solves of the adaptive run / uniform steps with the same error (log-log "
        "interpolated between uniform runs); s-ratio = the same for seconds at equal max error"
    )
    if good:
        print(
            f"steps ratio adaptive/uniform at equal max-over-time error: {min(good):.3f} ... "
            f"{max(good):.3f} (target <= 0.333)"
        )
    if goodT:
        print(
            f"steps ratio adaptive/uniform at equal error at T: {min(goodT):.3f} ... "
            f"{max(goodT):.3f} (target <= 0.333)"
        )
    return {"rows": rows}


# -- numerical dissipation ------------------------------------------------------------------------


def part_dissipation(taus=(0.1, 0.01, 0.001)) -> list[dict]:
    _, exact = mms_problem(2, 1)

    def held(t, x):
        return exact.u(0.0, x)

    def zero(t, x):
        return np.zeros_like(x)

    problem = ELDProblem(
        meshes.unit_square(16, named=True),
        exact.material,
        degree=1,
        damping=NoDamping(),
        dirichlet={"left": DirichletData(held, zero, zero)},
        u0=lambda x: exact.u(0.0, x),
        v0=lambda x: exact.u_dot(0.0, x),
        T=1.0,
    )
    print(
        f"undamped, no loads, constant G (left held at u(0)), P1, n = 16 "
        f"({problem.space.ndofs} dofs), regularized form; energy left at T = 1"
    )
    head = (
        f"{'tau':>7} {'Euler E(T)/E(0)':>16} {'BDF2 E(T)/E(0)':>15} {'BDF2 N_G/E(0)':>14} "
        f"{'BDF2 C^n-C^0':>13} {'balance residual':>17}"
    )
    print(head)
    print("-" * len(head))
    rows = []
    for tau in taus:
        e = run_eld(problem, control=Uniform(tau), store_fields=False).trajectory
        b = run_eld(problem, control=Uniform(tau), scheme=BDF2(), store_fields=False).trajectory
        E0 = b["energy"][0]
        row = {
            "tau": tau,
            "euler": e["energy"][-1] / e["energy"][0],
            "bdf2": b["energy"][-1] / E0,
            "bdf2_NG": b["numerical_dissipation_G"][-1] / E0,
            "bdf2_C": (
                b["numerical_dissipation"][-1]
                - b["numerical_dissipation_G"][-1]
                - b["step_change"][-1]
            )
            / E0,
            "residual": max(
                np.abs(e["balance_residual"]).max(), np.abs(b["balance_residual"]).max()
            )
            / E0,
        }
        rows.append(row)
        print(
            f"{tau:>7g} {row['euler']:>16.4f} {row['bdf2']:>15.4f} {row['bdf2_NG']:>14.3e} "
            f"{row['bdf2_C']:>13.3e} {row['residual']:>17.1e}",
            flush=True,
        )
    return rows


# -- the cantilever's reactions -------------------------------------------------------------------


def part_reactions() -> list[dict]:
    print(
        "eld-beam (E = 1000, nu = 0.3, rho = 1, Rayleigh b = 0.002, T = 2, motion purely in z), "
        "regularized form"
    )
    head = (
        f"{'mesh':<9} {'dofs':>6} {'scheme':<6} {'tau':>6} {'max|R_x|':>9} {'max|R_y|':>9} "
        f"{'max|R_z|':>9} {'sideways/R_z':>13} {'R_z(T)':>8} {'work in':>8} {'num. diss.':>10} "
        f"{'phys. diss.':>11} {'seconds':>8}"
    )
    print(head)
    print("-" * len(head))
    rows = []
    for n, deg, scheme, tau in [
        (3, 1, "euler", 0.01),
        (3, 2, "euler", 0.01),
        (3, 2, "euler", 0.0025),
        (3, 2, "bdf2", 0.01),
        (3, 2, "bdf2", 0.005),
        (4, 2, "bdf2", 0.01),
    ]:
        problem = beam_problem(n, damping=RayleighDamping(0.0, 0.002), degree=deg)
        t0 = time.perf_counter()
        traj = run_eld(
            problem, control=Uniform(tau), scheme=SCHEMES[scheme], store_fields=False
        ).trajectory
        sec = time.perf_counter() - t0
        R = traj["reaction_left"]
        peak = np.abs(R).max(axis=0)
        row = {
            "mesh": f"P{deg} n={n}",
            "dofs": problem.space.ndofs,
            "scheme": scheme,
            "tau": tau,
            "peak": peak.tolist(),
            "sideways": (peak[:2] / peak[2]).tolist(),
            "Rz_T": float(R[-1, 2]),
            "work": float(traj["work_reaction"][-1]),
            "numerical": float(traj["numerical_dissipation"][-1]),
            "physical": float(traj["dissipated"][-1]),
            "seconds": sec,
        }
        rows.append(row)
        side = f"{100 * row['sideways'][0]:.1f}/{100 * row['sideways'][1]:.1f} %"
        print(
            f"{row['mesh']:<9} {row['dofs']:>6d} {scheme:<6} {tau:>6g} {peak[0]:>9.4f} "
            f"{peak[1]:>9.4f} {peak[2]:>9.4f} {side:>13} {row['Rz_T']:>8.4f} {row['work']:>8.4f} "
            f"{row['numerical']:>10.4f} {row['physical']:>11.4f} {sec:>8.2f}",
            flush=True,
        )
    return rows


# -- quick: the same code paths at small sizes, for before/after comparisons ------------------


def part_quick(repeats: int = 3) -> list[dict]:
    """Seconds of a few small runs (the best of ``repeats``, wall clock and CPU time of this
    process: on a shared machine the CPU time is the steadier of the two): uniform Euler and
    BDF2 in both forms, nonlinear damping, adaptive steps, and space adaptivity on the pulse
    (the adapt step: estimate, mark, refine, rebuild, transfer)."""
    from rothe.eld.examples import pulse_problem
    from rothe.fem.adapt import SpaceAdaptivity

    mms = mms_problem(16, 2, damping=RayleighDamping(0.1, 0.01))[0]
    mms_nl = mms_problem(16, 2)[0]
    beam = beam_problem(4, damping=RayleighDamping(0.0, 0.002), T=0.5)
    ramp = ramp_problem(4, 2)
    space = SpaceAdaptivity(
        space_tol=1e-3, refine_fraction=0.5, coarsen_fraction=0.05, max_dofs=3000, adapt_every=1
    )
    cases = [
        ("2D P2 n=16 Rayleigh, Euler, regularized", lambda: run_eld(mms, control=Uniform(0.01))),
        (
            "2D P2 n=16 Rayleigh, BDF2, original",
            lambda: run_eld(mms, form=Original(), control=Uniform(0.01), scheme=BDF2()),
        ),
        (
            "2D P2 n=16 nonlinear, Euler, regularized",
            lambda: run_eld(mms_nl, control=Uniform(0.01)),
        ),
        (
            "3D P2 beam n=4, BDF2, regularized",
            lambda: run_eld(beam, control=Uniform(0.01), scheme=BDF2(), store_fields=False),
        ),
        (
            "ramp P2 n=4, adaptive BDF2 tol 1e-5",
            lambda: run_eld(ramp, scheme=BDF2(), control=Adaptive(1e-5, tau=0.01)),
        ),
        (
            "pulse P2 n=4, T=0.2, adapt-space",
            lambda: run_eld(
                pulse_problem(4, T=0.2),
                control=Uniform(0.01),
                scheme=BDF2(),
                keep_every=10,
                adapt=space,
            ),
        ),
    ]
    head = f"{'case':<44} {'steps':>6} {'solves':>7} {'seconds':>8} {'s/step':>9} {'CPU s':>8}"
    print(head)
    print("-" * len(head))
    rows = []
    for label, run in cases:
        best, cpu, result = np.inf, np.inf, None
        for _ in range(repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            result = run()
            best = min(best, time.perf_counter() - t0)
            cpu = min(cpu, time.process_time() - c0)
        st = result.statistics
        rows.append(
            {
                "case": label,
                "steps": st.accepted_steps,
                "solves": st.inner_solves,
                "seconds": best,
                "cpu_seconds": cpu,
            }
        )
        print(
            f"{label:<44} {st.accepted_steps:>6d} {st.inner_solves:>7d} {best:>8.3f} "
            f"{best / st.accepted_steps:>9.2e} {cpu:>8.3f}",
            flush=True,
        )
    print(
        f"{'total':<44} {'':>6} {'':>7} {sum(r['seconds'] for r in rows):>8.3f} {'':>9} "
        f"{sum(r['cpu_seconds'] for r in rows):>8.3f}"
    )
    return rows


# -- the BDF2 start -------------------------------------------------------------------------------


def part_start(taus=(0.0025, 0.00125, 0.000625, 0.0003125)) -> dict:
    problem, exact = mms_problem(2, 2, T=0.05)
    print(
        "largest multiplier error over all steps, original form, BDF2, manufactured solution "
        "(P2, n = 2), T = 0.05 (the start dominates)"
    )
    head = f"{'start':<10}" + "".join(f" {f'tau={t:g}':>13}" for t in taus) + f" {'order':>7}"
    print(head)
    print("-" * len(head))
    out = {}
    for start in ("taylor", "taylor2", "euler"):
        errs = []
        for tau in taus:
            result = run_eld(
                problem, form=Original(), control=Uniform(tau), scheme=BDF2(start=start)
            )
            errs.append(mms_errors(exact, result)["error_lam_l2_max"])
        out[start] = errs
        rate = fitted_rate(taus, errs)
        print(f"{start:<10}" + "".join(f" {e:>13.3e}" for e in errs) + f" {rate:>7.2f}", flush=True)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--part",
        default="all",
        choices=("all", "steps", "beam", "adaptive", "dissipation", "reactions", "start"),
    )
    parser.add_argument("--ramp-n", type=int, default=4, help="ramp problem cells (default 4)")
    parser.add_argument(
        "--ramp-ref", type=int, default=14, help="reference tau = 2^-k (default 14)"
    )
    parser.add_argument("--n2d", type=int, default=64, help="2D cells per side (default 64)")
    parser.add_argument("--n3d", type=int, default=8, help="beam cells across for LU (default 8)")
    parser.add_argument("--tau", type=float, default=0.01)
    parser.add_argument("--beam-n", type=int, default=44, help="beam cells across (default 44)")
    parser.add_argument("--beam-steps", type=int, default=5)
    parser.add_argument("--beam-child", nargs=2, type=int, help=argparse.SUPPRESS)
    parser.add_argument(
        "--quick",
        action="store_true",
        help="only a few small runs, best of 3 (before/after comparisons)",
    )
    args = parser.parse_args(argv)
    if args.beam_child:
        print(json.dumps(beam_child(*args.beam_child)))
        return 0
    if args.quick:
        print("Seconds of small runs (best of 3)")
        part_quick()
        return 0
    if args.part in ("all", "steps"):
        print("Per-step cost against one back-substitution with the same factorization")
        part_steps(args.n2d, args.n3d, args.tau)
        print()
    if args.part in ("all", "adaptive"):
        print("Adaptive against uniform BDF2 on a fast ramp of G (issue 9)")
        part_adaptive(args.ramp_n, args.ramp_ref, (1e-3, 1e-4, 1e-5, 1e-6))
        print()
    if args.part in ("all", "dissipation"):
        print("Numerical dissipation of Euler and BDF2 (issue 9)")
        part_dissipation()
        print()
    if args.part in ("all", "reactions"):
        print("eld-beam: reactions and dissipation by mesh and scheme (issue 9)")
        part_reactions()
        print()
    if args.part in ("all", "start"):
        print("The BDF2 start (SPEC 7)")
        part_start()
        print()
    if args.part in ("all", "beam"):
        print("3D cantilever, regularized form, pyamg SA + rigid-body modes, CG to 1e-8")
        part_beam(args.beam_n, args.beam_steps)
    return 0


if __name__ == "__main__":
    sys.exit(main())
