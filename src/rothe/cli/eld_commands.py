"""CLI commands for elastodynamics: ``rothe run eld-mms|eld-beam``,
``rothe study eld-convergence|eld-perturbation``.

Outputs follow the foundation layout: ``summary.json``, ``trajectory.npz`` (runs), a table
(studies), PNG figures unless ``--no-plots``, XDMF for the beam. Bad input is one line and exit
status 2 (raised as RotheInputError by the library where the value enters, e.g. tau >= rho/d0 by
the stepper before the first step); a run that fails midway writes what it has and exits 1.
"""

from __future__ import annotations

import shutil
import sys

import numpy as np

from ..errors import check_choice, check_int, check_positive, fail
from .common import (
    add_output_options,
    output_dir,
    parse_float,
    parse_float_list,
    peak_memory_mb,
    print_summary,
    progress_of,
    write_summary,
    write_table,
)
from .registry import command
from .session import RunSession, add_run_options

FORMS = ("regularized", "original")


def _damping_options(parser, default_b: float = 0.01) -> None:
    parser.add_argument("--damping", default="nonlinear",
                        help="nonlinear | rayleigh | none (default nonlinear: "
                             "D v = b K v - d0 M v + d_nl v/sqrt(1+|v|^2/v_ref^2))")
    parser.add_argument("--rho", type=parse_float("--rho"), default=1.0, help="density (default 1)")
    parser.add_argument("--d0", type=parse_float("--d0"), default=0.5,
                        help="L2 anti-damping constant d0 of the nonlinear damping (default 0.5)")
    parser.add_argument("--d-nl", type=parse_float("--d-nl"), default=1.0,
                        help="coefficient d_nl of the saturating part (default 1)")
    parser.add_argument("--v-ref", type=parse_float("--v-ref"), default=1.0,
                        help="saturation velocity v_ref (default 1)")
    parser.add_argument("--b", type=parse_float("--b"), default=default_b,
                        help=f"stiffness-proportional coefficient b (default {default_b:g})")
    parser.add_argument("--a", type=parse_float("--a"), default=0.0,
                        help="mass-proportional coefficient a of Rayleigh damping (default 0)")


def _make_damping(args):
    from ..eld.damping import DAMPINGS, make_damping

    kind = check_choice("--damping", args.damping, DAMPINGS)
    return make_damping(kind, a=args.a, b=args.b, d0=args.d0, d_nl=args.d_nl, v_ref=args.v_ref)


def _mms_options(parser) -> None:
    parser.add_argument("--n", type=int, default=8,
                        help="cells per side of the unit square (default 8)")
    parser.add_argument("--degree", type=int, default=2, help="1 or 2 (default 2: exact in space)")
    parser.add_argument("--lam", type=parse_float("--lam"), default=2.0,
                        help="Lamé lambda (default 2)")
    parser.add_argument("--mu", type=parse_float("--mu"), default=1.0, help="Lamé mu (default 1)")
    parser.add_argument("--T", type=parse_float("--T"), default=1.0, help="end time (default 1)")
    parser.add_argument("--data", default="points",
                        help="points | means | differenced: how F, G, G', G'' enter (3.3)/(3.1)")
    parser.add_argument("--lifting", default="nodal",
                        help="right inverse of B for the regularized form: nodal | harmonic")
    _damping_options(parser)


def energy_summary(traj) -> dict:
    return {
        "energy_initial": float(traj["energy"][0]),
        "energy_final": float(traj["energy"][-1]),
        "work_loads": float(traj["work"][-1]),
        "work_support": float(traj["work_reaction"][-1]),
        "dissipated_physical": float(traj["dissipated"][-1]),
        "dissipated_numerical": float(traj["numerical_dissipation"][-1]),
        "data_mismatch": float(traj["data_mismatch"][-1]),
        "balance_residual_max": float(np.max(np.abs(traj["balance_residual"]))),
    }


def _write_run(args, out, traj, summary, label, plots: bool = True) -> None:
    """What every ELD run writes into ``out`` (its staging directory): trajectory.npz, the
    energy and reaction figures (completed runs), summary.json last."""
    traj.save_npz(out / "trajectory.npz")
    if plots and not args.no_plots:
        from ..plotting.eld import plot_energy_balance, plot_reactions

        plot_energy_balance(traj, out / "fig_energy.png", title=label)
        plot_reactions(traj, out / "fig_reaction.png", title=label)
    write_summary(out, summary)


def _print_run(args, results, name, summary, keys) -> None:
    if not args.quiet:
        print(f"rothe run {name}: wrote {results}/")
        print_summary(summary, keys)
        print(format_energy_balance(summary))


def _already_completed(session) -> bool:
    if session.already_completed:
        print(f"rothe: {session.out}: the run already completed; its results are there",
              file=sys.stderr)
        return True
    return False


