"""CLI commands for elastodynamics: ``rothe run eld-mms|eld-beam|eld-pulse``,
``rothe study eld-convergence|eld-perturbation``.

Outputs: ``summary.json``, ``trajectory.npz`` (runs: with the mesh,
the kept u, v, a, lambda and the dof layout, see :mod:`rothe.eld.output`), a table (studies),
PNG figures unless ``--no-plots``, and for every run XDMF for ParaView (u, v, Cauchy and von
Mises stresses, lambda). Bad input is one line and exit status 2 (raised as RotheInputError by
the library where the value enters, e.g. tau >= rho/d0 by the stepper before the first step).
The run commands are sessions (:mod:`rothe.cli.session`): checkpoints in ``OUT/checkpoint``
(``--checkpoint-every``, ``--resume``, ``rothe resume OUT``), results staged and committed
together with ``summary.json`` last; a run that fails midway (a failed solve, a non-finite state
or datum) writes what it has with ``status: failed`` and exits 1, a run stopped by SIGINT /
SIGTERM with ``status: interrupted`` and exits 130 / 143.
"""

from __future__ import annotations

import shutil
import sys

import numpy as np

from ..errors import check_choice, check_int, check_positive, described, fail
from ..parallel.executor import add_parallel_options, executor_from_args
from .common import (
    add_output_options,
    fit_default_cap,
    given,
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
SCHEMES = ("euler", "bdf2")
#: eld-beam: P2 with 3 cells across (3675 dofs): sideways reactions 0.4 % / 0.3 % (Euler) and
#: 0.5 % / 0.7 % (BDF2) of R_z, R_z within 0.03 % of n = 4 (P1 n = 3: 17 % / 27 %)
BEAM_DEFAULT_N = 3
BEAM_DEFAULT_DEGREE = 2
#: the note on a coarse mesh when a sideways reaction exceeds this fraction of R_z
BEAM_SIDEWAYS_NOTE = 0.02
CONTROLS = ("uniform", "adaptive")


def _run_step_options(parser, tau_default: float) -> None:
    """--form, --scheme, --tau and --control/--tol: every eld run command steps the same way."""
    parser.add_argument("--form", default="regularized", help="regularized | original")
    _scheme_option(parser)
    parser.add_argument(
        "--tau",
        type=parse_float("--tau"),
        default=tau_default,
        help=f"time step; must divide T (default {tau_default:g}); the first "
        "step with --control adaptive",
    )
    _control_options(parser)


def _scheme_option(parser) -> None:
    parser.add_argument(
        "--scheme",
        default="euler",
        help="euler | bdf2: implicit Euler (3.4), the paper's scheme (default), or "
        "variable-step BDF2 (second order)",
    )


def _control_options(parser) -> None:
    parser.add_argument(
        "--control",
        default="uniform",
        help="uniform | adaptive: equal steps tau (must divide T), or steps chosen "
        "by the local error estimate (then --tau is the first step)",
    )
    parser.add_argument(
        "--tol",
        type=parse_float("--tol"),
        default=None,
        help="tolerance of --control adaptive: local error in the energy norm "
        "relative to the run's energy-norm scale",
    )


def _check_control(args) -> tuple[str, str, float | None]:
    scheme = check_choice("--scheme", args.scheme, SCHEMES)
    control = check_choice("--control", args.control, CONTROLS)
    tol = args.tol
    if control == "adaptive":
        if tol is None:
            raise fail("--tol", None, "must be given (> 0) with --control adaptive")
        tol = check_positive("--tol", tol)
    elif tol is not None:
        raise fail("--tol", tol, "is used by --control adaptive only (this run has uniform steps)")
    return scheme, control, tol


#: the options of space adaptivity (all with --adapt-space only)
SPACE_OPTIONS = (
    "--space-tol",
    "--refine-fraction",
    "--coarsen-fraction",
    "--max-dofs",
    "--adapt-every",
)


def _space_options(
    parser, on: bool = False, default_tol: float | None = None, default_max_dofs: int | None = None
) -> None:
    import argparse

    parser.add_argument(
        "--adapt-space",
        action=argparse.BooleanOptionalAction if on else "store_true",
        default=on,
        help="adapt the mesh (refine and coarsen by bisection) after every "
        "--adapt-every-th step, by the residual indicator (docs/eld.md)"
        + ("; on by default, --no-adapt-space keeps the mesh" if on else ""),
    )
    parser.add_argument(
        "--space-tol",
        type=parse_float("--space-tol"),
        default=None,
        help="tolerance of the estimate eta of a step (refine while above; "
        + ("required with --adapt-space)" if default_tol is None else f"default {default_tol:g})"),
    )
    parser.add_argument(
        "--refine-fraction",
        type=parse_float("--refine-fraction"),
        default=None,
        help="Doerfler bulk fraction of eta^2 to refine, in (0, 1) (default 0.5)",
    )
    parser.add_argument(
        "--coarsen-fraction",
        type=parse_float("--coarsen-fraction"),
        default=None,
        help="share of max(eta, space-tol)^2 the coarsened cells "
        "may carry, in (0, 1) (default 0.05)",
    )
    parser.add_argument(
        "--max-dofs",
        type=int,
        default=None,
        help="cap on the dofs of an adapted mesh (default "
        + (
            "none)"
            if default_max_dofs is None
            else f"{default_max_dofs:,}".replace(",", " ")
            + ", or twice the initial mesh's dofs when that is more)"
        ),
    )
    parser.add_argument(
        "--adapt-every",
        type=int,
        default=None,
        help="adapt after every k-th accepted step (default 1)",
    )


#: default --max-dofs of eld-mms (2D) and eld-beam (3D): a --space-tol below what the time
#: step's error allows (the indicator sees the step's residual, time error included) refines
#: without end, until memory runs out; twice the initial mesh's dofs when that is more
ELD_MAX_DOFS = {"2d": 200_000, "3d": 300_000}


def space_adaptivity(args, default_tol: float | None = None, default_max_dofs: int | None = None):
    """The SpaceAdaptivity of the --adapt-space options, or None (one-line errors naming the
    options; an option without --adapt-space is refused). ``default_max_dofs`` applies when
    --max-dofs is not given (see :func:`rothe.cli.common.fit_default_cap`)."""
    values = {o: getattr(args, o.lstrip("-").replace("-", "_")) for o in SPACE_OPTIONS}
    if not args.adapt_space:
        for option, value in values.items():
            if value is not None:
                raise fail(option, value, "is used by --adapt-space only (this run keeps its mesh)")
        return None
    from ..fem.adapt import SpaceAdaptivity

    if values["--space-tol"] is None:
        if default_tol is None:
            raise fail("--space-tol", None, "must be given (> 0) with --adapt-space")
        values["--space-tol"] = default_tol
    if values["--max-dofs"] is None:
        values["--max-dofs"] = default_max_dofs
    kw = {"space_tol": values["--space-tol"], "max_dofs": values["--max-dofs"]}
    for key, option, default in (
        ("refine_fraction", "--refine-fraction", 0.5),
        ("coarsen_fraction", "--coarsen-fraction", 0.05),
        ("adapt_every", "--adapt-every", 1),
    ):
        kw[key] = default if values[option] is None else values[option]
    return SpaceAdaptivity(naming="cli", **kw)


def _check_space(args, space) -> None:
    if space is not None and args.data != "points":
        raise fail(
            "--data",
            args.data,
            "must be points with --adapt-space (the data of t_j is "
            "re-evaluated on the new Dirichlet nodes)",
        )


def _keep_option(parser, default: int) -> None:
    parser.add_argument(
        "--keep-every",
        type=int,
        default=default,
        help=f"keep u, v, a, lambda of every k-th step in trajectory.npz and the "
        f"XDMF files (default {default}; t = 0 and the last step always)",
    )


def _damping_options(parser, default_b: float = 0.01) -> None:
    parser.add_argument(
        "--damping",
        default="nonlinear",
        help="nonlinear | rayleigh | none (default nonlinear: "
        "D v = b K v - d0 M v + d_nl v/sqrt(1+|v|^2/v_ref^2))",
    )
    parser.add_argument("--rho", type=parse_float("--rho"), default=1.0, help="density (default 1)")
    parser.add_argument(
        "--d0",
        type=parse_float("--d0"),
        default=0.5,
        help="L2 anti-damping constant d0 of the nonlinear damping (default 0.5)",
    )
    parser.add_argument(
        "--d-nl",
        type=parse_float("--d-nl"),
        default=1.0,
        help="coefficient d_nl of the saturating part (default 1)",
    )
    parser.add_argument(
        "--v-ref",
        type=parse_float("--v-ref"),
        default=1.0,
        help="saturation velocity v_ref (default 1)",
    )
    parser.add_argument(
        "--b",
        type=parse_float("--b"),
        default=default_b,
        help=f"stiffness-proportional coefficient b (default {default_b:g})",
    )
    parser.add_argument(
        "--a",
        type=parse_float("--a"),
        default=0.0,
        help="mass-proportional coefficient a of Rayleigh damping (default 0)",
    )


def _make_damping(args):
    from ..eld.damping import DAMPINGS, make_damping

    kind = check_choice("--damping", args.damping, DAMPINGS)
    return make_damping(kind, a=args.a, b=args.b, d0=args.d0, d_nl=args.d_nl, v_ref=args.v_ref)


# -- input validation (kept apart from the commands: called first in each execute) ------------

#: the damping parameters each --damping reads; one written on the command line that the chosen
#: damping ignores is refused (``eld-mms --a -1`` ran nonlinear damping and exited 0)
DAMPING_OPTIONS = {
    "nonlinear": ("--b", "--d0", "--d-nl", "--v-ref"),
    "rayleigh": ("--a", "--b"),
    "none": (),
}
#: most time steps of one ELD run the CLI accepts (T / tau): beyond, --tau is a typo or
#: an underflow (``--tau 1e-320`` made T / tau infinite)
MAX_ELD_STEPS = 10**7
#: peak memory per unknown (bytes). Measured here (summary.json's peak_memory_mb minus ~90 MB
#: of interpreter): eld-mms (2D, P2, sparse LU) 3.5 and 4.6 kB/dof at 33k and 132k dofs,
#: eld-beam (3D, LU) 7 kB/dof at 8k dofs. The team's solver measurements on this machine: a 3D
#: elasticity LU alone takes 0.8 GB at 28k and 4.3 GB at 89k dofs (29, 48 kB/dof), AMG 2.3 GB
#: at 1.07M (2.1 kB/dof). Rounded up: refuses sizes that cannot fit, before allocating.
ELD_BYTES_PER_DOF = {"2d": 6000, "3d-lu": 50_000, "3d-amg": 3000}
#: 3D unknowns up to which the beam's auto solver is sparse LU (rothe.eld.solvers)
BEAM_LU_LIMIT = 30_000


def check_damping_options(args) -> None:
    from ..eld.damping import DAMPINGS

    kind = check_choice("--damping", args.damping, DAMPINGS)
    for option in sorted({o for opts in DAMPING_OPTIONS.values() for o in opts}):
        if given(args, option) and option not in DAMPING_OPTIONS.get(kind, ()):
            users = [k for k, opts in DAMPING_OPTIONS.items() if option in opts]
            value = getattr(args, option.lstrip("-").replace("-", "_"))
            raise fail(
                option,
                value,
                f"is not used by --damping {kind}; {option} is for --damping {' or '.join(users)}",
            )


def check_eld_step(option: str, tau, T: float) -> float:
    """A time step with T / tau <= MAX_ELD_STEPS (and tau > 0)."""
    tau = check_positive(option, tau)
    T = check_positive("--T", T)
    smallest = T / MAX_ELD_STEPS
    if tau < smallest:
        raise fail(
            option, tau, f"must be >= {smallest:g} (at most {MAX_ELD_STEPS:.0e} steps of T = {T:g})"
        )
    return tau


def check_study_options(args) -> None:
    """The study options that rothe.eld.studies also checks, named as on the command line."""
    from ..eld.studies import check_delta, check_halvings, check_noise_targets

    if hasattr(args, "halvings"):
        check_halvings("--halvings", args.halvings, args.tau0, args.T)
    if hasattr(args, "targets"):
        check_noise_targets("--targets", args.targets)
        check_int("--seed", args.seed, minimum=0)
        check_delta("--delta", args.delta)


def check_mms_size(n: int, degree: int) -> None:
    from .ris_fem_commands import check_memory

    if degree in (1, 2):
        dofs = 2 * (degree * n + 1) ** 2
        check_memory("--n", n, dofs, ELD_BYTES_PER_DOF["2d"], what="unknowns")


def check_beam_size(n: int, length: float, degree: int, solver: str) -> None:
    from .ris_fem_commands import check_memory

    if degree in (1, 2) and length > 0:
        nx = max(1, round(length * n))
        dofs = 3 * (degree * nx + 1) * (degree * n + 1) ** 2
        lu = solver == "direct" or (solver == "auto" and dofs <= BEAM_LU_LIMIT)
        check_memory(
            "--n", n, dofs, ELD_BYTES_PER_DOF["3d-lu" if lu else "3d-amg"], what="unknowns"
        )


def _mms_options(parser, n: int = 8) -> None:
    parser.add_argument(
        "--n", type=int, default=n, help=f"cells per side of the unit square (default {n})"
    )
    parser.add_argument("--degree", type=int, default=2, help="1 or 2 (default 2: exact in space)")
    parser.add_argument(
        "--lam", type=parse_float("--lam"), default=2.0, help="Lamé lambda (default 2)"
    )
    parser.add_argument("--mu", type=parse_float("--mu"), default=1.0, help="Lamé mu (default 1)")
    parser.add_argument("--T", type=parse_float("--T"), default=1.0, help="end time (default 1)")
    parser.add_argument(
        "--data",
        default="points",
        help="points | means | differenced: how F, G, G', G'' enter (3.3)/(3.1)",
    )
    parser.add_argument(
        "--lifting",
        default="nodal",
        help="right inverse of B for the regularized form: nodal | harmonic",
    )
    _damping_options(parser)


def energy_summary(traj) -> dict:
    e0 = float(traj["energy"][0])
    e1 = float(traj["energy"][-1])
    return {
        "energy_initial": e0,
        "energy_final": e1,
        "energy_ratio": e1 / e0 if e0 > 0 else None,
        "work_loads": float(traj["work"][-1]),
        "work_support": float(traj["work_reaction"][-1]),
        "dissipated_physical": float(traj["dissipated"][-1]),
        "dissipated_numerical": float(traj["numerical_dissipation"][-1]),
        "dissipated_numerical_G": float(traj["numerical_dissipation_G"][-1]),
        "step_change": float(traj["step_change"][-1]),
        "numerical_boundary_term": float(
            traj["numerical_dissipation"][-1]
            - traj["numerical_dissipation_G"][-1]
            - traj["step_change"][-1]
        ),
        "data_mismatch": float(traj["data_mismatch"][-1]),
        "residual_work": float(traj["residual_work"][-1]),
        "transfer": float(traj["transfer"][-1]),
        "balance_residual_max": float(np.max(np.abs(traj["balance_residual"]))),
    }


def _write_run(
    args, out, name, traj, summary, label, problem, xdmf: bool = True, plots: bool = True
) -> None:
    """What every ELD run writes into ``out`` (its staging directory): trajectory.npz (with the
    mesh), XDMF of the kept states (unless streamed already), the energy and reaction figures
    (completed runs), summary.json last."""
    from ..eld.output import write_eld_result

    write_eld_result(
        traj,
        problem,
        out,
        name=name.replace("eld-", ""),
        xdmf=xdmf and "kept_t" in traj,
        figures=plots and not args.no_plots and "energy" in traj,
        title=label,
    )
    write_summary(out, summary)


def _print_run(args, results, name, summary, keys) -> None:
    if not args.quiet:
        print(f"rothe run {name}: wrote {results}/")
        print_summary(summary, keys)
        print(format_energy_balance(summary))


def _already_completed(session) -> bool:
    if session.already_completed:
        print(
            f"rothe: {session.out}: the run already completed; its results are there",
            file=sys.stderr,
        )
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
        ("  + solver residual work", e["residual_work"]),
        ("  + mesh transfer", e["transfer"]),
    )
    lines = ["energy balance of the scheme (E = kinetic + elastic):"]
    lines += [f"  {name:<26} {value:>14.6g}" for name, value in rows]
    if e.get("numerical_boundary_term"):  # BDF2: N = N_G + S + (C^n - C^0), rothe.eld.schemes
        lines.insert(6, f"  {'    (G-form part N_G':<26} {e['dissipated_numerical_G']:>14.6g}")
        lines.insert(7, f"  {'     + step changes S':<26} {e['step_change']:>14.6g}")
        lines.insert(8, f"  {'     + C^n - C^0)':<26} {e['numerical_boundary_term']:>14.6g}")
    lines.append(f"  {'max |residual| per step':<26} {e['balance_residual_max']:>14.2e}")
    return "\n".join(lines)


