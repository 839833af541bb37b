"""CLI commands for elastodynamics: ``rothe run eld-mms|eld-beam|eld-pulse|eld-pulse-3d``,
``rothe study eld-convergence|eld-perturbation``.

Outputs: ``summary.json``, ``trajectory.npz`` (runs: with the mesh,
the kept u, v, a, lambda and the dof layout, see :mod:`rothe.eld.output`), a table (studies),
PNG figures unless ``--no-plots``, and for every run XDMF for ParaView (u, v, Cauchy and von
Mises stresses, lambda). Bad input is one line and exit status 2 (the options and the map from
their names to the library's objects: :mod:`rothe.cli.eld_options`; values the library checks
where they enter, e.g. tau >= rho/d0 by the stepper before the first step).
The run commands share one run sequence (:class:`EldRunCommand`: run -> stage -> annotate ->
write -> finish) as sessions (:mod:`rothe.cli.session`): checkpoints in ``OUT/checkpoint``
(``--checkpoint-every``, ``--resume``, ``rothe resume OUT``), results staged and committed
together with ``summary.json`` last; a run that fails midway (a failed solve, a non-finite state
or datum) writes what it has with ``status: failed`` and exits 1, a run stopped by SIGINT /
SIGTERM with ``status: interrupted`` and exits 130 / 143.
"""

from __future__ import annotations

import shutil

import numpy as np

from ..eld.data import NOISE_TARGETS
from ..eld.examples import (
    BEAM_MESH,
    PULSE_3D_MESH,
    beam_problem,
    mms_errors,
    mms_problem,
    pulse_3d_problem,
    pulse_problem,
    tip_mass_problem,
)
from ..eld.output import EldXdmfWriter, write_eld_result
from ..eld.run import BACKENDS, ELDResult, prepare_eld_run
from ..eld.solvers import AMG_PRODUCTS
from ..eld.studies import (
    COUPLED_TARGETS,
    check_delta,
    check_noise_targets,
    convergence_study,
    coupled_perturbation_study,
    format_convergence_table,
    format_perturbation_table,
    format_tip_mass_table,
    perturbation_study,
    tip_mass_bar,
    tip_mass_study,
)
from ..errors import RotheInputError, check_choice, check_int, check_positive, described, fail
from ..fem.mesh import boundary_part_names, check_mesh_dim
from ..fem.petsc_env import launched_processes
from ..io.checkpoint import CheckpointError, load_checkpoint
from .adapt_options import add_space_options, check_memory, fit_default_cap, space_adaptivity
from .common import (
    add_output_options,
    add_parallel_options,
    dofs_keys,
    executor_from_args,
    float_option,
    given,
    output_dir,
    parse_float_list,
    parse_int,
    peak_memory_mb,
    print_summary,
    progress_of,
    write_summary,
    write_table,
)
from .eld_options import (
    ELD_BYTES_PER_DOF,
    ELD_MAX_DOFS,
    MESH_PARAMETERS,
    MMS_MATERIAL,
    TIP_MASS_MAX_DOFS,
    body_material,
    body_mesh,
    check_beam_size,
    check_convergence_runs,
    check_damping_options,
    check_eld_step,
    check_mesh_options,
    check_mms_size,
    check_space_data,
    check_study_options,
    damping_of,
    damping_options,
    data_of,
    form_of,
    form_option,
    keep_option,
    lifting_option,
    material_of,
    material_options,
    mesh_fields,
    mesh_options,
    mms_options,
    parts_of,
    run_objects,
    scheme_of,
    scheme_option,
    step_options,
    summary_material,
)
from .registry import command
from .session import add_run_options, run_sequence

#: eld-beam: P2 with 3 cells across (3675 dofs): sideways reactions 0.4 % / 0.3 % (Euler) and
#: 0.5 % / 0.7 % (BDF2) of R_z, R_z within 0.03 % of n = 4 (P1 n = 3: 17 % / 27 %)
BEAM_DEFAULT_N = 3
BEAM_DEFAULT_DEGREE = 2
#: the note on a coarse mesh when a sideways reaction exceeds this fraction of R_z
BEAM_SIDEWAYS_NOTE = 0.02
#: eld-beam's material (rothe.eld.examples.beam_problem)
BEAM_MATERIAL = {"E": 1000.0, "nu": 0.3}
#: eld-pulse defaults (benchmarks/space_adaptivity.py)
PULSE_SPACE_TOL = 1e-3
PULSE_MAX_DOFS = 100_000
#: eld-pulse: adapt after every 6th step (a mesh change costs about 30 back-substitutions, the
#: band keeps the wave inside the refined region meanwhile; measured with the defaults, tau
#: 0.005: u(T) within 2.6 % of a 66k-dof uniform run in 8.9 s, adapt_every 4: 2.8 % in 16.6 s,
#: 8: 2.5 % in 10.9 s, 1: 2.4 % in 42 s)
PULSE_ADAPT_EVERY = 6
#: the help texts of ELD's band and hysteresis options (rothe.eld.adapt: the band follows the
#: pressure wave; no coarsening delay, no bound on re-coarsening, no coarsening batch)
ELD_HYSTERESIS = {
    "refine_band": "c_p tau adapt-every, the distance the pressure wave travels until the next "
    "adaptation",
    "coarsen_delay": 0,
    "max_recoarsen": None,
    "coarsen_batch": 0,
}


# -- summaries ----------------------------------------------------------------------------------


def energy_summary(traj) -> dict:
    """The energy identity at T, term by term (:mod:`rothe.eld.state`)."""
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


def format_energy_balance(e: dict) -> str:
    """The discrete energy identity at T, term by term (see rothe.eld.state)."""
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
    if e.get("numerical_boundary_term"):  # BDF2: N = N_G + S + (C^n - C^0), rothe.eld.state
        lines.insert(6, f"  {'    (G-form part N_G':<26} {e['dissipated_numerical_G']:>14.6g}")
        lines.insert(7, f"  {'     + step changes S':<26} {e['step_change']:>14.6g}")
        lines.insert(8, f"  {'     + C^n - C^0)':<26} {e['numerical_boundary_term']:>14.6g}")
    lines.append(f"  {'max |residual| per step':<26} {e['balance_residual_max']:>14.2e}")
    return "\n".join(lines)


def run_summary(result: ELDResult, example: str) -> dict:
    """The summary of a run: options, problem, statistics, reactions and energies at T, and
    (space adaptivity) the dofs and adaptations."""
    traj = result.trajectory
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
    if result.meshes is not None:
        summary.update(meshes_summary(traj, result.meshes))
    return summary