def format_energy_balance(e: dict) -> str:
    """The discrete energy identity at T, term by term (see rothe.eld.schemes)."""
    lhs = e["energy_final"] - e["energy_initial"]
    rows = (
        ("E(T) - E(0)", lhs),
        ("  = work of the loads", e["work_loads"]),
        ("  + work of the support", e["work_support"]),
        ("  - physical dissipation", e["dissipated_physical"]),
        ("  - numerical dissipation", e["dissipated_numerical"]),
        ("  - data mismatch", e["data_mismatch"]),
    )
    lines = ["energy balance of the scheme (E = kinetic + elastic):"]
    lines += [f"  {name:<26} {value:>14.6g}" for name, value in rows]
    lines.append(f"  {'max |residual| per step':<26} {e['balance_residual_max']:>14.2e}")
    return "\n".join(lines)


def run_summary(traj, example: str) -> dict:
    st = traj.stats
    meta = traj.meta
    solver = meta.get("linear_solver", {})
    summary = {
        "example": example,
        "form": meta.get("form"),
        "tau": meta.get("tau"),
        "data": meta.get("data"),
        "lifting": meta.get("lifting"),
        "n_steps": meta.get("n_steps"),
        "ndofs": meta["problem"]["ndofs"],
        "constrained_dofs": meta["problem"]["constrained_dofs"],
        "damping": meta["problem"]["damping"],
        "step_bound_rho_over_d0": meta.get("step_bound"),
        "accepted_steps": st.accepted_steps,
        "rejected_steps": st.rejected_steps,
        "inner_solves": st.inner_solves,
        "newton_iterations": st.newton_iterations,
        "newton_per_step": st.newton_iterations / max(st.accepted_steps, 1),
        "linear_solver": solver.get("kind"),
        "linear_factorizations": solver.get("factorizations", st.linear_factorizations),
        "backsolves": solver.get("backsolves", st.linear_solves),
        "krylov_iterations": solver.get("krylov_iterations", st.krylov_iterations),
        "t_final": float(traj["t"][-1]),
        "wall_time_s": st.wall_time_s,
        "peak_memory_mb": peak_memory_mb(),
        "status": "completed",
    }
    if st.accepted_steps:
        for key in traj.keys():
            if key.startswith("reaction_"):
                summary[f"{key}_final"] = traj[key][-1].tolist()
    summary.update(energy_summary(traj))
    return summary


MMS_KEYS = ("example", "form", "tau", "n_steps", "ndofs", "newton_per_step", "error_u_l2",
            "error_u_h1", "error_v_l2", "error_v_h1", "error_lam_l2", "wall_time_s")


@command("run", "eld-mms")
class RunEldMMS:
    help = ("Manufactured solution on the unit square: time-dependent Dirichlet data by a "
            "multiplier, traction, nonlinear damping (Altmann 2015, scheme (3.4))")
    name = "eld-mms"

    def configure(self, parser) -> None:
        parser.add_argument("--form", default="regularized", help="regularized | original")
        parser.add_argument("--tau", type=parse_float("--tau"), default=0.01,
                            help="time step; must divide T (default 0.01)")
        parser.add_argument("--dirichlet", default="left",
                            help="comma-separated Dirichlet parts (default left); "
                                 "traction on the rest")
        parser.add_argument("--start", default="exact",
                            help="exact | rest: initial data u(0), u'(0) of the solution, or zero "
                                 "(inconsistent with G(0): refused, Remark 2.2)")
        _mms_options(parser)
        add_output_options(parser, self.name)
        add_run_options(parser)

    def execute(self, args) -> int:
        from ..eld.examples import mms_errors, mms_problem
        from ..eld.schemes import run_eld

        form = check_choice("--form", args.form, FORMS)
        tau = check_positive("--tau", args.tau)
        n = check_int("--n", args.n, minimum=1)
        parts = tuple(p.strip() for p in args.dirichlet.split(",") if p.strip())
        if not parts:
            raise fail("--dirichlet", args.dirichlet, "must name at least one boundary part")
        damping = _make_damping(args)
        problem, exact = mms_problem(n, args.degree, damping=damping, rho=args.rho, lam=args.lam,
                                     mu=args.mu, T=args.T, dirichlet=parts, start=args.start)
        session = RunSession(args, self.name)
        with session:
            if _already_completed(session):
                return 0
            outcome = session.run(lambda **kw: run_eld(problem, form, tau, data=args.data,
                                                       lifting=args.lifting, **kw))
            results = session.results_dir(outcome.status)
            traj = outcome.result
            if traj is not None:
                with session.outputs(outcome.status) as stage:
                    summary = run_summary(traj, self.name)
                    summary.update(n=n, degree=args.degree, dirichlet=list(parts))
                    if outcome.status == "completed":
                        summary.update(mms_errors(problem, exact, traj))
                    session.annotate(summary, outcome)
                    _write_run(args, stage, traj, summary, f"eld-mms, {form}, tau={tau:g}",
                               plots=outcome.status == "completed")
            code = session.finish(outcome, results)
        if outcome.status == "completed":
            _print_run(args, results, self.name, summary, MMS_KEYS)
        return code