def run_summary(traj, example: str) -> dict:
    st = traj.stats
    meta = traj.meta
    solver = meta.get("linear_solver", {})
    summary = {
        "example": example,
        "form": meta.get("form"),
        "scheme": meta.get("scheme"),
        "control": meta.get("control"),
        "tol": meta.get("tol"),
        "tau": meta.get("tau"),
        "data": meta.get("data"),
        "lifting": meta.get("lifting"),
        "n_steps": meta.get("n_steps"),
        "ndofs": meta.get("problem", {}).get("ndofs"),
        "constrained_dofs": meta.get("problem", {}).get("constrained_dofs"),
        "damping": meta.get("problem", {}).get("damping"),
        "step_bound_rho_over_d0": meta.get("step_bound"),
        "accepted_steps": st.accepted_steps,
        "rejected_steps": st.rejected_steps,
        "tau_min_used": float(np.min(traj["tau"])) if st.accepted_steps else None,
        "tau_max_used": float(np.max(traj["tau"])) if st.accepted_steps else None,
        "inner_solves": st.inner_solves,
        "newton_iterations": st.newton_iterations,
        "newton_per_step": st.newton_iterations / max(st.accepted_steps, 1),
        "linear_solver": solver.get("kind"),
        "linear_factorizations": solver.get("factorizations", st.linear_factorizations),
        "backsolves": solver.get("backsolves", st.linear_solves),
        "krylov_iterations": solver.get("krylov_iterations", st.krylov_iterations),
        "t_final": float(traj["t"][-1]) if "t" in traj else None,
        "wall_time_s": st.wall_time_s,
        "peak_memory_mb": peak_memory_mb(),
        "status": "completed",
    }
    if st.accepted_steps:
        for key in traj.keys():
            if key.startswith("reaction_"):
                summary[f"{key}_final"] = traj[key][-1].tolist()
    if "energy" in traj:
        summary.update(energy_summary(traj))
    space = getattr(traj, "space", None)
    if space is not None:
        summary.update(space_summary(traj))
    return summary