def meshes_summary(traj, meshes=None, space=None) -> dict:
    """Dofs over the run and the adaptations of a space-adaptive run -- ``run_eld``'s and the
    coupled runs' (``rothe run eld-tip-mass|eld-tmd|eld-control|eld-two-bodies
    --adapt-space``): ``adaptations`` after steps, ``meshes``, ``ndofs`` (the last state's),
    ``ndofs_initial``, ``ndofs_max``, ``ndofs_summed_over_steps``, ``refinements_in_steps`` (a
    step's own mesh refined and the step solved again: run_eld), ``bisections`` and ``merges``
    of both, ``transfer_energy`` (the ledger's ``transfer`` at the end).

    ``traj``: the trajectory (point series ``ndofs``, ``mesh_id``, ``transfer``; step series
    ``step_refinements``, ``step_bisections`` where the stepper refines in steps); ``meshes``:
    the run's series of meshes and log of adaptations (:class:`rothe.eld.adapt.ELDMeshes`),
    None for a run that stopped before it had a result (then the counts come from the
    states' mesh ids, ``bisections`` and ``merges`` are None); ``space``: the adaptivity
    options as described (default the trajectory's meta ``space``)."""
    dofs = np.asarray(traj["ndofs"])
    # refinements inside a step (the step solved again on its refined mesh) count too
    in_steps = int(np.sum(traj["step_bisections"])) if "step_bisections" in traj else 0
    rounds = int(np.sum(traj["step_refinements"])) if "step_refinements" in traj else 0
    if meshes is not None:
        log = meshes.adaptations
        adaptations, count = len(log), len(meshes.series.ids)
        bisections = int(sum(a["bisections"] for a in log)) + in_steps
        merges = int(sum(a["merges"] for a in log))
    else:
        ids = np.asarray(traj["mesh_id"])
        adaptations, count = int(np.count_nonzero(np.diff(ids))), int(np.unique(ids).size)
        bisections = merges = None
    return {
        "space": traj.meta.get("space") if space is None else space,  # (the key since issue 8)
        "adaptations": adaptations,
        "meshes": count,
        "ndofs": int(dofs[-1]),
        "ndofs_initial": int(dofs[0]),
        "ndofs_max": int(dofs.max()),
        "ndofs_summed_over_steps": int(dofs[1:].sum()),
        "refinements_in_steps": rounds,
        "bisections": bisections,
        "merges": merges,
        "transfer_energy": float(traj["transfer"][-1]),
    }


# -- the run sequence -----------------------------------------------------------------------------


class EldRunCommand:
    """Base of the ELD run commands: the one run sequence (run -> stage -> annotate -> write ->
    finish, :meth:`run`)."""

    name = ""
    #: the summary fields printed after a completed run
    keys: tuple = ()

    def report(self, args, summary: dict) -> None:
        """Print what the command adds after the summary of a completed run."""

    def summary_keys(self, args) -> tuple:
        """The summary fields printed after a completed run (:attr:`keys`)."""
        return self.keys

    def add_common_options(self, parser, **space) -> None:
        """The options every ELD run command ends with: the space options (``space``: the
        command's defaults for :func:`~rothe.cli.adapt_options.add_space_options`), the
        outputs and the run options."""
        add_space_options(parser, norms=True, **space)
        add_output_options(parser, self.name)
        add_run_options(parser)

    @staticmethod
    def step_checks(args):
        """The checks every ELD run command starts with: --tau against T, the run's objects
        (scheme, form, control, data: :func:`~rothe.cli.eld_options.run_objects`) and
        --keep-every. Returns ``(objects, keep)``."""
        check_eld_step("--tau", args.tau, args.T)
        return run_objects(args), check_int("--keep-every", args.keep_every, minimum=1)

    def run(self, args, problem, options: dict, label: str, summarize, stream=None) -> int:
        """Run ``problem`` with the :func:`rothe.eld.run_eld` keywords ``options`` as a session;
        write the result (also of a failed or interrupted run), the summary last; print.

        ``summarize(summary, result, completed)`` adds the command's fields to the summary;
        ``stream(session, options)`` opens a writer that streams the steps while the run goes
        (it may set ``options``'s observer; None: the outputs are written at the end)."""
        streams = []  # the stream writer, once the session is open
        prepared = []

        def prepare(session):
            if stream is not None:
                streams.append(stream(session, options))

        def start(checkpoint, resume, progress):
            run = prepare_eld_run(problem, checkpoint=checkpoint, resume=resume, **options)
            prepared.append(run)
            return run.evolve(progress=progress)

        def write(stage, outcome):
            result = _result_of(outcome, prepared, problem)
            if result is None:
                return None
            writer = streams[0] if streams else None
            completed = outcome.status == "completed"
            return self.write_result(args, stage, result, completed, writer, summarize, label)

        def discard():
            if streams:
                streams[0].discard()

        code, outcome, results, summary = run_sequence(
            args, self.name, start, write, prepare=prepare, completed=discard
        )
        if outcome is not None and outcome.status == "completed":
            self.print_result(args, results, summary)
        return code

    def write_result(
        self, args, stage, result: ELDResult, completed: bool, writer, summarize, label
    ) -> dict:
        """Write ``result`` into the staging directory ``stage`` and return its summary (the
        ``write`` step of :func:`~rothe.cli.session.run_sequence`, also of ``eld-beam --backend
        petsc`` on rank 0): the streamed XDMF of ``writer`` (None: XDMF from the kept states),
        :func:`run_summary` with the command's fields (``summarize``), trajectory and figures."""
        if writer is not None:
            writer.export(stage)
        summary = run_summary(result, self.name)
        if writer is not None:
            summary.update(xdmf=[p.name for p in writer.paths], xdmf_steps=writer.steps_written)
        summarize(summary, result, completed)
        write_eld_result(
            result,
            stage,
            name=self.name.replace("eld-", ""),
            xdmf=writer is None and "kept_t" in result.trajectory,
            figures=(completed and not args.no_plots and "energy" in result.trajectory),
            title=label,
        )
        return summary

    def print_result(self, args, results, summary: dict) -> None:
        """What a completed run prints (unless --quiet): where it wrote, the summary, the
        energy balance and the command's report."""
        if args.quiet:
            return
        print(f"rothe run {self.name}: wrote {results}/")
        keys = self.summary_keys(args)
        print_summary(summary, dofs_keys(keys, summary, "ndofs", "ndofs_initial", "ndofs_max"))
        print(format_energy_balance(summary))
        self.report(args, summary)