@command("run", "eld-beam")
class RunEldBeam:
    help = ("3D cantilever (E=1000, nu=0.3, rho=1): one end held and moved by G(t), the other "
            "free; the multiplier is the reaction at the held end (XDMF for ParaView)")
    name = "eld-beam"

    def configure(self, parser) -> None:
        parser.add_argument("--form", default="regularized", help="regularized | original")
        parser.add_argument("--n", type=int, default=3,
                            help="cells across the unit cross-section (default 3); "
                                 "round(length*n) along the beam")
        parser.add_argument("--length", type=parse_float("--length"), default=4.0,
                            help="beam length (default 4)")
        parser.add_argument("--degree", type=int, default=1, help="1 or 2 (default 1)")
        parser.add_argument("--tau", type=parse_float("--tau"), default=0.01,
                            help="time step (default 0.01)")
        parser.add_argument("--T", type=parse_float("--T"), default=2.0,
                            help="end time (default 2)")
        parser.add_argument("--E", type=parse_float("--E"), default=1000.0, help="Young's modulus")
        parser.add_argument("--nu", type=parse_float("--nu"), default=0.3, help="Poisson ratio")
        parser.add_argument("--amplitude", type=parse_float("--amplitude"), default=0.1,
                            help="end displacement (z) of the held end's motion (default 0.1)")
        parser.add_argument("--t-move", type=parse_float("--t-move"), default=0.5,
                            help="duration of the motion; held still afterwards (default 0.5)")
        parser.add_argument("--solver", default="auto", help="auto | direct | amg")
        parser.add_argument("--save-every", type=int, default=5,
                            help="write every k-th step to XDMF (default 5)")
        _damping_options(parser, default_b=0.002)
        parser.set_defaults(damping="rayleigh")
        add_output_options(parser, self.name)
        add_run_options(parser)

    def execute(self, args) -> int:
        from ..eld.examples import beam_problem
        from ..eld.schemes import run_eld
        from ..io.eld_output import EldXdmfWriter

        form = check_choice("--form", args.form, FORMS)
        tau = check_positive("--tau", args.tau)
        n = check_int("--n", args.n, minimum=1)
        every = check_int("--save-every", args.save_every, minimum=1)
        damping = _make_damping(args)
        problem = beam_problem(n, length=args.length, E=args.E, nu=args.nu, rho=args.rho,
                               damping=damping, amplitude=args.amplitude, t_move=args.t_move,
                               T=args.T, degree=args.degree)
        session = RunSession(args, self.name)
        with session:
            if _already_completed(session):
                return 0
            stream = session.checkpoint_dir / "stream"
            if session.resume is None:  # segments of an earlier run are not this run's
                shutil.rmtree(stream, ignore_errors=True)
            writer = EldXdmfWriter(stream, problem, name="beam")
            if session.resume is None:
                writer.write(0.0, problem.u0, problem.v0, None)

            def observer(state, result):
                if state.j % every == 0 or state.j == round(problem.T / tau):
                    writer.write(state.t, state.u, state.v, result.lam)

            session.checkpoint.attachments = {"xdmf": writer}
            outcome = session.run(lambda **kw: run_eld(
                problem, form, tau, solver=args.solver, store_fields=False, observer=observer,
                linear_rtol=1e-8, **kw))
            results = session.results_dir(outcome.status)
            traj = outcome.result
            if traj is not None:
                with session.outputs(outcome.status) as stage:
                    writer.export(stage)
                    summary = run_summary(traj, self.name)
                    summary.update(
                        n=n, degree=args.degree, length=args.length, E=args.E, nu=args.nu,
                        amplitude=args.amplitude, t_move=args.t_move,
                        seconds_per_step=traj.stats.wall_time_s
                        / max(traj.stats.accepted_steps, 1),
                        xdmf=[p.name for p in writer.paths], xdmf_steps=writer.steps_written,
                    )
                    if traj.stats.accepted_steps:
                        R = traj["reaction_left"]
                        summary["reaction_left_max_abs"] = np.max(np.abs(R), axis=0).tolist()
                    session.annotate(summary, outcome)
                    label = f"eld-beam, {form}, tau={tau:g}, {problem.space.ndofs} dofs"
                    _write_run(args, stage, traj, summary, label,
                               plots=outcome.status == "completed")
            code = session.finish(outcome, results)
            if outcome.status == "completed":
                writer.discard()
        if outcome.status == "completed":
            _print_run(args, results, self.name, summary,
                       ("example", "form", "tau", "n_steps", "ndofs", "linear_solver",
                        "krylov_iterations", "seconds_per_step", "peak_memory_mb",
                        "reaction_left_final", "wall_time_s"))
        return code