def space_summary(traj) -> dict:
    """Dofs over the run and the adaptations of a space-adaptive run."""
    sp = traj.space
    dofs = np.asarray(traj["ndofs"])
    return {
        "space": traj.meta.get("space"),
        "adaptations": len(sp.adaptations),
        "meshes": len(sp.series.ids),
        "ndofs": int(dofs[-1]),
        "ndofs_initial": int(dofs[0]),
        "ndofs_max": int(dofs.max()),
        "ndofs_summed_over_steps": int(dofs[1:].sum()),
        "bisections": int(sum(a["bisections"] for a in sp.adaptations)),
        "merges": int(sum(a["merges"] for a in sp.adaptations)),
        "transfer_energy": float(traj["transfer"][-1]),
    }


MMS_KEYS = (
    "example",
    "form",
    "scheme",
    "control",
    "tau",
    "accepted_steps",
    "rejected_steps",
    "ndofs",
    "newton_per_step",
    "error_u_l2",
    "error_u_h1",
    "error_v_l2",
    "error_v_h1",
    "error_lam_l2",
    "error_lam_l2_max",
    "wall_time_s",
)


@command("run", "eld-mms")
class RunEldMMS:
    help = (
        "Manufactured solution on the unit square: time-dependent Dirichlet data by a "
        "multiplier, traction, nonlinear damping (Altmann 2015, scheme (3.4))"
    )
    name = "eld-mms"

    def configure(self, parser) -> None:
        _run_step_options(parser, 0.01)
        parser.add_argument(
            "--steps",
            type=parse_float_list("--steps"),
            default=None,
            help="a given step sequence tau_1,...,tau_n summing to T (instead of "
            "--tau; BDF2: ratios below 1 + sqrt(2))",
        )
        parser.add_argument(
            "--load-quadrature",
            type=int,
            default=None,
            help="degree of the quadrature of body force and tractions (default 2 * degree)",
        )
        _keep_option(parser, 1)
        parser.add_argument(
            "--dirichlet",
            default="left",
            help="comma-separated Dirichlet parts (default left); traction on the rest",
        )
        parser.add_argument(
            "--start",
            default="exact",
            help="exact | rest: initial data u(0), u'(0) of the solution, or zero "
            "(inconsistent with G(0): refused, Remark 2.2)",
        )
        _mms_options(parser)
        _space_options(parser, default_max_dofs=ELD_MAX_DOFS["2d"])
        add_output_options(parser, self.name)
        add_run_options(parser)

    def validate(self, args):
        """The checks that need no mesh (also run by ``rothe sweep`` before any run starts)."""
        check_damping_options(args)
        check_eld_step("--tau", args.tau, args.T)
        check_mms_size(check_int("--n", args.n, minimum=1), args.degree)
        form = check_choice("--form", args.form, FORMS)
        tau = check_positive("--tau", args.tau)
        scheme, control, tol = _check_control(args)
        keep = check_int("--keep-every", args.keep_every, minimum=1)
        if args.steps is not None and control != "uniform":
            raise fail(
                "--steps",
                described("a step sequence"),
                "is a fixed grid: not with --control adaptive",
            )
        n = check_int("--n", args.n, minimum=1)
        parts = tuple(p.strip() for p in args.dirichlet.split(",") if p.strip())
        if not parts:
            raise fail("--dirichlet", args.dirichlet, "must name at least one boundary part")
        _check_space(args, space_adaptivity(args, default_max_dofs=ELD_MAX_DOFS["2d"]))
        return form, tau, scheme, control, tol, keep, n, parts, _make_damping(args)

    def execute(self, args) -> int:
        from ..eld.examples import mms_errors, mms_problem
        from ..eld.schemes import run_eld

        form, tau, scheme, control, tol, keep, n, parts, damping = self.validate(args)
        space = space_adaptivity(args, default_max_dofs=ELD_MAX_DOFS["2d"])
        problem, exact = mms_problem(
            n,
            args.degree,
            damping=damping,
            rho=args.rho,
            lam=args.lam,
            mu=args.mu,
            T=args.T,
            dirichlet=parts,
            start=args.start,
            load_quadrature=args.load_quadrature,
        )
        fit_default_cap(args, space, problem.space.ndofs)
        label = f"eld-mms, {scheme}, {form}, " + (f"tol={tol:g}" if tol else f"tau={tau:g}")
        session = RunSession(args, self.name)
        with session:
            if _already_completed(session):
                return 0
            outcome = session.run(
                lambda **kw: run_eld(
                    problem,
                    form,
                    tau,
                    scheme=scheme,
                    control=control,
                    tol=tol,
                    steps=args.steps,
                    data=args.data,
                    lifting=args.lifting,
                    keep_every=keep,
                    space=space,
                    **kw,
                )
            )
            results = session.results_dir(outcome.status)
            traj = outcome.result
            completed = outcome.status == "completed"
            if traj is not None:
                with session.outputs(outcome.status) as stage:
                    summary = run_summary(traj, self.name)
                    summary.update(n=n, degree=args.degree, dirichlet=list(parts))
                    if completed:
                        summary.update(mms_errors(problem, exact, traj))
                    session.annotate(summary, outcome)
                    _write_run(
                        args, stage, self.name, traj, summary, label, problem, plots=completed
                    )
            code = session.finish(outcome, results)
        if completed:
            _print_run(args, results, self.name, summary, MMS_KEYS)
        return code