def _result_of(outcome, prepared: list, problem) -> ELDResult | None:
    """The run's result: the completed run's, or what a failed or interrupted run has (its
    trajectory so far, the problem and the series of meshes); None without a trajectory."""
    if outcome.status == "completed":
        return outcome.result
    traj = outcome.result
    if traj is None:
        return None
    if prepared:
        return prepared[0].result()
    return ELDResult(traj, None, None, None, problem, None)


# -- the run commands -------------------------------------------------------------------------

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
class RunEldMMS(EldRunCommand):
    """``rothe run eld-mms``: the manufactured solution (errors of u, v, lambda)."""

    help = (
        "Manufactured solution on the unit square: time-dependent Dirichlet data by a "
        "multiplier, traction, nonlinear damping (Altmann 2015, scheme (3.4))"
    )
    name = "eld-mms"
    keys = MMS_KEYS
    #: the library's parameters by their options (materials, regions of --material/--region)
    parameter_options = MESH_PARAMETERS

    def configure(self, parser) -> None:
        """The step options, --steps, --load-quadrature, --keep-every, --dirichlet, --start, the
        manufactured solution's options, the space options and the outputs.
        """
        step_options(parser, 0.01)
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
        keep_option(parser, 1)
        parser.add_argument(
            "--dirichlet",
            default="left",
            metavar="PART[,PART]",
            help="comma-separated Dirichlet parts (default left; with --mesh every physical "
            "group of the boundary); the exact traction on the rest",
        )
        mesh_options(parser, dirichlet=None)
        parser.add_argument(
            "--start",
            default="exact",
            help="exact | rest: initial data u(0), u'(0) of the solution, or zero "
            "(inconsistent with G(0): refused, Remark 2.2) (default exact)",
        )
        mms_options(parser)
        self.add_common_options(
            parser, default_max_dofs=ELD_MAX_DOFS["2d"], hysteresis=ELD_HYSTERESIS
        )

    def validate(self, args):
        """The checks that need no mesh (also run by ``rothe sweep`` before any run starts)."""
        check_damping_options(args)
        objects, keep = self.step_checks(args)
        check_mesh_options(args, ("--n",))
        n = check_int("--n", args.n, minimum=1)
        if args.mesh is None:
            check_mms_size(n, args.degree)
        # (--mesh without --dirichlet: every boundary part, read with the mesh in execute)
        parts = parts_of(args) if args.mesh is None or given(args, "--dirichlet") else None
        space = space_adaptivity(args, default_max_dofs=ELD_MAX_DOFS["2d"], hysteresis=True)
        check_space_data(args, space)
        # several materials (--material/--region, on the cell groups of --mesh): built with
        # the mesh in execute (materials_from's checks of the constants run there)
        material = None if args.material else material_of(args, MMS_MATERIAL)
        return objects, keep, n, parts, damping_of(args), space, material

    def execute(self, args) -> int:
        """Build the manufactured solution, run it as a session; the summary adds its errors."""
        objects, keep, n, parts, damping, space, material = self.validate(args)
        mesh = body_mesh(args)
        if material is None:
            material = body_material(args, MMS_MATERIAL, mesh)
        if parts is None:
            parts = tuple(boundary_part_names(mesh))
        problem, exact = mms_problem(
            n,
            args.degree,
            damping=damping,
            T=args.T,
            dirichlet=parts,
            start=args.start,
            load_quadrature=args.load_quadrature,
            material=material,
            mesh=mesh,
        )
        fit_default_cap(args, space, problem.space.ndofs)
        label = f"eld-mms, {objects['scheme'].name}, {objects['form'].name}, " + (
            f"tol={args.tol:g}" if args.tol else f"tau={args.tau:g}"
        )

        def summarize(summary, result, completed):
            summary.update({"n": n} if mesh is None else mesh_fields(args, mesh))
            summary.update(degree=args.degree, dirichlet=list(parts))
            summary["material"] = summary_material(args, MMS_MATERIAL, material)
            if completed:
                summary.update(mms_errors(exact, result))

        return self.run(
            args, problem, dict(objects, keep_every=keep, adapt=space), label, summarize
        )


#: --backend of eld-beam: the run's backends and ``auto`` (:meth:`RunEldBeam.backend`)
BEAM_BACKENDS = ("auto", *BACKENDS)