@command("study", "eld-convergence")
class StudyEldConvergence:
    help = "Order in tau of both forms on the manufactured solution (tau halved repeatedly)"
    name = "eld-convergence"

    def configure(self, parser) -> None:
        parser.add_argument("--form", default="regularized", help="regularized | original")
        parser.add_argument("--tau0", type=parse_float("--tau0"), default=0.1,
                            help="largest step (default 0.1)")
        parser.add_argument("--halvings", type=int, default=5,
                            help="times tau is halved (default 5)")
        _mms_options(parser)
        parser.set_defaults(n=4)
        add_output_options(parser, self.name)

    def execute(self, args) -> int:
        from ..eld.studies import convergence_study, format_convergence_table

        form = check_choice("--form", args.form, FORMS)
        halvings = check_int("--halvings", args.halvings, minimum=1)
        n = check_int("--n", args.n, minimum=1)
        damping = _make_damping(args)
        out = output_dir(args, self.name)
        study = convergence_study(form, tau0=args.tau0, halvings=halvings, n=n,
                                  degree=args.degree, damping=damping, rho=args.rho,
                                  lam=args.lam, mu=args.mu, T=args.T, data=args.data,
                                  lifting=args.lifting, progress=progress_of(args))
        table = format_convergence_table(study)
        write_table(out, table + "\n")
        study["peak_memory_mb"] = peak_memory_mb()
        write_summary(out, study)
        if not args.no_plots:
            from ..plotting.eld import plot_convergence

            plot_convergence(
                study["tau"],
                {"u L2": study["error_u"], "u H1": study["error_u_h1"], "v L2": study["error_v"],
                 "lambda L2(G_D)": study["error_lam"]},
                out / "fig_convergence.png",
                rates={"u L2": study["rate_u"], "u H1": study["rate_u_h1"],
                       "v L2": study["rate_v"], "lambda L2(G_D)": study["rate_lam"]},
                title=f"eld-mms, {form}, P{study['degree']}")
        if not args.quiet:
            print(table)
            print(f"wrote {out}/")
        return 0


@command("study", "eld-perturbation")
class StudyEldPerturbation:
    help = ("Theorem 4.5: amplification of delta-noise in G and in F by both forms, "
            "for tau from 1e-1 to 1e-3")
    name = "eld-perturbation"

    def configure(self, parser) -> None:
        parser.add_argument("--taus", type=parse_float_list("--taus"),
                            default=[0.1, 0.05, 0.02, 0.01, 0.005, 0.002, 0.001],
                            help="step sizes (default 0.1,0.05,0.02,0.01,0.005,0.002,0.001)")
        parser.add_argument("--delta", type=parse_float("--delta"), default=1e-6,
                            help="size of the noise (default 1e-6)")
        parser.add_argument("--n", type=int, default=6, help="cells per side (default 6)")
        parser.add_argument("--degree", type=int, default=1, help="1 or 2 (default 1)")
        parser.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
        parser.add_argument("--targets", default="G,F", help="noise in G, F or both (default G,F)")
        _damping_options(parser)
        add_output_options(parser, self.name)

    def execute(self, args) -> int:
        from ..eld.studies import format_perturbation_table, perturbation_study

        taus = [check_positive("--taus", t) for t in args.taus]
        if len(taus) < 2:
            raise fail("--taus", ",".join(map(str, args.taus)), "needs at least two step sizes")
        targets = tuple(t.strip() for t in args.targets.split(",") if t.strip())
        for t in targets:
            check_choice("--targets", t, ("G", "F"))
        n = check_int("--n", args.n, minimum=1)
        damping = _make_damping(args)
        out = output_dir(args, self.name)
        study = perturbation_study(taus, delta=args.delta, targets=targets, n=n,
                                   degree=args.degree, damping=damping, seed=args.seed,
                                   progress=progress_of(args))
        table = format_perturbation_table(study)
        write_table(out, table + "\n")
        study["peak_memory_mb"] = peak_memory_mb()
        write_summary(out, study)
        if not args.no_plots:
            from ..plotting.eld import plot_perturbation

            for target in targets:
                plot_perturbation(study["tau"], study[target],
                                  out / f"fig_perturbation_{target}.png",
                                  title=f"noise in {target}, delta = {args.delta:g}")
        if not args.quiet:
            print(table)
            print(f"wrote {out}/")
        return 0