@command("run", "eld-beam")
class RunEldBeam:
    help = (
        "3D cantilever (E=1000, nu=0.3, rho=1): one end held and moved by G(t), the other "
        "free; the multiplier is the reaction at the held end (XDMF for ParaView)"
    )
    name = "eld-beam"

    def configure(self, parser) -> None:
        parser.add_argument("--form", default="regularized", help="regularized | original")
        _scheme_option(parser)
        parser.add_argument(
            "--n",
            type=int,
            default=BEAM_DEFAULT_N,
            help=f"cells across the unit cross-section (default {BEAM_DEFAULT_N}); "
            "round(length*n) along the beam",
        )
        parser.add_argument(
            "--length", type=parse_float("--length"), default=4.0, help="beam length (default 4)"
        )
        parser.add_argument(
            "--degree",
            type=int,
            default=BEAM_DEFAULT_DEGREE,
            help=f"1 or 2 (default {BEAM_DEFAULT_DEGREE})",
        )
        parser.add_argument(
            "--tau",
            type=parse_float("--tau"),
            default=0.01,
            help="time step (default 0.01); the first step with --control adaptive",
        )
        _control_options(parser)
        parser.add_argument(
            "--T", type=parse_float("--T"), default=2.0, help="end time (default 2)"
        )
        parser.add_argument("--E", type=parse_float("--E"), default=1000.0, help="Young's modulus")
        parser.add_argument("--nu", type=parse_float("--nu"), default=0.3, help="Poisson ratio")
        parser.add_argument(
            "--amplitude",
            type=parse_float("--amplitude"),
            default=0.1,
            help="end displacement (z) of the held end's motion (default 0.1)",
        )
        parser.add_argument(
            "--t-move",
            type=parse_float("--t-move"),
            default=0.5,
            help="duration of the motion; held still afterwards (default 0.5)",
        )
        parser.add_argument("--solver", default="auto", help="auto | direct | amg")
        parser.add_argument(
            "--save-every", type=int, default=5, help="write every k-th step to XDMF (default 5)"
        )
        _keep_option(parser, 5)
        _damping_options(parser, default_b=0.002)
        parser.set_defaults(damping="rayleigh")
        _space_options(parser, default_max_dofs=ELD_MAX_DOFS["3d"])
        add_output_options(parser, self.name)
        add_run_options(parser)

    def validate(self, args):
        """The checks that need no mesh (also run by ``rothe sweep`` before any run starts)."""
        check_damping_options(args)
        check_eld_step("--tau", args.tau, args.T)
        check_beam_size(check_int("--n", args.n, minimum=1), args.length, args.degree, args.solver)
        form = check_choice("--form", args.form, FORMS)
        tau = check_positive("--tau", args.tau)
        scheme, control, tol = _check_control(args)
        n = check_int("--n", args.n, minimum=1)
        every = check_int("--save-every", args.save_every, minimum=1)
        keep = check_int("--keep-every", args.keep_every, minimum=1)
        space_adaptivity(args, default_max_dofs=ELD_MAX_DOFS["3d"])
        return form, tau, scheme, control, tol, n, every, keep, _make_damping(args)

    def execute(self, args) -> int:
        from ..eld.examples import beam_problem
        from ..eld.output import EldXdmfWriter
        from ..eld.schemes import run_eld

        form, tau, scheme, control, tol, n, every, keep, damping = self.validate(args)
        space = space_adaptivity(args, default_max_dofs=ELD_MAX_DOFS["3d"])
        problem = beam_problem(
            n,
            length=args.length,
            E=args.E,
            nu=args.nu,
            rho=args.rho,
            damping=damping,
            amplitude=args.amplitude,
            t_move=args.t_move,
            T=args.T,
            degree=args.degree,
        )
        fit_default_cap(args, space, problem.space.ndofs)
        label = f"eld-beam, {scheme}, {form}, tau={tau:g}, {problem.space.ndofs} dofs"
        session = RunSession(args, self.name)
        with session:
            if _already_completed(session):
                return 0
            stream = session.checkpoint_dir / "stream"
            if session.resume is None:  # segments of an earlier run are not this run's
                shutil.rmtree(stream, ignore_errors=True)
            # a fixed mesh streams XDMF as it goes; an adaptive run writes one VTU per kept
            # state on its own mesh at the end (rothe.eld.output)
            writer = None if space is not None else EldXdmfWriter(stream, problem, name="beam")
            if session.resume is None and writer is not None:
                writer.write(0.0, problem.u0, problem.v0, None)

            def observer(state, result):
                # n tau may round to just below T: the last step by a relative margin
                if state.j % every == 0 or state.t >= problem.T * (1.0 - 1e-12):
                    writer.write(state.t, state.u, state.v, result.lam)

            if writer is not None:
                session.checkpoint.attachments = {"xdmf": writer}
            outcome = session.run(
                lambda **kw: run_eld(
                    problem,
                    form,
                    tau,
                    scheme=scheme,
                    control=control,
                    tol=tol,
                    solver=args.solver,
                    keep_every=keep,
                    observer=None if writer is None else observer,
                    linear_rtol=1e-8,
                    space=space,
                    **kw,
                )
            )
            results = session.results_dir(outcome.status)
            traj = outcome.result
            completed = outcome.status == "completed"
            if traj is not None:
                with session.outputs(outcome.status) as stage:
                    if writer is not None:
                        writer.export(stage)
                    summary = run_summary(traj, self.name)
                    summary.update(
                        n=n,
                        degree=args.degree,
                        length=args.length,
                        E=args.E,
                        nu=args.nu,
                        amplitude=args.amplitude,
                        t_move=args.t_move,
                        seconds_per_step=traj.stats.wall_time_s / max(traj.stats.accepted_steps, 1),
                    )
                    if writer is not None:
                        summary.update(
                            xdmf=[p.name for p in writer.paths], xdmf_steps=writer.steps_written
                        )
                    e = None
                    if traj.stats.accepted_steps:
                        summary.update(_beam_reactions(traj))
                        e = energy_summary(traj)
                        put_in = e["work_support"] + e["work_loads"]
                        summary["numerical_dissipation_fraction"] = (
                            e["dissipated_numerical"] / put_in if put_in > 0 else None
                        )
                    session.annotate(summary, outcome)
                    _write_run(
                        args,
                        stage,
                        self.name,
                        traj,
                        summary,
                        label,
                        problem,
                        xdmf=writer is None,
                        plots=completed,
                    )
            code = session.finish(outcome, results)
            if completed and writer is not None:
                writer.discard()
        if completed:
            _print_run(
                args,
                results,
                self.name,
                summary,
                (
                    "example",
                    "form",
                    "scheme",
                    "tau",
                    "accepted_steps",
                    "ndofs",
                    "linear_solver",
                    "krylov_iterations",
                    "seconds_per_step",
                    "peak_memory_mb",
                    "reaction_left_final",
                    "reaction_left_max_abs",
                    "wall_time_s",
                ),
            )
            if not args.quiet and e is not None:
                sideways = summary["reaction_sideways_over_z"]
                print(
                    f"numerical dissipation: {e['dissipated_numerical']:.4g} of the "
                    f"{put_in:.4g} put in by the support and the loads (physical damping "
                    f"{e['dissipated_physical']:.4g})"
                )
                if max(sideways) > BEAM_SIDEWAYS_NOTE:
                    print(
                        f"note: coarse mesh for the reactions: the sideways reactions are "
                        f"{100 * sideways[0]:.1f} % (x) and {100 * sideways[1]:.1f} % (y) of "
                        "R_z, zero for the exact solution; use --degree 2 or a larger --n"
                    )
        return code