@command("run", "eld-beam")
class RunEldBeam(EldRunCommand):
    """``rothe run eld-beam``: the cantilever, XDMF streamed while it runs."""

    help = (
        "3D cantilever (E=1000, nu=0.3, rho=1): one end held and moved by G(t), the other "
        "free; the multiplier is the reaction at the held end (XDMF for ParaView)"
    )
    name = "eld-beam"
    #: the library's parameters by their options (materials, regions of --material/--region)
    parameter_options = MESH_PARAMETERS
    keys = (
        "example",
        "form",
        "scheme",
        "tau",
        "accepted_steps",
        "ndofs",
        "processes",
        "linear_solver",
        "krylov_iterations",
        "seconds_per_step",
        "peak_memory_mb",
        "reaction_left_final",
        "reaction_left_max_abs",
        "wall_time_s",
    )

    def configure(self, parser) -> None:
        """The step options, the beam's mesh, material, support motion and damping, the space
        options and the outputs.
        """
        step_options(parser, 0.01)
        parser.add_argument(
            "--n",
            type=int,
            default=BEAM_DEFAULT_N,
            help=f"cells across the unit cross-section (default {BEAM_DEFAULT_N}); "
            "round(length*n) along the beam",
        )
        float_option(parser, "--length", default=4.0, help="beam length (default 4)")
        parser.add_argument(
            "--degree",
            type=int,
            default=BEAM_DEFAULT_DEGREE,
            help=f"1 or 2 (default {BEAM_DEFAULT_DEGREE})",
        )
        float_option(parser, "--T", default=2.0, help="end time (default 2)")
        material_options(parser, BEAM_MATERIAL)
        mesh_options(
            parser,
            dirichlet="left",
            dirichlet_help="the held boundary parts, moved along z by G(t) (tetrahedra: --mesh "
            "is 3D)",
        )
        float_option(
            parser,
            "--amplitude",
            default=0.1,
            help="end displacement (z) of the held end's motion (default 0.1)",
        )
        float_option(
            parser,
            "--t-move",
            default=0.5,
            help="duration of the motion; held still afterwards (default 0.5)",
        )
        parser.add_argument("--solver", default="auto", help="auto | direct | amg (default auto)")
        parser.add_argument(
            "--save-every", type=int, default=5, help="write every k-th step to XDMF (default 5)"
        )
        parser.add_argument(
            "--backend",
            default="auto",
            help="auto | serial | petsc: serial is one process with pyamg; petsc one mesh on "
            "the processes of mpiexec -n N (or on one) with PETSc's GAMG; auto (default) takes "
            "petsc under mpiexec -n N > 1 and serial on one process, where its step is the "
            "faster one (docs/scaling.md)",
        )
        parser.add_argument(
            "--amg-products",
            default=None,
            help="fast | lean, with the petsc backend: how PETSc's GAMG forms its coarse "
            "operators; fast (default) PETSc's two-step products, lean the all-at-once ones, "
            "which never store A P: about 0.75x the peak memory per process on two processes, "
            "for a set-up 5-7x slower (docs/scaling.md)",
        )
        keep_option(parser, 5)
        damping_options(parser, default="rayleigh", default_b=0.002)
        self.add_common_options(
            parser, default_max_dofs=ELD_MAX_DOFS["3d"], hysteresis=ELD_HYSTERESIS
        )

    def validate(self, args):
        """The checks that need no mesh (also run by ``rothe sweep`` before any run starts)."""
        check_damping_options(args)
        objects, keep = self.step_checks(args)
        check_mesh_options(args, ("--n", "--length"))
        n = check_int("--n", args.n, minimum=1)
        check_beam_size(n, args.length, args.degree, args.solver)
        parts_of(args)
        every = check_int("--save-every", args.save_every, minimum=1)
        space = space_adaptivity(args, default_max_dofs=ELD_MAX_DOFS["3d"], hysteresis=True)
        # (--material: built on the mesh, in execute)
        material = None if args.material else material_of(args, BEAM_MATERIAL, dim=3)
        backend = self.backend(args)
        if backend == "petsc" and args.mesh is not None:
            raise fail(
                "--mesh",
                args.mesh,
                "is not supported with --backend petsc (the distributed beam builds its own "
                "box)"
                + ("" if args.backend == "petsc" else f" under mpiexec -n {launched_processes()}"),
            )
        if backend == "petsc" and space is not None:
            raise fail(
                "--adapt-space",
                described("given"),
                "is not supported with --backend petsc (space adaptivity is not distributed)"
                + ("" if args.backend == "petsc" else f" under mpiexec -n {launched_processes()}"),
            )
        if args.amg_products is not None:
            check_choice("--amg-products", args.amg_products, AMG_PRODUCTS)
            if backend != "petsc":
                raise fail(
                    "--amg-products",
                    args.amg_products,
                    "is an option of the petsc backend (PETSc's GAMG); this run takes the "
                    "serial backend (pyamg): use --backend petsc",
                )
        return objects, n, every, keep, damping_of(args), space, material, backend

    @staticmethod
    def backend(args) -> str:
        """--backend with ``auto`` resolved (the option's help; docs/scaling.md, "Which
        backend"): petsc under ``mpiexec -n N`` with N > 1 (every process would otherwise run
        the whole serial problem), the backend of the checkpoint a resumed run continues, and
        serial on one process, with or without petsc4py: its pyamg cycle (scipy's CG around
        :func:`rothe.fem.linear.v_cycle`) takes 0.87x the seconds per step of PETSc's GAMG
        on one process at 1.07 M dofs, and its set-up less (docs/scaling.md, seventh
        session). Until then, auto took petsc on one process where petsc4py was installed
        (0.81-0.85x the former pyamg step)."""
        backend = check_choice("--backend", args.backend, BEAM_BACKENDS)
        if backend != "auto":
            return backend
        if launched_processes() > 1:
            return "petsc"
        if getattr(args, "resume", None) is not None:
            try:
                header = load_checkpoint(args.resume, header_only=True).header
            except CheckpointError:  # the session says what is wrong with it
                return "serial"
            return "petsc" if header.get("arguments", {}).get("backend") == "petsc" else "serial"
        return "serial"

    def execute(self, args) -> int:
        """Build the cantilever, run it as a session (XDMF streamed while it runs); with
        ``--backend petsc`` on the processes of mpiexec (:mod:`rothe.cli.eld_mpi`)."""
        objects, n, every, keep, damping, space, material, backend = self.validate(args)
        if backend == "petsc":
            # mpi4py and petsc4py (optional, heavy) are imported only for this backend
            from .eld_mpi import execute_beam

            return execute_beam(self, args)
        # (before the materials are built on it; beam_problem checks the same)
        mesh = check_mesh_dim(body_mesh(args), 3, BEAM_MESH, "--mesh")
        if mesh is not None:
            material = body_material(args, BEAM_MATERIAL, mesh)
        problem = self.beam(args, n, damping, material, mesh)
        fit_default_cap(args, space, problem.space.ndofs)
        label = (
            f"eld-beam, {objects['scheme'].name}, {objects['form'].name}, "
            f"tau={args.tau:g}, {problem.space.ndofs} dofs"
        )
        options = dict(objects, solver=args.solver, keep_every=keep, linear_rtol=1e-8, adapt=space)

        def summarize(summary, result, completed):
            self.summarize(args, summary, result.trajectory, material, mesh)
            summary.update(backend="serial")  # which --backend auto took (as the petsc run)

        # a fixed mesh streams XDMF as it goes (checkpointed with the run); an adaptive run
        # writes one VTU per kept state on its own mesh at the end (rothe.eld.output)
        stream = (
            None
            if space is not None
            else (lambda session, opts: _beam_stream(session, problem, opts, every))
        )
        return self.run(args, problem, options, label, summarize, stream)

    @staticmethod
    def beam(args, n: int, damping, material, mesh=None):
        """The cantilever of the command line with ``n`` cells across (or the ``mesh`` of
        --mesh) and the ``material`` of :meth:`validate`, held on the --dirichlet parts
        (:func:`rothe.eld.examples.beam_problem`)."""
        return beam_problem(
            n,
            length=args.length,
            material=material,
            damping=damping,
            amplitude=args.amplitude,
            t_move=args.t_move,
            T=args.T,
            degree=args.degree,
            mesh=mesh,
            dirichlet=parts_of(args),
        )

    @staticmethod
    def stream_dir(session):
        """The directory of the streamed XDMF in the session's checkpoint directory, emptied
        for a new run (segments of an earlier run are not this run's)."""
        stream = session.checkpoint_dir / "stream"
        if session.resume is None:
            shutil.rmtree(stream, ignore_errors=True)
        return stream

    @staticmethod
    def frame_due(state, every: int, T: float) -> bool:
        """Whether the state after an accepted step is written: every ``every``-th step and the
        last (n tau may round to just below T: the last by a relative margin)."""
        return state.j % every == 0 or state.t >= T * (1.0 - 1e-12)

    def summarize(self, args, summary: dict, traj, material, mesh=None) -> None:
        """The beam's fields of the summary: its options (or the ``mesh`` of --mesh and its
        held parts), the ``material`` of :meth:`validate`, seconds per step, the reactions at
        the (first) held part and the fraction of the energy put in that the scheme
        dissipated."""
        fields = summary_material(args, BEAM_MATERIAL, material)
        # (one material: its E and nu at the top level too, before it, as the beam always had)
        summary.update({} if args.material else {"E": fields["E"], "nu": fields["nu"]})
        summary["material"] = fields
        if mesh is None:
            summary.update(n=args.n, length=args.length)
        else:
            summary.update(mesh_fields(args, mesh), dirichlet=list(parts_of(args)))
        summary.update(
            degree=args.degree,
            amplitude=args.amplitude,
            t_move=args.t_move,
            seconds_per_step=traj.stats.wall_time_s / max(traj.stats.accepted_steps, 1),
        )
        if traj.stats.accepted_steps:
            summary.update(_beam_reactions(traj, parts_of(args)[0]))
            put_in = summary["work_support"] + summary["work_loads"]
            summary["numerical_dissipation_fraction"] = (
                summary["dissipated_numerical"] / put_in if put_in > 0 else None
            )

    def summary_keys(self, args) -> tuple:
        """:attr:`keys` with the reactions of the first --dirichlet part (``left`` on the box)."""
        part = parts_of(args)[0]
        return tuple(k.replace("reaction_left_", f"reaction_{part}_") for k in self.keys)

    def report(self, args, summary) -> None:
        """Print the numerical dissipation against the work put in, and a note when the sideways
        reactions show a too coarse mesh.
        """
        put_in = summary["work_support"] + summary["work_loads"]
        sideways = summary["reaction_sideways_over_z"]
        print(
            f"numerical dissipation: {summary['dissipated_numerical']:.4g} of the "
            f"{put_in:.4g} put in by the support and the loads (physical damping "
            f"{summary['dissipated_physical']:.4g})"
        )
        if max(sideways) > BEAM_SIDEWAYS_NOTE:
            finer = "a larger --n" if args.mesh is None else "a finer --mesh"
            remedy = finer if args.degree >= 2 else f"--degree 2 or {finer}"
            print(
                f"note: coarse mesh for the reactions: the sideways reactions are "
                f"{100 * sideways[0]:.1f} % (x) and {100 * sideways[1]:.1f} % (y) of "
                f"R_z, zero for the exact solution; use {remedy}"
            )