#: eld-pulse defaults (benchmarks/space_adaptivity.py)
PULSE_SPACE_TOL = 1e-3
PULSE_MAX_DOFS = 100_000


@command("run", "eld-pulse")
class RunEldPulse:
    help = (
        "A 2D body hit by a short boundary pulse: the wave front crosses the body, adaptive "
        "meshes refine on it and coarsen behind it (space adaptivity)"
    )
    name = "eld-pulse"

    def configure(self, parser) -> None:
        _run_step_options(parser, 0.005)
        parser.set_defaults(scheme="bdf2")
        parser.add_argument(
            "--n",
            type=int,
            default=4,
            help="cells across the height of the initial mesh (default 4; round(length*n) along)",
        )
        parser.add_argument("--degree", type=int, default=2, help="1 or 2 (default 2)")
        parser.add_argument(
            "--length",
            type=parse_float("--length"),
            default=2.0,
            help="length of the body [0, length] x [0, 1] (default 2)",
        )
        parser.add_argument(
            "--T",
            type=parse_float("--T"),
            default=0.8,
            help="end time (default 0.8: the pressure front crosses 80 %%)",
        )
        parser.add_argument(
            "--amplitude",
            type=parse_float("--amplitude"),
            default=0.01,
            help="peak displacement of the pulse (default 0.01)",
        )
        parser.add_argument(
            "--t-pulse",
            type=parse_float("--t-pulse"),
            default=0.1,
            help="duration of the pulse (default 0.1)",
        )
        parser.add_argument(
            "--width",
            type=parse_float("--width"),
            default=0.1,
            help="width of the pushed part around y = 1/2 (default 0.1)",
        )
        parser.add_argument("--lam", type=parse_float("--lam"), default=2.0, help="Lamé lambda")
        parser.add_argument("--mu", type=parse_float("--mu"), default=1.0, help="Lamé mu")
        parser.add_argument("--rho", type=parse_float("--rho"), default=1.0, help="density")
        parser.add_argument(
            "--b",
            type=parse_float("--b"),
            default=0.001,
            help="Rayleigh stiffness-proportional damping b (default 0.001)",
        )
        parser.add_argument(
            "--lifting",
            default="nodal",
            help="right inverse of B for the regularized form: nodal | harmonic",
        )
        _keep_option(parser, 10)
        _space_options(
            parser, on=True, default_tol=PULSE_SPACE_TOL, default_max_dofs=PULSE_MAX_DOFS
        )
        add_output_options(parser, self.name)
        add_run_options(parser)

    def validate(self, args):
        """The checks that need no mesh (also run by ``rothe sweep`` before any run starts)."""
        check_eld_step("--tau", args.tau, args.T)
        form = check_choice("--form", args.form, FORMS)
        tau = check_positive("--tau", args.tau)
        scheme, control, tol = _check_control(args)
        keep = check_int("--keep-every", args.keep_every, minimum=1)
        n = check_int("--n", args.n, minimum=1)
        if args.degree not in (1, 2):
            raise fail("--degree", args.degree, "must be 1 or 2")
        length = check_positive("--length", args.length)
        check_mms_size(max(n, round(n * length)), args.degree)
        for option in ("--t-pulse", "--width", "--lam", "--mu", "--rho"):
            check_positive(option, getattr(args, option.lstrip("-").replace("-", "_")))
        space = space_adaptivity(args, default_tol=PULSE_SPACE_TOL, default_max_dofs=PULSE_MAX_DOFS)
        return form, tau, scheme, control, tol, keep, n, length, space

    def execute(self, args) -> int:
        from ..eld.examples import pulse_problem
        from ..eld.schemes import run_eld

        form, tau, scheme, control, tol, keep, n, length, space = self.validate(args)
        problem = pulse_problem(
            n,
            args.degree,
            length=length,
            amplitude=args.amplitude,
            t_pulse=args.t_pulse,
            width=args.width,
            b=args.b,
            rho=args.rho,
            lam=args.lam,
            mu=args.mu,
            T=args.T,
        )
        fit_default_cap(args, space, problem.space.ndofs)
        label = f"eld-pulse, {scheme}, {form}, " + (
            f"space_tol={space.space_tol:g}" if space else "fixed mesh"
        )
        session = RunSession(args, self.name)
        with session:
            if _already_completed(session):
                return 0
            outcome = session.run(
                lambda **kw: run_eld(
                    problem,
                    form,
                    tau,
                    scheme=scheme,
                    control=control,
                    tol=tol,
                    lifting=args.lifting,
                    keep_every=keep,
                    space=space,
                    **kw,
                )
            )
            results = session.results_dir(outcome.status)
            traj = outcome.result
            completed = outcome.status == "completed"
            if traj is not None:
                with session.outputs(outcome.status) as stage:
                    summary = run_summary(traj, self.name)
                    summary.update(
                        n=n,
                        degree=args.degree,
                        length=length,
                        t_pulse=args.t_pulse,
                        width=args.width,
                    )
                    session.annotate(summary, outcome)
                    _write_run(
                        args, stage, self.name, traj, summary, label, problem, plots=completed
                    )
            code = session.finish(outcome, results)
        if completed:
            _print_run(
                args,
                results,
                self.name,
                summary,
                (
                    "example",
                    "form",
                    "scheme",
                    "tau",
                    "accepted_steps",
                    "ndofs_initial",
                    "ndofs",
                    "ndofs_max",
                    "ndofs_summed_over_steps",
                    "adaptations",
                    "meshes",
                    "bisections",
                    "merges",
                    "transfer_energy",
                    "wall_time_s",
                ),
            )
        return code