@command("run", "eld-pulse")
class RunEldPulse(EldRunCommand):
    """``rothe run eld-pulse``: the boundary pulse on adaptive meshes."""

    help = (
        "A 2D body (or any 2D/3D --mesh) hit by a short boundary pulse: the wave front crosses "
        "the body, adaptive meshes refine on it and coarsen behind it (space adaptivity)"
    )
    name = "eld-pulse"
    parameter_options = MESH_PARAMETERS
    keys = (
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
        "refinements_in_steps",
        "meshes",
        "bisections",
        "merges",
        "transfer_energy",
        "wall_time_s",
    )

    def configure(self, parser) -> None:
        """The step options (BDF2 by default), the body, the pulse, the material and damping,
        --lifting, --keep-every, the space options (on by default) and the outputs.
        """
        step_options(parser, 0.005, scheme_default="bdf2")
        parser.add_argument(
            "--n",
            type=int,
            default=4,
            help="cells across the height of the initial mesh (default 4; round(length*n) along)",
        )
        parser.add_argument("--degree", type=int, default=2, help="1 or 2 (default 2)")
        float_option(
            parser,
            "--length",
            default=2.0,
            help="length of the body [0, length] x [0, 1] (default 2)",
        )
        float_option(
            parser,
            "--T",
            default=0.8,
            help="end time (default 0.8: the pressure front crosses 80 %%)",
        )
        float_option(
            parser,
            "--amplitude",
            default=0.01,
            help="peak displacement of the pulse (default 0.01)",
        )
        float_option(
            parser,
            "--t-pulse",
            default=0.1,
            help="duration of the pulse (default 0.1)",
        )
        float_option(
            parser,
            "--width",
            default=0.1,
            help="width of the pushed part around y = 1/2 (default 0.1)",
        )
        material_options(parser, MMS_MATERIAL, rho=1.0, plane="strain")
        mesh_options(
            parser,
            dirichlet="left",
            dirichlet_help="boundary parts held by the multiplier, the first pushed by the pulse "
            "(along its mean inward normal, around its centre), the others held still; the "
            "rest is free",
        )
        float_option(
            parser,
            "--b",
            default=0.001,
            help="Rayleigh stiffness-proportional damping b (default 0.001)",
        )
        lifting_option(parser)
        keep_option(parser, 10)
        self.add_common_options(
            parser,
            on=True,
            default_tol=PULSE_SPACE_TOL,
            default_max_dofs=PULSE_MAX_DOFS,
            hysteresis=ELD_HYSTERESIS,
            default_adapt_every=PULSE_ADAPT_EVERY,
        )

    #: the space options' defaults (eld-pulse-3d has its own)
    space_defaults = dict(
        default_tol=PULSE_SPACE_TOL,
        default_max_dofs=PULSE_MAX_DOFS,
        default_adapt_every=PULSE_ADAPT_EVERY,
    )

    def pulse_checks(self, args):
        """The checks of the step, size, pulse and space options (eld-pulse and eld-pulse-3d).
        Returns ``(objects, keep, n, length, space)``."""
        objects, keep = self.step_checks(args)
        n = check_int("--n", args.n, minimum=1)
        if args.degree not in (1, 2):
            raise fail("--degree", args.degree, "must be 1 or 2")
        length = check_positive("--length", args.length)
        for option in ("--t-pulse", "--width"):
            check_positive(option, getattr(args, option.lstrip("-").replace("-", "_")))
        space = space_adaptivity(args, hysteresis=True, **self.space_defaults)
        return objects, keep, n, length, space

    def run_pulse(self, args, problem, objects, keep, space, grid, mesh, parts, material):
        """Run the pulse ``problem`` (2D or 3D: this command's) as a session: its label, and
        its summary's grid (``grid`` = (n, length)) or mesh file with the held parts, the
        pulse's parameters and the material."""
        fit_default_cap(args, space, problem.space.ndofs)
        label = f"{self.name}, {objects['scheme'].name}, {objects['form'].name}, " + (
            f"space_tol={space.space_tol:g}" if space else "fixed mesh"
        )

        def summarize(summary, result, completed):
            if mesh is None:
                summary.update(n=grid[0], length=grid[1])
            else:
                summary.update(mesh_fields(args, mesh), dirichlet=list(parts))
            summary.update(degree=args.degree, t_pulse=args.t_pulse, width=args.width)
            summary["material"] = summary_material(args, MMS_MATERIAL, material)

        return self.run(
            args, problem, dict(objects, keep_every=keep, adapt=space), label, summarize
        )

    def validate(self, args):
        """The checks that need no mesh (also run by ``rothe sweep`` before any run starts)."""
        check_mesh_options(args, ("--n", "--length"))
        objects, keep, n, length, space = self.pulse_checks(args)
        if args.mesh is None:
            check_mms_size(max(n, round(n * length)), args.degree)
        parts = parts_of(args)
        if args.mesh is None and not args.material:
            material_of(args, MMS_MATERIAL)  # (on a mesh: in its dimension, when loaded)
        return objects, keep, n, length, space, parts

    def execute(self, args) -> int:
        """Build the pulse problem and run it as a session."""
        objects, keep, n, length, space, parts = self.validate(args)
        mesh = body_mesh(args)
        material = body_material(args, MMS_MATERIAL, mesh)
        problem = pulse_problem(
            n,
            args.degree,
            length=length,
            amplitude=args.amplitude,
            t_pulse=args.t_pulse,
            width=args.width,
            b=args.b,
            T=args.T,
            material=material,
            mesh=mesh,
            dirichlet=parts,
        )
        return self.run_pulse(
            args, problem, objects, keep, space, (n, length), mesh, parts, material
        )


#: eld-pulse-3d defaults (docs/adaptivity.md, benchmarks/space_adaptivity.py --family eld3d)
PULSE3D_SPACE_TOL = 8e-3
PULSE3D_MAX_DOFS = 150_000
PULSE3D_ADAPT_EVERY = 4


@command("run", "eld-pulse-3d")
class RunEldPulse3d(RunEldPulse):
    """``rothe run eld-pulse-3d``: the boundary pulse in a 3D block on adaptive meshes
    (:func:`rothe.eld.examples.pulse_3d_problem`, P2 by default: why in its docstring)."""

    help = (
        "The block [0, length] x [0, 1] x [0, 1] pushed by a short pulse around the centre of "
        "its face x = 0: the pressure and shear fronts cross it, adaptive tetrahedral meshes "
        "refine on them and coarsen behind (P2 by default)"
    )
    name = "eld-pulse-3d"
    parameter_options = MESH_PARAMETERS
    space_defaults = dict(
        default_tol=PULSE3D_SPACE_TOL,
        default_max_dofs=PULSE3D_MAX_DOFS,
        default_adapt_every=PULSE3D_ADAPT_EVERY,
    )

    def configure(self, parser) -> None:
        """The step options (BDF2, tau 0.01), the block, the pulse, the material and damping,
        --lifting, --keep-every, the space options (on by default) and the outputs."""
        step_options(parser, 0.01, scheme_default="bdf2")
        parser.add_argument(
            "--n",
            type=int,
            default=2,
            help="cubes (of six tetrahedra) across the block's cross-section in the initial "
            "mesh (default 2; round(length*n) along x)",
        )
        parser.add_argument(
            "--degree", type=int, default=2, help="1 or 2 (default 2: P2, see the docs)"
        )
        float_option(
            parser, "--length", default=1.0, help="length of the block along x (default 1)"
        )
        float_option(
            parser,
            "--T",
            default=0.5,
            help="end time (default 0.5: the pressure front reaches x = 1)",
        )
        float_option(
            parser,
            "--amplitude",
            default=0.01,
            help="peak displacement of the pulse (default 0.01)",
        )
        float_option(parser, "--t-pulse", default=0.1, help="duration of the pulse (default 0.1)")
        float_option(
            parser,
            "--width",
            default=0.15,
            help="width of the pushed spot around (0, 1/2, 1/2) (default 0.15)",
        )
        material_options(parser, MMS_MATERIAL, rho=1.0)
        mesh_options(
            parser,
            dirichlet="left",
            dirichlet_help="boundary parts held by the multiplier (tetrahedra: --mesh is 3D), the "
            "first pushed by the pulse (along its mean inward normal, around its centre), the "
            "others held still; the rest is free",
        )
        float_option(
            parser,
            "--b",
            default=0.001,
            help="Rayleigh stiffness-proportional damping b (default 0.001)",
        )
        lifting_option(parser)
        keep_option(parser, 10)
        self.add_common_options(
            parser,
            on=True,
            default_tol=PULSE3D_SPACE_TOL,
            default_max_dofs=PULSE3D_MAX_DOFS,
            hysteresis=ELD_HYSTERESIS,
            default_adapt_every=PULSE3D_ADAPT_EVERY,
        )

    def validate(self, args):
        """The checks of eld-pulse (:meth:`RunEldPulse.pulse_checks`), the block's size
        against the memory, the material."""
        check_mesh_options(args, ("--n", "--length"))
        objects, keep, n, length, space = self.pulse_checks(args)
        check_beam_size(n, length, args.degree, "auto")  # the same box of P1/P2 nodes
        parts = parts_of(args)
        # (--material: built on the mesh, in execute)
        material = None if args.material else material_of(args, MMS_MATERIAL, dim=3)
        return objects, keep, n, length, space, material, parts

    def execute(self, args) -> int:
        """Build the 3D pulse problem and run it as a session."""
        objects, keep, n, length, space, material, parts = self.validate(args)
        # (before the materials are built on it; pulse_3d_problem checks the same)
        mesh = check_mesh_dim(body_mesh(args), 3, PULSE_3D_MESH, "--mesh")
        if mesh is not None:
            material = body_material(args, MMS_MATERIAL, mesh)
        problem = pulse_3d_problem(
            n,
            args.degree,
            length=length,
            amplitude=args.amplitude,
            t_pulse=args.t_pulse,
            width=args.width,
            b=args.b,
            T=args.T,
            material=material,
            mesh=mesh,
            dirichlet=parts,
        )
        return self.run_pulse(
            args, problem, objects, keep, space, (n, length), mesh, parts, material
        )