def _beam_reactions(traj) -> dict:
    """The peak reactions at the held end and the sideways ones relative to R_z (the motion is
    purely in z and the beam symmetric: R_x, R_y vanish for the exact solution)."""
    peak = np.max(np.abs(traj["reaction_left"]), axis=0)
    sideways = (peak[:2] / peak[2]).tolist() if peak[2] > 0 else [0.0, 0.0]
    return {"reaction_left_max_abs": peak.tolist(), "reaction_sideways_over_z": sideways}


@command("study", "eld-convergence")
class StudyEldConvergence:
    help = "Order in tau of both forms on the manufactured solution (tau halved repeatedly)"
    name = "eld-convergence"

    def configure(self, parser) -> None:
        parser.add_argument("--form", default="regularized", help="regularized | original")
        _scheme_option(parser)
        parser.add_argument(
            "--tau0", type=parse_float("--tau0"), default=0.1, help="largest step (default 0.1)"
        )
        parser.add_argument(
            "--halvings", type=int, default=5, help="times tau is halved (default 5)"
        )
        _mms_options(parser, n=4)
        add_output_options(parser, self.name)
        add_parallel_options(parser)

    def execute(self, args) -> int:
        from ..eld.studies import convergence_study, format_convergence_table

        check_damping_options(args)
        check_eld_step("--tau0", args.tau0, args.T)
        check_mms_size(check_int("--n", args.n, minimum=1), args.degree)
        check_study_options(args)
        form = check_choice("--form", args.form, FORMS)
        scheme = check_choice("--scheme", args.scheme, SCHEMES)
        halvings = check_int("--halvings", args.halvings, minimum=1)
        n = check_int("--n", args.n, minimum=1)
        damping = _make_damping(args)
        executor = executor_from_args(args, f"rothe study {self.name}")
        out = output_dir(args, self.name)
        study = convergence_study(
            form,
            tau0=args.tau0,
            halvings=halvings,
            n=n,
            degree=args.degree,
            damping=damping,
            rho=args.rho,
            lam=args.lam,
            mu=args.mu,
            T=args.T,
            data=args.data,
            lifting=args.lifting,
            scheme=scheme,
            progress=progress_of(args),
            executor=executor,
        )
        table = format_convergence_table(study)
        write_table(out, table + "\n")
        study["peak_memory_mb"] = peak_memory_mb()
        write_summary(out, study)
        if not args.no_plots:
            from ..eld.figures import plot_convergence

            plot_convergence(
                study["tau"],
                {
                    "u L2": study["error_u"],
                    "u H1": study["error_u_h1"],
                    "v L2": study["error_v"],
                    "lambda L2(G_D)": study["error_lam"],
                    "max_j lambda": study["error_lam_max"],
                },
                out / "fig_convergence.png",
                rates={
                    "u L2": study["rate_u"],
                    "u H1": study["rate_u_h1"],
                    "v L2": study["rate_v"],
                    "lambda L2(G_D)": study["rate_lam"],
                    "max_j lambda": study["rate_lam_max"],
                },
                title=f"eld-mms, {scheme}, {form}, P{study['degree']}",
                order=1 if scheme == "euler" else 2,
            )
        if not args.quiet:
            print(table)
            print(f"wrote {out}/")
        return 0 if all("status" not in r for r in study["rows"]) else 1