def _beam_stream(session, problem, options: dict, every: int) -> EldXdmfWriter:
    """The beam's XDMF writer in the checkpoint directory (an attachment of the run's
    checkpoint, so a resumed run continues it), fed by the observer with the initial state
    (lambda(0) included: both series start at t = 0) and every ``every``-th step."""
    writer = EldXdmfWriter(RunEldBeam.stream_dir(session), problem, name="beam")

    def observer(state, result):
        if result is None:  # the initial state (not on resume): u0, v0 and lambda(0)
            writer.write(0.0, problem.u0, problem.v0, state.lam)
            return
        if RunEldBeam.frame_due(state, every, problem.T):
            writer.write(state.t, state.u, state.v, result.lam)

    options["observer"] = observer
    session.checkpoint.attachments = {"xdmf": writer}
    return writer


def _beam_reactions(traj, part: str = "left") -> dict:
    """The peak reactions at the held ``part`` and the sideways ones relative to R_z (the motion
    is purely in z and the beam symmetric: R_x, R_y vanish for the exact solution)."""
    peak = np.max(np.abs(traj[f"reaction_{part}"]), axis=0)
    sideways = (peak[:2] / peak[2]).tolist() if peak[2] > 0 else [0.0, 0.0]
    return {f"reaction_{part}_max_abs": peak.tolist(), "reaction_sideways_over_z": sideways}


# -- studies --------------------------------------------------------------------------------------


def run_study(name: str, args, study_fn, *positional, **options):
    """Run ``study_fn(*positional, **options)`` on the manufactured solution of the command line
    (``--n``, ``--degree``, the damping) with its progress and executor (``rothe study
    <name>``); returns the study and the output directory."""
    n = check_int("--n", args.n, minimum=1)
    damping = damping_of(args)
    executor = executor_from_args(args, f"rothe study {name}")
    out = output_dir(args, name)
    study = study_fn(
        *positional,
        n=n,
        degree=args.degree,
        damping=damping,
        progress=progress_of(args),
        executor=executor,
        **options,
    )
    return study, out


def write_study(args, out, study: dict, table: str, draw) -> None:
    """The outputs of an ELD study: ``table.txt``, ``summary.json`` (the study with the peak
    memory), the figures (``draw()``, unless --no-plots) and, unless --quiet, the table."""
    write_table(out, table + "\n")
    study["peak_memory_mb"] = peak_memory_mb()
    write_summary(out, study)
    if not args.no_plots:
        draw()
    if not args.quiet:
        print(table)
        print(f"wrote {out}/")


@command("study", "eld-convergence")
class StudyEldConvergence:
    """``rothe study eld-convergence``: order in tau on the manufactured solution."""

    help = "Order in tau of both forms on the manufactured solution (tau halved repeatedly)"
    name = "eld-convergence"

    def configure(self, parser) -> None:
        """--form, --scheme, --tau0, --halvings, the manufactured solution's options, the outputs
        and the executor.
        """
        form_option(parser)
        scheme_option(parser)
        float_option(parser, "--tau0", default=0.1, help="largest step (default 0.1)")
        parser.add_argument(
            "--halvings", type=int, default=5, help="times tau is halved (default 5)"
        )
        mms_options(parser, n=4, plane=False)
        add_output_options(parser, self.name)
        add_parallel_options(parser)

    def execute(self, args) -> int:
        """Run the convergence study (tau halved ``--halvings`` times); write its table and
        figures.
        """
        check_damping_options(args)
        check_eld_step("--tau0", args.tau0, args.T)
        check_mms_size(check_int("--n", args.n, minimum=1), args.degree)
        check_study_options(args)
        form = form_of(args)
        scheme = scheme_of(args)
        halvings = check_int("--halvings", args.halvings, minimum=1)
        data = data_of(args)
        material = material_of(args, MMS_MATERIAL)
        # what every run would refuse, before the cluster starts or --out is made (issue 21)
        check_convergence_runs(args, scheme, data)
        study, out = run_study(
            self.name,
            args,
            convergence_study,
            form,
            tau0=args.tau0,
            halvings=halvings,
            rho=args.rho,
            lam=material.lam,
            mu=material.mu,
            T=args.T,
            data=data,
            scheme=scheme,
        )
        table = format_convergence_table(study)

        def draw():
            # matplotlib is imported only for the figures
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
                title=f"eld-mms, {scheme.name}, {form.name}, P{study['degree']}",
                order=scheme.order,
            )

        write_study(args, out, study, table, draw)
        return 0 if all("status" not in r for r in study["rows"]) else 1


@command("study", "eld-perturbation")
class StudyEldPerturbation:
    """``rothe study eld-perturbation``: Theorem 4.5, the amplification of noise."""

    help = (
        "Theorem 4.5: amplification of delta-noise in each of G, G', G'' and F alone by "
        "both forms, for tau from 1e-1 to 1e-3"
    )
    name = "eld-perturbation"
    #: the study's defaults and what it perturbs (the coupled study below overrides them)
    taus = (0.1, 0.05, 0.02, 0.01, 0.005, 0.002, 0.001)
    n, degree, T = 6, 1, 1.0
    damping = "nonlinear"
    targets = NOISE_TARGETS
    study = staticmethod(perturbation_study)

    def configure(self, parser) -> None:
        """--taus, --delta, --n, --degree, --seed, --targets, --scheme, the damping, the outputs and
        the executor.
        """
        taus = ",".join(f"{t:g}" for t in self.taus)
        parser.add_argument(
            "--taus",
            type=parse_float_list("--taus"),
            default=list(self.taus),
            help=f"step sizes (default {taus})",
        )
        float_option(
            parser,
            "--delta",
            default=1e-6,
            help="size of the noise (default 1e-6)",
        )
        parser.add_argument(
            "--n", type=int, default=self.n, help=f"cells across (default {self.n})"
        )
        parser.add_argument(
            "--degree", type=int, default=self.degree, help=f"1 or 2 (default {self.degree})"
        )
        parser.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
        parser.add_argument(
            "--targets",
            default=",".join(self.targets),
            help=f"the data perturbed, each alone (default {','.join(self.targets)})",
        )
        scheme_option(parser)
        damping_options(parser, default=self.damping)
        add_output_options(parser, self.name)
        add_parallel_options(parser)

    def check_problem(self, args) -> None:
        """What the study's problem refuses, before its cluster starts: the manufactured
        solution's size."""
        check_mms_size(check_int("--n", args.n, minimum=1), args.degree)

    def execute(self, args) -> int:
        """Run the perturbation study of Theorem 4.5 for every ``--taus``; write its table and
        figures.
        """
        check_damping_options(args)
        for t in args.taus:
            check_eld_step("--taus", t, self.T)
        self.check_problem(args)
        taus = [check_positive("--taus", t) for t in args.taus]
        if len(taus) < 2:
            raise fail("--taus", ",".join(map(str, args.taus)), "needs at least two step sizes")
        targets = check_noise_targets("--targets", args.targets, self.targets)
        check_int("--seed", args.seed, minimum=0)
        check_delta("--delta", args.delta)
        scheme = scheme_of(args)
        study, out = run_study(
            self.name,
            args,
            self.study,
            taus,
            delta=args.delta,
            targets=targets,
            seed=args.seed,
            scheme=scheme,
            rho=args.rho,
        )
        table = format_perturbation_table(study)
        labels = study.get("norms", {})

        def draw():
            # matplotlib is imported only for the figures
            from ..eld.figures import plot_perturbation

            for target in targets:
                plot_perturbation(
                    study["tau"],
                    study[target],
                    out / f"fig_perturbation_{target}.png",
                    title=f"{scheme.name}: noise in {target}, delta = {args.delta:g}",
                    labels=labels if "columns" in study else None,
                )

        write_study(args, out, study, table, draw)
        return 0 if "failed" not in study else 1


@command("study", "eld-coupled-perturbation")
class StudyEldCoupledPerturbation(StudyEldPerturbation):
    """``rothe study eld-coupled-perturbation``: Theorem 4.5 with a coupling (issue 19)."""

    help = (
        "Theorem 4.5 with a coupling: noise in the tip mass's coordinates as the body sees "
        "them (q, q', q'' in g, g', g''), both forms (the tip-mass bar, B u = q)"
    )
    name = "eld-coupled-perturbation"
    taus = (0.02, 0.01, 0.005, 0.0025, 0.00125, 0.000625)
    n, degree, T = 2, 2, 0.2
    # the coupled step takes linear damping only
    damping = "rayleigh"
    targets = COUPLED_TARGETS
    study = staticmethod(coupled_perturbation_study)

    def check_problem(self, args) -> None:
        """The tip-mass bar of --n, --degree and the damping (built once here: it refuses a
        mesh with too few axial modes, naming --n)."""
        tip_mass_problem(args.n, args.degree, rho=args.rho, T=self.T, damping=damping_of(args))


@command("study", "eld-tip-mass")
class StudyEldTipMass:
    """``rothe study eld-tip-mass``: the first frequency of the tip-mass bar in h and tau."""

    help = (
        "The tip-mass bar's first axial frequency measured from runs against the analytic "
        "value, for every mesh (--ns) and step (--taus): the error split into space and time, "
        "fitted orders"
    )
    name = "eld-tip-mass"

    def configure(self, parser) -> None:
        """--ns, --taus, --degree, --scheme, --form, --mass, --T, the outputs and the executor."""
        parser.add_argument(
            "--ns",
            type=parse_float_list("--ns"),
            default=[1, 2, 4],
            help="cells across the strip, one mesh each (default 1,2,4)",
        )
        parser.add_argument(
            "--taus",
            type=parse_float_list("--taus"),
            default=[0.01, 0.005, 0.0025],
            help="step sizes (default 0.01,0.005,0.0025)",
        )
        parser.add_argument("--degree", type=int, default=2, help="1 or 2 (default 2)")
        scheme_option(parser, default="bdf2")
        form_option(parser)
        float_option(
            parser, "--mass", default=0.25, help="tip mass (default 0.25 = the bar's mass)"
        )
        float_option(parser, "--T", default=2.0, help="end time (default 2: ~2.7 periods)")
        parser.add_argument(
            "--dim",
            type=int,
            default=2,
            help="2: the plane-stress strip 1 x 0.25, n cells across; 3: the bar 1 x 0.25 x "
            "0.25, n x n cubes across (6 tetrahedra each) (default 2)",
        )
        parser.add_argument(
            "--modes",
            type=parse_int("--modes", minimum=1),
            default=3,
            metavar="K",
            help="start every run in the sum of the first K axial modes and measure their K "
            "frequencies from its modal coordinates (default 3)",
        )
        add_output_options(parser, self.name)
        add_parallel_options(parser)

    def execute(self, args) -> int:
        """Run every (n, tau); write the table and the figure."""
        ns = [check_int("--ns", n, minimum=1) for n in args.ns]
        T = check_positive("--T", args.T)
        taus = [check_eld_step("--taus", t, T) for t in args.taus]
        if len(ns) < 2 and len(taus) < 2:
            raise fail(
                "--ns",
                ",".join(f"{n:g}" for n in args.ns),
                "needs two meshes, or --taus two step sizes, to fit an order",
            )
        if args.degree not in (1, 2):
            raise fail("--degree", args.degree, "must be 1 or 2")
        check_positive("--mass", args.mass)
        dim = args.dim
        if dim not in (2, 3):
            raise fail("--dim", dim, "must be 2 or 3")
        for n in ns:  # the strip has 4n x n cells, the 3D bar 4n x n x n cubes
            dofs = dim * (args.degree * 4 * n + 1) * (args.degree * n + 1) ** (dim - 1)
            check_memory("--ns", n, dofs, ELD_BYTES_PER_DOF["2d"], what="unknowns")
            if dim == 3 and dofs > TIP_MASS_MAX_DOFS:
                raise fail(
                    "--ns",
                    n,
                    f"gives {dofs} unknowns in 3D (P{args.degree}), must give at most "
                    f"{TIP_MASS_MAX_DOFS} (the reference frequencies come from a dense modal "
                    "analysis)",
                )
        scheme, form = scheme_of(args), form_of(args)
        # the coarsest bar refuses a mesh with too few axial modes, naming --ns, before the
        # cluster starts
        check_int("--modes", args.modes, minimum=1)
        try:
            tip_mass_problem(
                min(ns),
                args.degree,
                mass=args.mass,
                T=T,
                mesh=tip_mass_bar(min(ns), dim),
                modes=args.modes,
            )
        except RotheInputError as err:  # (the library's name for the option's)
            if err.parameter != "modes":
                raise
            raise err.renamed("--modes") from None
        executor = executor_from_args(args, f"rothe study {self.name}")
        out = output_dir(args, self.name)
        study = tip_mass_study(
            ns,
            taus,
            degree=args.degree,
            scheme=scheme,
            form=form,
            mass=args.mass,
            T=T,
            dim=dim,
            modes=args.modes,
            executor=executor,
        )
        table = format_tip_mass_table(study)

        def draw():
            # matplotlib is imported only for the figures
            from ..eld.figures import plot_tip_mass_study

            plot_tip_mass_study(
                study,
                out / "fig_tip_mass_frequency.png",
                title=f"eld-tip-mass: first {args.modes} axial frequencies, {dim}D, "
                f"P{args.degree}, m = {args.mass:g}",
            )

        write_study(args, out, study, table, draw)
        return 0 if "failed" not in study else 1