@command("study", "eld-perturbation")
class StudyEldPerturbation:
    help = (
        "Theorem 4.5: amplification of delta-noise in each of G, G', G'' and F alone by "
        "both forms, for tau from 1e-1 to 1e-3"
    )
    name = "eld-perturbation"

    def configure(self, parser) -> None:
        parser.add_argument(
            "--taus",
            type=parse_float_list("--taus"),
            default=[0.1, 0.05, 0.02, 0.01, 0.005, 0.002, 0.001],
            help="step sizes (default 0.1,0.05,0.02,0.01,0.005,0.002,0.001)",
        )
        parser.add_argument(
            "--delta",
            type=parse_float("--delta"),
            default=1e-6,
            help="size of the noise (default 1e-6)",
        )
        parser.add_argument("--n", type=int, default=6, help="cells per side (default 6)")
        parser.add_argument("--degree", type=int, default=1, help="1 or 2 (default 1)")
        parser.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
        parser.add_argument(
            "--targets",
            default="G,G_dot,G_ddot,F",
            help="the data perturbed, each alone (default G,G_dot,G_ddot,F)",
        )
        _scheme_option(parser)
        _damping_options(parser)
        add_output_options(parser, self.name)
        add_parallel_options(parser)

    def execute(self, args) -> int:
        from ..eld.studies import format_perturbation_table, perturbation_study

        check_damping_options(args)
        for t in args.taus:
            check_eld_step("--taus", t, 1.0)
        check_mms_size(check_int("--n", args.n, minimum=1), args.degree)
        check_study_options(args)
        taus = [check_positive("--taus", t) for t in args.taus]
        if len(taus) < 2:
            raise fail("--taus", ",".join(map(str, args.taus)), "needs at least two step sizes")
        from ..eld.data import NOISE_TARGETS

        targets = tuple(t.strip() for t in args.targets.split(",") if t.strip())
        if not targets:
            raise fail(
                "--targets", args.targets, "must name at least one of " + ", ".join(NOISE_TARGETS)
            )
        for t in targets:
            check_choice("--targets", t, NOISE_TARGETS)
        scheme = check_choice("--scheme", args.scheme, SCHEMES)
        n = check_int("--n", args.n, minimum=1)
        damping = _make_damping(args)
        executor = executor_from_args(args, f"rothe study {self.name}")
        out = output_dir(args, self.name)
        study = perturbation_study(
            taus,
            delta=args.delta,
            targets=targets,
            n=n,
            degree=args.degree,
            damping=damping,
            seed=args.seed,
            scheme=scheme,
            progress=progress_of(args),
            executor=executor,
        )
        table = format_perturbation_table(study)
        write_table(out, table + "\n")
        study["peak_memory_mb"] = peak_memory_mb()
        write_summary(out, study)
        if not args.no_plots:
            from ..eld.figures import plot_perturbation

            for target in targets:
                plot_perturbation(
                    study["tau"],
                    study[target],
                    out / f"fig_perturbation_{target}.png",
                    title=f"{scheme}: noise in {target}, delta = {args.delta:g}",
                )
        if not args.quiet:
            print(table)
            print(f"wrote {out}/")
        return 0 if "failed" not in study else 1
