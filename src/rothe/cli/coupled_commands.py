"""CLI commands for elastic bodies coupled to other dynamical systems (issue 19):
``rothe run eld-tip-mass|eld-tmd|eld-control|eld-two-bodies``.

Every command runs :func:`rothe.eld.coupled_run.run_coupled` through the one run sequence of
the ``run`` commands (:func:`rothe.cli.session.run_sequence`: run -> stage -> write -> annotate
-> summary last -> finish): results staged and committed together with ``summary.json`` last,
an earlier completed result never destroyed, a run stopped by SIGINT/SIGTERM writes what it has
(``status: interrupted``, exit 130/143) and a checkpoint, a failed run ``status: failed`` (exit
1). Checkpoints in ``OUT/checkpoint`` (``--checkpoint-every``, ``--resume DIR``, ``rothe resume
OUT``, as the other run commands): the commands that compare two runs checkpoint both as one
(:func:`rothe.eld.coupled_run.run_coupled_many`); a resumed run writes the uninterrupted run's
results bit for bit; a resume with other options is refused in one line (exit 2). ParaView
output of every command, one series per body and run (:mod:`rothe.eld.bodies_output`):
eld-two-bodies ``body1``, ``body2``; the one-body commands ``body`` and, for the second run,
``body_<label>``; ``.xdmf`` (with ``_multiplier.xdmf``) on a fixed mesh, with
``--adapt-space`` the adaptive body as a ``.pvd``, one VTU per state on its own mesh
(docs/coupling.md, Sec. 14).

``--adapt-space`` (every command; with ``--space-tol`` and the usual options of
:mod:`rothe.cli.adapt_options`) adapts the mesh of the elastic body between accepted steps
(:mod:`rothe.eld.coupled_adapt`; eld-two-bodies: body 1, the base); ``trajectory.npz`` then
also holds every mesh once (``mesh_ids``, ``mesh_points_<k>``, ``mesh_cells_<k>``,
``state_mesh_id``) and the series ``mesh_id``, ``ndofs``, ``space_estimate``, ``transfer``.

Outputs: ``summary.json``, ``trajectory.npz`` (the run's q, p, z, the reactions on every
constrained part, the whole-system ledger per state, the steps: see
:class:`rothe.eld.coupled_run.CoupledResult`), for the commands that compare two runs the
second as ``trajectory_<label>.npz`` (``trajectory_without_tmd.npz``,
``trajectory_uncontrolled.npz``; every run records its body's fields: ``u``, ``v``, ``lam``,
``pdot`` per state, or the kept fields on their meshes with ``--adapt-space``), the ParaView
series above, and a figure unless ``--no-plots``. Bad input is one line and exit status 2.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial import cKDTree

from ..eld.bodies import Body, GluedBodies, strip_pair, strip_pair_dofs, strip_union
from ..eld.bodies_output import write_bodies_result, write_body_result
from ..eld.coupled_run import run_coupled_many
from ..eld.examples import control_problem, tip_mass_problem, tmd_problem
from ..eld.frequencies import (
    crossing_frequency,
    decay_rate,
    modal_frequencies,
    pencil_frequencies,
    pencil_roots,
)
from ..eld.run import run_eld
from ..errors import RotheInputError, check_choice, check_int, check_positive, described, fail
from ..fem.mesh import describe, load_mesh, mesh_dim
from .adapt_options import add_space_options, check_memory, fit_default_cap, space_adaptivity
from .common import (
    add_output_options,
    float_option,
    given,
    parse_int,
    peak_memory_mb,
    print_summary,
)
from .eld_commands import meshes_summary
from .eld_options import (
    MESH_PARAMETERS,
    TIP_MASS_MAX_DOFS,
    body_material,
    body_mesh,
    check_eld_step,
    check_mesh_options,
    control_of,
    form_of,
    keep_option,
    lifting_option,
    material_constants,
    material_of,
    material_options,
    mesh_fields,
    mesh_options,
    part_option,
    parts_of,
    region_map,
    scheme_of,
    step_options,
    summary_material,
)
from .registry import command
from .session import add_run_options, run_sequence

#: the strip's material (nu = 0: the axial motion is the 1D bar's, the analytic frequencies are
#: exact for it); eld-control's too
TIP_MASS_MATERIAL = {"E": 100.0, "nu": 0.0}
CONTROL_MATERIAL = TIP_MASS_MATERIAL
#: eld-tmd's slender strip: E = 10^4 puts its first bending frequency near 9 rad/s
TMD_MATERIAL = {"E": 1e4, "nu": 0.0}
#: the most cells the dense modal analysis behind the reference frequencies takes
TIP_MASS_MAX_CELLS = 4000
#: forcing periods at the end of an eld-tmd run over which the final amplitudes are taken
TMD_LAST_PERIODS = 2
#: --max-dofs of --adapt-space by default (the body's P_k vector unknowns; twice the initial
#: mesh's when that is more): the examples' 2D strips run with a few hundred to a few thousand
COUPLED_MAX_DOFS = 50_000


def check_modal_size(mesh, degree: int) -> None:
    """Refuse a --mesh body too large for the dense modal analysis (one line naming --mesh)."""
    d = mesh.p.shape[0]
    edges = mesh.facets if d == 2 else mesh.edges  # (P2: one more node per edge)
    nodes = mesh.p.shape[1] + (edges.shape[1] if degree == 2 else 0)
    if d * nodes > TIP_MASS_MAX_DOFS:
        raise fail(
            "--mesh",
            described(f"a mesh of {d * nodes} unknowns (P{degree})"),
            f"must have at most {TIP_MASS_MAX_DOFS} (the reference frequencies come from a dense "
            "modal analysis)",
        )


#: the library's parameters by their options on eld-tmd and eld-control: --material/--region,
#: and their couplings, the base's first (its support) and the tip's second (eld-tmd's plate)
BASE_TIP_PARAMETERS = {
    **MESH_PARAMETERS,
    "couplings[0].part": "--base",
    "couplings[1].part": "--tip",
    "axis": "--axis",
}


class CoupledRunCommand:
    """Base of the coupled run commands: the options every one has, and :meth:`run`, the run
    sequence of one or two coupled runs."""

    name = ""
    #: the summary fields printed after a completed run
    keys: tuple = ()
    parameter_options: dict = {"adapt": "--adapt-space"}
    #: the default of the one material of --E/--nu | --lam/--mu (:meth:`validate`)
    default_material: dict = {}

    @staticmethod
    def strip_options(parser, *, n: int, length: float, height: float, T: float, what: str):
        """--n, --degree, --length, --height (the plane-stress strip) and --T."""
        parser.add_argument(
            "--n",
            type=int,
            default=n,
            help=f"cells across the strip (default {n}; round(n L/H) along)",
        )
        parser.add_argument("--degree", type=int, default=2, help="1 or 2 (default 2)")
        float_option(
            parser, "--length", default=length, help=f"strip length L (default {length:g})"
        )
        float_option(
            parser,
            "--height",
            default=height,
            help=f"strip height H, the cross-section per unit thickness (default {height:g})",
        )
        float_option(parser, "--T", default=T, help=f"end time (default {T:g}: {what})")

    @staticmethod
    def strip_checks(args) -> int:
        """--n, --degree, --length, --height: one line naming the option; returns n."""
        n = check_int("--n", args.n, minimum=1)
        if args.degree not in (1, 2):
            raise fail("--degree", args.degree, "must be 1 or 2")
        length = check_positive("--length", args.length)
        height = check_positive("--height", args.height)
        cells = 2 * n * max(1, round(n * length / height))
        if getattr(args, "mesh", None) is None and cells > TIP_MASS_MAX_CELLS:
            raise fail(
                "--n",
                n,
                f"gives {cells} cells, must give at most {TIP_MASS_MAX_CELLS} (the reference "
                "frequencies come from a dense modal analysis)",
            )
        return n

    @staticmethod
    def base_tip_options(parser, *, base: str, tip: str) -> None:
        """``--mesh`` and its options (no ``--dirichlet``: the body is held by its couplings),
        ``--base PART`` and ``--tip PART`` (eld-tmd, eld-control)."""
        mesh_options(parser, dirichlet=None)
        part_option(parser, "--base", "left", base)
        part_option(parser, "--tip", "right", tip)
        parser.add_argument(
            "--axis",
            default="x",
            help="x | y | z: the body's long axis (default x; y with --mesh only, the strip lies "
            "along x; z with a 3D --mesh); L is the mesh's extent along it",
        )

    def validate(self, args):
        """The checks that need no system, one line naming the option: (objects of
        :meth:`run_objects`, n of :meth:`strip_checks`, the material of the options with
        :attr:`default_material`, None with ``--material``: it needs the mesh's regions,
        :meth:`body_material_of`) -- the material built once for execute and the summary.
        With ``--mesh``: not with the strip's --n/--length/--height."""
        objects = self.run_objects(args)
        check_mesh_options(args, ("--n", "--length", "--height"))
        if check_choice("--axis", args.axis, ("x", "y", "z")) != "x" and args.mesh is None:
            raise fail("--axis", args.axis, "needs --mesh (the built-in strip lies along x)")
        n = self.strip_checks(args)
        material = None if args.material else material_of(args, self.default_material)
        # (a --mesh body: the material in the mesh's dimension, body_material_of; the 2D one
        # above checks the options before the mesh is read)
        return objects, n, None if args.mesh is not None else material

    def body_material_of(self, args, material, mesh):
        """The body's material: ``material`` of :meth:`validate`, or with ``--material``/
        ``--region`` the :class:`~rothe.eld.materials.PiecewiseMaterial` on the mesh's
        regions (its refusals name --material/--region: ``MESH_PARAMETERS``)."""
        if material is not None:
            return material
        if mesh is not None and args.axis == "z" and mesh_dim(mesh) == 2:
            raise fail("--axis", "z", f"needs a 3D --mesh (got a 2D mesh: {describe(mesh)})")
        return body_material(args, self.default_material, mesh)

    @staticmethod
    def body_of(args, example, mesh):
        """The summary's fields of the body: the strip's n, L, H, or the mesh file's fields with
        the parts and the L, H the example took from the mesh (extent along --axis,
        area / L; 3D: ``area``, the section's volume / L, instead of H)."""
        if args.mesh is None:
            return {"n": args.n, "length": args.length, "height": args.height}
        section = "height" if mesh_dim(mesh) == 2 else "area"
        return {
            **mesh_fields(args, mesh),
            "base": args.base,
            "tip": args.tip,
            "axis": args.axis,
            "length": example.length,
            section: example.height,
        }

    #: the SpaceAdaptivity of --adapt-space (None: fixed mesh), set by :meth:`run_objects`
    adapt = None
    #: the ParaView series of a one-body command, set by :meth:`body_outputs` (the summary's
    #: ``paraview``)
    paraview: list | None = None
    #: --keep-every of the one-body commands by default: the body's fields of every 5th state
    #: (and the first and last) in ParaView and trajectory.npz, as eld-beam -- every state made
    #: eld-tmd's default output 61 MB instead of 0.5 MB (docs/coupling.md, Sec. 18)
    KEEP_EVERY = 5

    def run_body(self, args, runs: dict, objects, summarize, draw, extra=None) -> int:
        """:meth:`run` of a one-body command (eld-tip-mass, eld-tmd, eld-control): the runs
        record their body's fields, written by :meth:`body_outputs` every --keep-every states
        (``extra(label, result)``: the command's own arrays for that run's npz, or None)."""
        return self.run(
            args,
            runs,
            objects,
            summarize,
            draw,
            fields=True,
            outputs=self.body_outputs(runs, args.keep_every, extra),
        )

    def body_outputs(self, runs: dict, every: int, extra=None):
        """``outputs`` of :meth:`run` for the one-body commands: every completed run's
        ``trajectory[_<label>].npz`` and its body's ParaView series ``body[_<label>]`` (u, v,
        stresses and the multiplier on every constrained part; ``.xdmf`` on a fixed mesh, a
        ``.pvd`` of VTU files with --adapt-space: :func:`rothe.eld.bodies_output.
        write_body_result`) of every ``every``-th state (--keep-every), the first run without
        the suffix; ``extra(label, result)``: more arrays for its npz (None: none)."""
        labels = list(runs)
        suffixes = {label: "" if k == 0 else f"_{label}" for k, label in enumerate(labels)}
        kind = "xdmf" if self.adapt is None else "pvd"
        self.paraview = [f"body{suffixes[label]}.{kind}" for label in labels]

        def outputs(stage, label, result):
            suffix = suffixes[label]
            return write_body_result(
                result,
                runs[label].body,
                stage,
                f"body{suffix}",
                npz=f"trajectory{suffix}.npz",
                every=every,
                extra=None if extra is None else extra(label, result),
            )

        return outputs

    @staticmethod
    def space_options(parser) -> None:
        """--adapt-space and its options (the body's mesh; :mod:`rothe.eld.coupled_adapt`)."""
        add_space_options(
            parser,
            default_max_dofs=COUPLED_MAX_DOFS,
            indicator="the body's residual indicator (the coupled run's explicit adapt step)",
            norms=True,
        )

    def run_objects(self, args) -> dict:
        """scheme, form and control of the command line (--tau against --T first); the
        --adapt-space options checked too (:attr:`adapt`)."""
        check_eld_step("--tau", args.tau, args.T)
        if hasattr(args, "keep_every"):  # (the one-body commands: body_outputs)
            check_int("--keep-every", args.keep_every, minimum=1)
        control = control_of(args)
        self.adapt = space_adaptivity(args, default_max_dofs=COUPLED_MAX_DOFS)
        return {"scheme": scheme_of(args), "form": form_of(args), "control": control}

    def run(
        self, args, runs: dict, objects: dict, summarize, draw=None, *, fields=False, outputs=None
    ) -> int:
        """Run the coupled systems ``runs`` (label -> CoupledProblem; the first is the command's
        run, written to ``trajectory.npz``, the others to ``trajectory_<label>.npz``) one after
        the other as one session; ``summarize(summary, trajectories, completed)`` adds the
        command's fields, ``draw(stage, trajectories, summary)`` the figure. ``fields``: record
        the body's u, v, lambda (:func:`run_coupled`); ``outputs(stage, label, result)``:
        writes a completed run's files instead of its ``trajectory.npz`` alone."""
        done: dict = {}
        self.results = done  # (the command's summary reads the runs' final systems)
        labels = list(runs)
        adapt = self.adapt
        fit_default_cap(args, adapt, next(iter(runs.values())).body.space.ndofs)

        def start(checkpoint, resume, progress):
            # the runs one after the other with one checkpoint (the finished runs and the one
            # under way); ``done`` gets each as it finishes, restored ones first
            return run_coupled_many(
                runs,
                progress=progress,
                fields=fields,
                adapt=adapt,
                checkpoint=checkpoint,
                resume=resume,
                results=done,
                **objects,
            )

        def write(stage, outcome):
            completed = outcome.status == "completed"
            trajs = {label: result.trajectory for label, result in done.items()}
            if not completed and outcome.result is not None:
                trajs[labels[len(done)]] = outcome.result  # the run that stopped, so far
            for label, traj in trajs.items():
                if outputs is not None and completed:
                    outputs(stage, label, done[label])
                    continue
                name = "trajectory.npz" if label == labels[0] else f"trajectory_{label}.npz"
                meshes = done[label].mesh_arrays() if label in done else None
                traj.save_npz(stage / name, extra=meshes or None)
            summary = self.summary_head(args, objects, trajs)
            summarize(summary, trajs, completed)
            if completed and self.paraview is not None:
                summary.setdefault("paraview", self.paraview)
            if completed and not args.no_plots and draw is not None:
                draw(stage, trajs, summary)
            return summary

        code, outcome, results, summary = run_sequence(args, self.name, start, write)
        if outcome is not None and outcome.status == "completed" and not args.quiet:
            print(f"rothe run {self.name}: wrote {results}/")
            print_summary(summary, self.keys)
        return code

    def summary_head(self, args, objects: dict, trajs: dict) -> dict:
        """The fields every coupled run's summary starts with (of the first run, the wall
        time of all), the ledger's largest mismatch of each run."""
        control = objects["control"]
        first = next(iter(trajs.values()))
        st = first.stats
        return {
            "example": self.name,
            "status": "completed",
            "scheme": objects["scheme"].name,
            "form": objects["form"].name,
            "lifting": objects["form"].lifting,
            "control": type(control).__name__.lower(),
            "tau": args.tau,
            "tol": getattr(control, "tol", None),
            "accepted_steps": st.accepted_steps,
            "rejected_steps": st.rejected_steps,
            "T": args.T,
            "wall_time_s": sum(t.stats.wall_time_s for t in trajs.values()),
            "peak_memory_mb": peak_memory_mb(),
            **self.adapt_fields(trajs),
        }

    def adapt_fields(self, trajs: dict) -> dict:
        """With --adapt-space: ``adapt_space``, the options (``space``, as run_eld's summary,
        and ``space_options``), and per run (suffix ``_<label>`` for all but the first) the
        keys of run_eld's summary (:func:`~rothe.cli.eld_commands.meshes_summary`: meshes,
        adaptations, ndofs, ndofs_initial, ndofs_max, ndofs_summed_over_steps, bisections,
        merges, transfer_energy; the body's unknowns) with the coupled run's own:
        ``ndofs_min``, ``ndofs_final`` and ``constraint_max``."""
        if self.adapt is None:
            return {"adapt_space": False}
        space = self.adapt.describe()
        out = {"adapt_space": True, "space_options": space}
        for k, (label, traj) in enumerate(trajs.items()):
            suffix = "" if k == 0 else f"_{label}"
            done = self.results.get(label)  # None: the run that stopped (no result yet)
            fields = meshes_summary(traj, None if done is None else done.meshes, space)
            ndofs = np.asarray(traj["ndofs"])
            fields.update(
                ndofs_min=int(ndofs.min()),
                ndofs_final=int(ndofs[-1]),
                constraint_max=float(np.abs(traj["constraint"]).max()),
            )
            if k:
                del fields["space"]
            out.update({f"{key}{suffix}": value for key, value in fields.items()})
        return out


@command("run", "eld-tip-mass")
class RunEldTipMass(CoupledRunCommand):
    """``rothe run eld-tip-mass``: a clamped bar carrying a mass-spring at its tip."""

    help = (
        "Clamped plane-stress bar (or any --mesh body) carrying a mass on a spring at its free "
        "end (a coupled component, B u = q on the end): the first axial frequency measured from "
        "the run against the bar-with-tip-mass equation"
    )
    name = "eld-tip-mass"
    #: the library's parameters by their options (the tip's coupling is couplings[0])
    parameter_options = {**MESH_PARAMETERS, "couplings[0].part": "--tip", "modes": "--modes"}
    keys = (
        "example",
        "scheme",
        "form",
        "control",
        "accepted_steps",
        "rejected_steps",
        "ndofs",
        "analytic",
        "frequency_analytic",
        "frequency_discrete",
        "frequency_measured",
        "frequency_error_measured",
        "frequencies_measured",
        "frequencies_error_measured",
        "energy_drift",
        "balance_max",
        "wall_time_s",
    )

    def configure(self, parser) -> None:
        """Add the eld-tip-mass options (step, lifting, bar or mesh, material, mass, spring,
        damper, amplitude)."""
        step_options(parser, 0.005, scheme_default="bdf2")
        lifting_option(parser)
        self.strip_options(
            parser, n=2, length=1.0, height=0.25, T=2.0, what="about 2.7 periods of the first mode"
        )
        material_options(parser, TIP_MASS_MATERIAL, rho=1.0, plane="stress")
        mesh_options(parser, dirichlet="left", dirichlet_help="the clamped boundary parts (u = 0)")
        parser.add_argument(
            "--tip",
            default="right",
            metavar="PART",
            help="the boundary part tied to the mass (B u = q there) (default right)",
        )
        float_option(
            parser,
            "--mass",
            default=0.25,
            help="tip mass m (default 0.25 = the bar's mass rho H L)",
        )
        float_option(
            parser,
            "--spring",
            default=0.0,
            help="stiffness k of the spring from the tip mass to the ground (default 0)",
        )
        float_option(
            parser,
            "--damper",
            default=0.0,
            help="damping c of the tip mass to the ground (default 0: no damping, the energy "
            "is kept up to the scheme's numerical dissipation)",
        )
        float_option(
            parser,
            "--amplitude",
            default=0.01,
            help="initial tip displacement of each excited axial mode (default 0.01)",
        )
        parser.add_argument(
            "--modes",
            type=parse_int("--modes", minimum=1),
            default=1,
            metavar="K",
            help="start in the sum of the first K axial modes of the discrete system, each "
            "with its tip at --amplitude, and measure their K frequencies from the run's modal "
            "coordinates (default 1: the first mode alone)",
        )
        keep_option(parser, self.KEEP_EVERY)
        self.space_options(parser)
        add_output_options(parser, self.name)
        add_run_options(parser)

    def validate(self, args):
        """The checks that need no mesh: one line naming the option."""
        objects = self.run_objects(args)
        check_mesh_options(args, ("--n", "--length", "--height"))
        n = self.strip_checks(args)
        parts_of(args)
        if args.mesh is None and not args.material:
            material_of(args, TIP_MASS_MATERIAL)  # (on a mesh: in its dimension, when loaded)
        return objects, n

    def execute(self, args) -> int:
        """Run the tip-mass example; write trajectory, summary and figure; returns 0."""
        objects, n = self.validate(args)
        mesh = body_mesh(args)
        if mesh is not None:
            check_modal_size(mesh, args.degree)
        material = body_material(args, TIP_MASS_MATERIAL, mesh)
        example = tip_mass_problem(
            n,
            args.degree,
            length=args.length,
            height=args.height,
            material=material,
            mesh=mesh,
            clamp=parts_of(args),
            tip=args.tip,
            mass=args.mass,
            spring=args.spring,
            damper=args.damper,
            amplitude=args.amplitude,
            T=args.T,
            modes=args.modes,
        )

        def summarize(summary, trajs, completed):
            traj = trajs["tip"]
            t, q = traj["t"], np.asarray(traj["q"])
            tip = crossing_frequency(t, q[:, 0])
            K = example.modes
            pencil = np.array(pencil_frequencies(t, q[:, 0], K))
            modal = self.measured_frequencies(example, traj, tip, pencil)
            measured = modal[0]
            energy = traj["energy"]
            summary.update(
                n=n,
                degree=args.degree,
                # (--adapt-space: the last state's, as run_eld's summary: meshes_summary)
                ndofs=summary.get("ndofs", example.system.body.space.ndofs),
                length=args.length,
                height=args.height,
            )
            fields = summary_material(args, TIP_MASS_MATERIAL, material)
            summary.update({"material": fields} if args.material else fields)  # (flat: as always)
            summary.update(
                mass=args.mass,
                spring=args.spring,
                damper=args.damper,
                # "bar", "sliced bar" (several materials in slices along x) or "n/a: <why>"
                analytic=example.prediction,
                frequency_analytic=example.analytic.tolist(),
                frequency_discrete=example.discrete.tolist(),
                frequency_error_discrete=(example.discrete / example.analytic - 1).tolist(),
                frequency_measured=measured,
                frequency_error_measured=measured / example.analytic[0] - 1,
                frequency_error_measured_vs_discrete=measured / example.discrete[0] - 1,
                frequency_measured_tip_crossings=tip,
                modes=K,
                frequencies_measured=modal,
                frequencies_error_measured=(np.array(modal) / example.analytic[:K] - 1).tolist(),
                frequencies_error_measured_vs_discrete=(
                    np.array(modal) / example.discrete[:K] - 1
                ).tolist(),
                frequencies_measured_tip=pencil.tolist(),
                frequencies_error_measured_tip_vs_discrete=(
                    pencil / example.discrete[:K] - 1
                ).tolist(),
                energy_initial=float(energy[0]),
                energy_drift=float(energy[-1] / energy[0] - 1),
                balance_max=float(np.abs(traj["balance"]).max()),
            )
            if example.slices is not None:
                summary["slices"] = example.slices
            if self.adapt is not None and K > 1:
                summary["frequencies_measured_note"] = (
                    "with --adapt-space the modal coordinates would need the discrete modes on "
                    "every mesh: the frequencies are the matrix pencil's of the tip's q_x "
                    "(frequencies_measured_tip; null with --control adaptive, whose steps are "
                    "not equal)"
                )
            if mesh is not None:
                del summary["n"], summary["height"]
                summary.update(
                    mesh_fields(args, mesh),
                    dirichlet=list(parts_of(args)),
                    tip=args.tip,
                    length=example.length,
                    area=example.area,
                )

        def draw(stage, trajs, summary):
            # matplotlib is imported only for the figures
            from ..eld.figures import plot_tip_mass

            plot_tip_mass(
                trajs["tip"],
                stage / "fig_tip_mass.png",
                modal=None if self.adapt is not None else example.modal_coordinates(trajs["tip"]),
                title=f"eld-tip-mass, {summary['scheme']}, {summary['form']}, "
                f"m = {args.mass:g}, k = {args.spring:g}",
            )

        def modal(label, result):
            # the modal coordinates --modes measures from, with the rows that project on them,
            # so that a user can re-fit them (docs/coupling.md, Sec. 11); none on changing
            # meshes (the modes are the first mesh's)
            if self.adapt is not None:
                return None
            traj = result.trajectory
            return {
                "modal_t": np.asarray(traj["t"]),
                "modal_c": example.modal_coordinates(traj),
                "modal_rows_u": example.projection_u,
                "modal_rows_q": example.projection_q,
            }

        runs = {"tip": example.system}
        return self.run_body(args, runs, objects, summarize, draw, extra=modal)

    def measured_frequencies(self, example, traj, tip: float, pencil) -> list:
        """The K excited frequencies measured from the run: the zero crossings of the modal
        coordinates c_k = phi_k^T M x of every state (:meth:`~rothe.eld.examples.
        TipMassExample.modal_coordinates` of the recorded u and q; docs/coupling.md Sec. 11).
        With --adapt-space the states live on other meshes than the modes: one mode (K = 1)
        is the tip's crossing frequency ``tip`` (as before), several the matrix pencil's of
        the tip's q_x, ``pencil`` (NaN on unequal steps)."""
        if self.adapt is not None:
            return [tip] if example.modes == 1 else list(pencil)
        return modal_frequencies(traj["t"], example.modal_coordinates(traj))


@command("run", "eld-tmd")
class RunEldTmd(CoupledRunCommand):
    """``rothe run eld-tmd``: a cantilever shaken at its base, with and without a tuned mass
    damper on its tip."""

    help = (
        "Cantilever strip on a support pushed at the strip's first bending frequency, with and "
        "without a tuned mass damper (Den Hartog) on its tip plate: tip amplitude and base "
        "reaction over time, the amplitude reduction"
    )
    name = "eld-tmd"
    default_material = TMD_MATERIAL
    parameter_options = BASE_TIP_PARAMETERS
    keys = (
        "example",
        "scheme",
        "accepted_steps",
        "ndofs",
        "frequency_first_bending",
        "absorber_mass",
        "tip_amplitude_max",
        "tip_amplitude_max_without_tmd",
        "amplitude_reduction",
        "amplitude_reduction_last",
        "base_reaction_max",
        "base_reaction_max_without_tmd",
        "balance_max",
        "wall_time_s",
    )

    def configure(self, parser) -> None:
        """The step options, the strip, its material, the absorber and the forcing."""
        step_options(parser, 0.01, scheme_default="bdf2")
        lifting_option(parser)
        self.strip_options(
            parser, n=2, length=1.0, height=0.1, T=12.0, what="17 periods of the forcing"
        )
        material_options(parser, TMD_MATERIAL, rho=1.0, plane="stress")
        self.base_tip_options(
            parser,
            base="the end tied to the support (pushed along y)",
            tip="the end carrying the rigid plate and the absorber (centred at its centroid)",
        )
        parser.add_argument(
            "--direction",
            default=None,
            help="x | y | z: the transverse axis the support is pushed along and the absorber "
            "swings along (default the next axis after --axis: y for x, x for y in 2D; in 3D "
            "x -> y -> z -> x); must differ from --axis, z needs a 3D --mesh",
        )
        float_option(
            parser,
            "--mass-ratio",
            default=0.05,
            help="absorber mass / the modal mass of the first bending mode (default 0.05); "
            "its spring and damper by Den Hartog",
        )
        float_option(
            parser,
            "--force",
            default=0.01,
            help="amplitude of the force f = force sin(W t) e_y on the support (default 0.01)",
        )
        float_option(
            parser,
            "--forcing-ratio",
            default=1.0,
            help="W / w_1, the forcing against the first bending frequency of the system "
            "without the absorber (default 1: at resonance)",
        )
        float_option(
            parser, "--b", default=0.0, help="Rayleigh damping b K of the strip (default 0)"
        )
        keep_option(parser, self.KEEP_EVERY)
        self.space_options(parser)
        add_output_options(parser, self.name)
        add_run_options(parser)

    def direction_of(self, args, mesh) -> int | None:
        """--direction as an axis index, None where not given (tmd_problem's default, the next
        axis after --axis); one line naming --direction when it equals --axis or is z on a 2D
        body."""
        if args.direction is None:
            return None
        direction = check_choice("--direction", args.direction, ("x", "y", "z"))
        if direction == args.axis:
            raise fail(
                "--direction",
                direction,
                f"must differ from --axis {args.axis} (the absorber swings across the body)",
            )
        if direction == "z" and (mesh is None or mesh_dim(mesh) == 2):
            where = "the built-in strip" if mesh is None else f"a 2D mesh: {describe(mesh)}"
            raise fail("--direction", "z", f"needs a 3D --mesh (got {where})")
        return "xyz".index(direction)

    def execute(self, args) -> int:
        """Build both systems, run them, write both trajectories, the summary and the figure."""
        objects, n, material = self.validate(args)
        if args.direction is not None and (args.mesh is None or args.direction == args.axis):
            self.direction_of(args, None)  # (the refusals that need no mesh, before reading it)
        mesh = body_mesh(args)
        if mesh is not None:
            check_modal_size(mesh, args.degree)
        material = self.body_material_of(args, material, mesh)
        example = tmd_problem(
            n,
            args.degree,
            length=args.length,
            height=args.height,
            material=material,
            mesh=mesh,
            base=args.base,
            tip=args.tip,
            axis="xyz".index(args.axis),
            direction=self.direction_of(args, mesh),
            mass_ratio=args.mass_ratio,
            force=args.force,
            forcing_ratio=args.forcing_ratio,
            b=args.b,
            T=args.T,
        )
        across = example.direction  # (pushed and measured across the body)
        tip = example.with_tmd.offsets["tip"] + across  # the plate's deflection a_y, in q
        # the absorber's displacement s: the plate's last coordinate (a_x, a_y, theta, s; 3D:
        # a, theta, s)
        absorber = example.with_tmd.offsets["tip"] + example.with_tmd.components[1].size - 1

        def summarize(summary, trajs, completed):
            summary.update(
                **self.body_of(args, example, mesh),
                degree=args.degree,
                ndofs=summary.get("ndofs", example.with_tmd.body.space.ndofs),
                material=summary_material(args, TMD_MATERIAL, material),
                b=args.b,
                frequency_first_bending=example.frequency,
                frequency_clamped=example.clamped_frequency,
                frequency_beam_theory=example.beam_frequency,
                prediction=example.prediction or "beam theory: the strip's E, rho, L, H",
                forcing_frequency=example.forcing,
                modal_mass=example.modal_mass,
                mass_ratio=args.mass_ratio,
                absorber_mass=args.mass_ratio * example.modal_mass,
                absorber_stiffness=example.stiffness,
                absorber_damping=example.damping,
            )
            if mesh is not None:
                summary["direction"] = "xyz"[across]
            period = 2 * np.pi / example.forcing
            for label, suffix in (("with_tmd", ""), ("without_tmd", "_without_tmd")):
                if label not in trajs:
                    continue
                traj = trajs[label]
                t, q = traj["t"], np.asarray(traj["q"])
                last = t >= t[-1] - TMD_LAST_PERIODS * period
                summary[f"tip_amplitude_max{suffix}"] = float(np.abs(q[:, tip]).max())
                summary[f"tip_amplitude_last{suffix}"] = float(np.abs(q[last, tip]).max())
                reaction = np.abs(np.asarray(traj[f"reaction_{args.base}"])[:, across])
                summary[f"base_reaction_max{suffix}"] = float(reaction.max())
                summary[f"balance_max{suffix}"] = float(np.abs(traj["balance"]).max())
                summary[f"energy_final{suffix}"] = float(traj["energy"][-1])
            if "with_tmd" in trajs:
                q = np.asarray(trajs["with_tmd"]["q"])
                summary["absorber_amplitude_max"] = float(np.abs(q[:, absorber]).max())
            if completed:
                summary["amplitude_reduction"] = (
                    summary["tip_amplitude_max_without_tmd"] / summary["tip_amplitude_max"]
                )
                summary["amplitude_reduction_last"] = (
                    summary["tip_amplitude_last_without_tmd"] / summary["tip_amplitude_last"]
                )
                summary["reaction_reduction"] = (
                    summary["base_reaction_max_without_tmd"] / summary["base_reaction_max"]
                )

        def draw(stage, trajs, summary):
            # matplotlib is imported only for the figures
            from ..eld.figures import plot_comparison

            plot_comparison(
                {"with TMD": trajs["with_tmd"], "without TMD": trajs["without_tmd"]},
                stage / "fig_tmd.png",
                coordinate=tip,
                label=f"tip deflection (end plate a_{'xyz'[across]})",
                part=args.base,
                axis=across,
                title=f"eld-tmd, forcing {example.forcing:.4g} rad/s, mass ratio "
                f"{args.mass_ratio:g}: amplitude / {summary['amplitude_reduction']:.3g}",
            )

        runs = {"with_tmd": example.with_tmd, "without_tmd": example.without_tmd}
        return self.run_body(args, runs, objects, summarize, draw)


@command("run", "eld-control")
class RunEldControl(CoupledRunCommand):
    """``rothe run eld-control``: the clamped end moved by feedback on the tip velocity."""

    help = (
        "A bar whose held end (a base on a spring) is pushed by a PD law on the tip velocity: "
        "the decay rate of its free vibration against the uncontrolled run and the predicted "
        "rate of the first mode"
    )
    name = "eld-control"
    default_material = CONTROL_MATERIAL
    #: the library's parameters by their options (control_problem's base_stiffness)
    parameter_options = {**BASE_TIP_PARAMETERS, "base_stiffness": "--base-spring"}
    keys = (
        "example",
        "scheme",
        "accepted_steps",
        "ndofs",
        "frequency_first",
        "decay_rate_measured",
        "prediction",
        "decay_rate_predicted",
        "decay_rate_error",
        "decay_rate_predicted_discrete",
        "decay_rate_error_discrete",
        "decay_rate_measured_pencil",
        "decay_rate_pencil_error",
        "decay_rate_modal",
        "decay_rate_measured_uncontrolled",
        "decay_rate_predicted_uncontrolled",
        "mode2_rate_without_material_damping",
        "work_controller",
        "balance_max",
        "wall_time_s",
    )

    def configure(self, parser) -> None:
        """The step options, the strip, its material, the base, the feedback and the start."""
        step_options(parser, 0.005, scheme_default="bdf2")
        lifting_option(parser)
        self.strip_options(
            parser, n=2, length=1.0, height=0.25, T=6.0, what="6 periods of the first mode"
        )
        material_options(parser, CONTROL_MATERIAL, rho=1.0, plane="stress")
        self.base_tip_options(
            parser,
            base="the end held by the base (pushed along x)",
            tip="the end whose axial velocity is fed back (at its centroid)",
        )
        float_option(parser, "--base-mass", default=1.0, help="mass m_b of the base (default 1)")
        float_option(
            parser,
            "--base-spring",
            default=50.0,
            help="stiffness k_b of the base's spring along the bar (default 50)",
        )
        float_option(
            parser,
            "--gain",
            default=1.0,
            help="k_p: the actuator force -k_p v_L on the base, v_L the tip's axial velocity "
            "(k_p > 0: a damper; default 1). k_p < 0 feeds energy in: the run then grows; the "
            "decay rate in the summary is negative (a study of instability)",
        )
        float_option(
            parser,
            "--kd",
            default=0.0,
            help="k_d: the force -k_d v_L', v_L' by a first-order filter (default 0)",
        )
        float_option(
            parser,
            "--filter-time",
            default=0.02,
            help="T_f of the derivative's filter (1 + T_f s)^-1, with --kd (default 0.02)",
        )
        float_option(
            parser,
            "--b",
            default=0.005,
            help="Rayleigh (Kelvin-Voigt) damping b K of the bar (default 0.005: it holds the "
            "second mode, which the non-collocated feedback destabilizes)",
        )
        float_option(
            parser,
            "--amplitude",
            default=0.01,
            help="initial displacement of the base in the first mode (default 0.01)",
        )
        keep_option(parser, self.KEEP_EVERY)
        self.space_options(parser)
        add_output_options(parser, self.name)
        add_run_options(parser)

    def execute(self, args) -> int:
        """Build both systems, run them, write both trajectories, the summary and the figure."""
        objects, n, material = self.validate(args)
        mesh = body_mesh(args)
        if mesh is not None:
            check_modal_size(mesh, args.degree)
        material = self.body_material_of(args, material, mesh)
        example = control_problem(
            n,
            args.degree,
            length=args.length,
            height=args.height,
            material=material,
            mesh=mesh,
            base=args.base,
            tip=args.tip,
            axis="xyz".index(args.axis),
            base_mass=args.base_mass,
            base_stiffness=args.base_spring,
            gain=args.gain,
            kd=args.kd,
            filter_time=args.filter_time,
            b=args.b,
            amplitude=args.amplitude,
            T=args.T,
        )
        roots, free, undamped = example.roots, example.roots_uncontrolled, example.roots_undamped
        discrete = example.roots_discrete
        w1 = float(discrete[0].imag) if np.isfinite(discrete[0]) else example.frequency
        axis = "xyz".index(args.axis)  # (the base's displacement along the bar: q[axis])
        # several materials: the uniform bar's predictions are NaN (null in summary.json, the
        # reason in "prediction"), the measured rates of both runs are reported as for one
        predicted = example.prediction is None

        def summarize(summary, trajs, completed):
            summary.update(
                **self.body_of(args, example, mesh),
                degree=args.degree,
                ndofs=summary.get("ndofs", example.controlled.body.space.ndofs),
                material=summary_material(args, CONTROL_MATERIAL, material),
                prediction=example.prediction or "the uniform bar's characteristic equation",
                base_mass=args.base_mass,
                base_spring=args.base_spring,
                gain=args.gain,
                kd=args.kd,
                filter_time=args.filter_time if args.kd > 0 else None,
                b=args.b,
                frequency_first=example.frequency,
                decay_rate_predicted=float(-roots[0].real),
                frequency_predicted=float(roots[0].imag),
                decay_rate_modal=example.modal_rate,
                decay_rate_predicted_uncontrolled=float(-free[0].real),
                roots=[[float(s.real), float(s.imag)] for s in roots],
                mode2_rate=float(-roots[1].real),
                mode2_rate_without_material_damping=float(-undamped[1].real),
                # the semi-discrete closed loop's roots (any material and mesh): the rate the
                # run measures as tau -> 0, the prediction for several materials
                prediction_discrete="the discrete closed loop's eigenvalues (body, base, "
                "controller) near the first two axial modes",
                decay_rate_predicted_discrete=float(-discrete[0].real),
                frequency_predicted_discrete=float(discrete[0].imag),
                decay_rate_predicted_discrete_uncontrolled=float(
                    -example.roots_discrete_uncontrolled[0].real
                ),
                roots_discrete=[[float(s.real), float(s.imag)] for s in discrete],
                mode2_rate_discrete=float(-discrete[1].real),
            )
            for label, suffix in (("controlled", ""), ("uncontrolled", "_uncontrolled")):
                if label not in trajs:
                    continue
                traj = trajs[label]
                t, y = traj["t"], np.asarray(traj["q"])[:, axis]
                summary[f"decay_rate_measured{suffix}"] = decay_rate(t, y)
                summary[f"frequency_measured{suffix}"] = crossing_frequency(t, y)
                # the first mode's root by the matrix pencil of q(t): the other modes the start
                # excites (the uncontrolled mode is not the controlled one) do not bias it as
                # they bias the maxima, so it tends to the discrete closed loop's root at the
                # scheme's order (NaN with adaptive steps)
                found = np.asarray(pencil_roots(t, y, 3))
                first = found[np.argmin(np.abs(np.nan_to_num(found.imag, nan=np.inf) - w1))]
                summary[f"decay_rate_measured_pencil{suffix}"] = float(-first.real)
                summary[f"balance_max{suffix}"] = float(np.abs(traj["balance"]).max())
                # against the largest energy: a growing run (k_p < 0) has a ledger of growing
                # terms, whose round-off grows with them
                summary[f"balance_max_relative{suffix}"] = float(
                    np.abs(traj["balance"]).max() / np.abs(traj["energy"]).max()
                )
                summary[f"energy_ratio{suffix}"] = float(traj["energy"][-1] / traj["energy"][0])
            if "controlled" in trajs:
                summary["work_controller"] = float(trajs["controlled"]["work_controllers"][-1])
                # relative to the predicted rate, of either sign; undefined (null) without a
                # prediction (several materials) or where that rate is 0 (--gain 0 --b 0:
                # nothing damps the bar)
                rate = summary["decay_rate_predicted"]
                summary["decay_rate_error"] = (
                    summary["decay_rate_measured"] / rate - 1 if predicted and rate != 0 else None
                )
                rate = summary["decay_rate_predicted_discrete"]
                # (undefined where nothing damps the bar: --gain 0 --b 0 gives a rate of
                # round-off, ~1e-18, not a scale)
                defined = np.isfinite(rate) and abs(rate) > 1e-12 * w1
                for key, measured in (
                    ("decay_rate_error_discrete", "decay_rate_measured"),
                    ("decay_rate_pencil_error", "decay_rate_measured_pencil"),
                ):
                    summary[key] = summary[measured] / rate - 1 if defined else None

        def draw(stage, trajs, summary):
            # matplotlib is imported only for the figures
            from ..eld.figures import plot_comparison

            plot_comparison(
                {
                    f"feedback k_p = {args.gain:g}": trajs["controlled"],
                    "no feedback": trajs["uncontrolled"],
                },
                stage / "fig_control.png",
                coordinate=axis,
                label=f"base displacement q_{args.axis}",
                part=args.base,
                axis=axis,
                title=f"eld-control: decay rate {summary['decay_rate_measured']:.4g} "
                + f"(predicted {summary['decay_rate_predicted_discrete']:.4g}, "
                + f"without feedback {summary['decay_rate_measured_uncontrolled']:.3g})",
            )

        runs = {"controlled": example.controlled, "uncontrolled": example.uncontrolled}
        return self.run_body(args, runs, objects, summarize, draw)


#: eld-two-bodies: the clamped soft half and the stiffer, heavier free half
TWO_BODIES_MATERIAL = {"E": 100.0, "nu": 0.3}
TWO_BODIES_MATERIAL2 = {"E": 300.0, "nu": 0.2}
#: body 2's material options -> the API parameters they stand for
_BODY2_OPTIONS = {"E": "--E2", "nu": "--nu2", "lam": "--lam2", "mu": "--mu2", "rho": "--rho2"}
#: each body's constants of one material, which its --material<k> replaces
_BODY_CONSTANTS = {
    1: ("--E", "--nu", "--lam", "--mu"),
    2: ("--E2", "--nu2", "--lam2", "--mu2"),
}
#: eld-two-bodies' peak memory per unknown (both bodies; twice with --compare-union): a fixed
#: part and one per recorded state (the fields of both bodies at every state). Measured here
#: (peak RSS, T = 2, 201 states, --compare-union): 0.98 GB at 2 x 16770 and 3.26 GB at
#: 2 x 66306 unknowns, i.e. 14.6 and 12.3 kB per counted unknown; rounded up to 6000 + 60 per
#: state (18 kB at 201 states): refuses what cannot fit, before allocating (docs/coupling.md)
TWO_BODIES_BYTES_PER_DOF = 6000
TWO_BODIES_BYTES_PER_DOF_STATE = 60


@command("run", "eld-two-bodies")
class RunEldTwoBodies(CoupledRunCommand):
    """``rothe run eld-two-bodies``: two bodies of two materials glued along an interface."""

    help = (
        "Two elastic bodies of different materials glued along an interface (B1 u1 - B2 u2 = 0 "
        "with a multiplier; matching or mortar meshes): a strip clamped at one end, pulsed at "
        "the other; each body's fields, the interface reaction over time"
    )
    name = "eld-two-bodies"
    #: the library's parameters by their options
    parameter_options = {
        "attached[0].interface": "--interface",
        "attached[0].interface.part1": "--interface",
        "attached[0].interface.part2": "--interface",
        "attached[0].base_part": "--interface",
        "attached[0].body_part": "--interface",
        "attached[0].clamped": "--interface",
        "couplings[0].part": "--interface",
        "dirichlet": "--clamp",
        "traction": "--load-part",
        "attached[0].traction": "--load-part",
        "material.dim": "--mesh1",
        "adapt": "--adapt-space",
    }
    keys = (
        "example",
        "scheme",
        "form",
        "control",
        "accepted_steps",
        "rejected_steps",
        "ndofs",
        "interface_method",
        "tip_deflection_max",
        "interface_reaction_max",
        "clamp_reaction_max",
        "balance_max",
        "constraint_max",
        "seconds_per_step",
        "union_difference_u",
        "union_difference_energy",
        "seconds_per_step_ratio",
        "wall_time_s",
    )

    def configure(self, parser) -> None:
        """Step options; the strip (or two meshes); the two materials; the load."""
        step_options(parser, 0.01, scheme_default="bdf2")
        lifting_option(parser)
        parser.add_argument(
            "--n1", type=int, default=2, help="cells across body 1 (default 2; along in proportion)"
        )
        parser.add_argument(
            "--n2",
            type=int,
            default=None,
            help="cells across body 2 (default --n1: matching interface nodes; otherwise the "
            "interface is glued by the mortar projection)",
        )
        parser.add_argument("--degree", type=int, default=2, help="1 or 2 (default 2), body 1")
        parser.add_argument(
            "--degree2", type=int, default=None, help="1 or 2, body 2 (default --degree)"
        )
        float_option(parser, "--length", default=1.0, help="strip length L (default 1)")
        float_option(parser, "--height", default=0.25, help="strip height H (default 0.25)")
        float_option(
            parser, "--split", default=0.5, help="x of the interface, 0 < split < L (default 0.5)"
        )
        parser.add_argument(
            "--mesh1",
            default=None,
            metavar="FILE",
            help="body 1's mesh file instead of the strip (with --mesh2; parts by gmsh "
            "physical-group name)",
        )
        parser.add_argument("--mesh2", default=None, metavar="FILE", help="body 2's mesh file")
        parser.add_argument(
            "--interface",
            default="right,left",
            metavar="PART1,PART2",
            help="the glued parts of body 1 and body 2 (default right,left)",
        )
        parser.add_argument(
            "--clamp", default="left", metavar="PART", help="body 1's clamped part (default left)"
        )
        parser.add_argument(
            "--load-part",
            default="right",
            metavar="PART",
            help="body 2's part carrying the pulse (default right)",
        )
        parser.add_argument(
            "--method",
            default="auto",
            help="auto | matching | mortar: how the interface is glued (default auto: matching "
            "if the nodes pair up)",
        )
        material_options(parser, TWO_BODIES_MATERIAL, rho=1.0, plane="stress")
        for k in (1, 2):
            parser.add_argument(
                f"--material{k}",
                action="append",
                default=None,
                metavar="NAME:KEY=VALUE,...",
                help=f"with --mesh{k}: a material of body {k} by name, as --material of "
                f"eld-tip-mass (keys E, nu or lam, mu, and rho; rho defaults to "
                f"--rho{'' if k == 1 else '2'}); repeatable; without --region{k} a material fills "
                f"the physical group of its NAME; instead of body {k}'s "
                + "/".join(_BODY_CONSTANTS[k]),
            )
            parser.add_argument(
                f"--region{k}",
                action="append",
                default=None,
                metavar="NAME=GROUP[,GROUP]",
                help=f"with --material{k}: the physical groups of --mesh{k} that material NAME "
                f"fills; repeatable; every cell of body {k} must get one material",
            )
        names = {"E": "Young's modulus", "nu": "Poisson ratio", "lam": "Lamé lambda"}
        names["mu"] = "Lamé mu"
        for key, option in _BODY2_OPTIONS.items():
            if key == "rho":
                float_option(parser, option, default=2.0, help="body 2's density (default 2)")
                continue
            default = TWO_BODIES_MATERIAL2.get(key)
            float_option(
                parser,
                option,
                default=None,
                help=f"body 2's {names[key]}"
                + (f" (default {default:g})" if default is not None else "")
                + " (--E2/--nu2 or --lam2/--mu2)",
            )
        float_option(
            parser,
            "--force",
            default=0.1,
            help="amplitude F of the traction pulse F sin^2(pi t / T_p) (t < T_p) on --load-part "
            "(default 0.1)",
        )
        parser.add_argument(
            "--direction",
            default="y",
            help="x | y | z: the pulse's direction (z with 3D mesh files) (default y)",
        )
        float_option(parser, "--pulse", default=0.5, help="pulse duration T_p (default 0.5)")
        float_option(parser, "--T", default=2.0, help="end time (default 2)")
        parser.add_argument(
            "--compare-union",
            action="store_true",
            help="also run the single body on the union mesh (two materials per cell, the "
            "strip with matching meshes only) and report the difference and the seconds per "
            "step of both",
        )
        self.space_options(parser)
        add_output_options(parser, self.name)
        add_run_options(parser)

    def validate(self, args):
        """The checks that need no mesh: one line naming the option."""
        objects = self.run_objects(args)
        meshes = args.mesh1 is not None or args.mesh2 is not None
        if meshes:
            if args.mesh1 is None or args.mesh2 is None:
                missing = "--mesh1" if args.mesh1 is None else "--mesh2"
                raise fail(missing, None, "must be given with the other mesh file")
            for option in ("--n1", "--n2", "--length", "--height", "--split"):
                if given(args, option):
                    raise fail(
                        option,
                        getattr(args, option[2:]),
                        "is used without --mesh1/--mesh2 only",
                    )
        n1 = check_int("--n1", args.n1, minimum=1)
        n2 = n1 if args.n2 is None else check_int("--n2", args.n2, minimum=1)
        for option in ("--degree", "--degree2"):
            value = getattr(args, option[2:])
            if value is not None and value not in (1, 2):
                raise fail(option, value, "must be 1 or 2")
        length = check_positive("--length", args.length)
        check_positive("--height", args.height)
        if not 0 < args.split < length:
            raise fail(
                "--split", args.split, f"must lie strictly between 0 and --length {length:g}"
            )
        check_choice("--method", args.method, ("auto", "matching", "mortar"))
        check_choice("--direction", args.direction, ("x", "y", "z"))
        if args.direction == "z" and args.mesh1 is None:
            raise fail("--direction", "z", "needs 3D bodies (--mesh1/--mesh2); the strip is 2D")
        check_positive("--pulse", args.pulse)
        for k in (1, 2):
            self.check_body_materials(args, k)
        parts = args.interface.split(",")
        if len(parts) != 2 or not all(parts):
            raise fail("--interface", args.interface, "must be PART1,PART2 (body 1's, body 2's)")
        if args.clamp == parts[0]:
            raise fail(
                "--clamp",
                args.clamp,
                f"is body 1's glued part (--interface {args.interface}); a part is either "
                "clamped or glued",
            )
        if args.compare_union and args.adapt_space:
            raise fail(
                "--compare-union",
                described("it with --adapt-space"),
                "needs the fixed matching meshes (the union body's cells are both bodies'); "
                "compare an adaptive run with the fixed-mesh run by its summary instead",
            )
        if args.compare_union:
            same = {
                "--mesh1": args.mesh1 is None,
                "--n2": n2 == n1,
                "--degree2": args.degree2 in (None, args.degree),
                "--interface": tuple(parts) == ("right", "left"),
                "--clamp": args.clamp == "left",
                "--load-part": args.load_part == "right",
            }
            for option, ok in same.items():
                if not ok:
                    raise fail(
                        "--compare-union",
                        described(
                            f"it with {option} {getattr(args, option[2:].replace('-', '_'))}"
                        ),
                        "needs the strip with matching meshes (no --mesh1/--mesh2, --n2 = --n1, "
                        "--degree2 = --degree) and the default --interface, --clamp, --load-part",
                    )
        material1 = material_of(args, TWO_BODIES_MATERIAL)
        return objects, (n1, n2), tuple(parts), material1, self.material2(args)

    @staticmethod
    def union_fields(glued, traj, problem, result) -> dict:
        """The glued run against the union-mesh run: max |u_k(T) - u(T)| at every body's
        nodes relative to max |u(T)|, max |E_glued - E| / max E over the states (uniform
        steps; the final energies otherwise), the seconds per step of both."""
        U = result.state.u.reshape(-1, 2)
        tree = cKDTree(problem.space.doflocs.T)
        final = glued.fields(np.asarray(traj["u"])[-1], np.asarray(traj["q"])[-1])
        diff = max(
            float(np.abs(u.reshape(-1, 2) - U[tree.query(space.doflocs.T)[1]]).max())
            for u, (_, space) in zip(final, glued.bodies(), strict=True)
        )
        E, E1 = np.asarray(traj["energy"]), np.asarray(result.trajectory["energy"])
        if E.shape != E1.shape:
            E, E1 = E[-1:], E1[-1:]
        st = result.trajectory.stats
        per_step = st.wall_time_s / max(st.accepted_steps, 1)
        return {
            "union_ndofs": int(problem.space.ndofs),
            "union_difference_u": diff / max(float(np.abs(U).max()), 1e-300),
            "union_difference_energy": float(np.abs(E - E1).max() / max(E1.max(), 1e-300)),
            "union_seconds_per_step": per_step,
            "union_accepted_steps": st.accepted_steps,
            "seconds_per_step_ratio": traj.stats.wall_time_s
            / max(traj.stats.accepted_steps, 1)
            / per_step,
        }

    @staticmethod
    def _body_shadow(args, k: int):
        """Body k's --material<k>/--region<k> as the --material/--region of
        :func:`~rothe.cli.eld_options.body_material` (with body k's density option), and the
        names to rename in its refusals."""
        shadow = argparse.Namespace(
            material=getattr(args, f"material{k}"),
            region=getattr(args, f"region{k}"),
            rho=args.rho if k == 1 else args.rho2,
            plane=args.plane,
            _given=getattr(args, "_given", ()),
        )
        names = {
            "--material": f"--material{k}",
            "--region": f"--region{k}",
            "materials": f"--material{k}",
            "regions": f"--region{k}",
        }
        return shadow, names

    @classmethod
    def check_body_materials(cls, args, k: int) -> None:
        """Body k's --material<k>/--region<k> that need no mesh: with --mesh<k> only,
        --region<k> with --material<k>, not with body k's constants, their syntax; one line
        naming the option."""
        material, region = getattr(args, f"material{k}"), getattr(args, f"region{k}")
        if region and not material:
            raise fail(f"--region{k}", region[0], f"needs --material{k} (the materials it places)")
        if not material:
            return
        if getattr(args, f"mesh{k}") is None:
            raise fail(
                f"--material{k}",
                material[0],
                f"is used with --mesh{k} only (its regions are the mesh file's physical groups)",
            )
        for option in _BODY_CONSTANTS[k]:
            if given(args, option):
                raise fail(
                    option,
                    getattr(args, option[2:]),
                    f"must not be combined with --material{k} (give body {k}'s constants in "
                    f"each --material{k})",
                )
        shadow, names = cls._body_shadow(args, k)
        try:
            material_constants(shadow)
            region_map(shadow)
        except RotheInputError as exc:
            raise exc.renamed(names.get(exc.parameter), names) from None

    @classmethod
    def body_materials(cls, args, k: int, mesh):
        """Body k's :class:`~rothe.eld.materials.PiecewiseMaterial` of --material<k>/
        --region<k> on its mesh (in the mesh's dimension), checked on the mesh's regions
        (unknown group, cells without a material: one line naming --region<k>/--material<k>)."""
        shadow, names = cls._body_shadow(args, k)
        try:
            material = body_material(shadow, {}, mesh)
            material.on_mesh(mesh)
        except RotheInputError as exc:
            if exc.parameter not in names:
                raise
            raise exc.renamed(names[exc.parameter], names) from None
        return material

    @staticmethod
    def material2(args, dim: int = 2):
        """Body 2's material of --E2/--nu2 | --lam2/--mu2, --rho2 (errors name them), in
        ``dim`` (3D: plane strain, --plane is body 1's option and refused there)."""
        shadow = argparse.Namespace(
            plane=args.plane, **{key: getattr(args, o[2:]) for key, o in _BODY2_OPTIONS.items()}
        )
        try:
            return material_of(shadow, TWO_BODIES_MATERIAL2, dim=dim)
        except RotheInputError as exc:
            if exc.parameter not in _BODY2_OPTIONS:
                raise
            raise exc.renamed(_BODY2_OPTIONS[exc.parameter], _BODY2_OPTIONS) from None

    def execute(self, args) -> int:
        """Build the glued bodies, run them, write trajectory, ParaView series, figure and
        summary."""
        objects, (n1, n2), (part1, part2), material1, material2 = self.validate(args)
        degree2 = args.degree if args.degree2 is None else args.degree2
        # no fixed cap on body 2 (the glue's Jacobian is sparse): refused only if the run cannot
        # fit in memory -- both bodies' unknowns (twice with --compare-union: the union body),
        # the strip's counted before its meshes are built
        if args.mesh1 is not None:
            mesh1 = load_mesh(args.mesh1, name="mesh1")
            mesh2 = load_mesh(args.mesh2, name="mesh2")
            d = mesh_dim(mesh1)
            if mesh_dim(mesh2) != d:
                raise fail(
                    "--mesh2",
                    described(f"a {mesh_dim(mesh2)}D mesh"),
                    f"must have body 1's dimension {d}",
                )
            if d == 3:  # (validate built the materials in 2D, before the meshes were read)
                material1 = material_of(args, TWO_BODIES_MATERIAL, dim=3)
                material2 = self.material2(args, dim=3)
            elif args.direction == "z":
                raise fail("--direction", "z", "needs 3D bodies; the mesh files are 2D")
            # several materials per body on its mesh's regions (--material<k>/--region<k>)
            if args.material1:
                material1 = self.body_materials(args, 1, mesh1)
            if args.material2:
                material2 = self.body_materials(args, 2, mesh2)
            # P2: one more node per edge (the facets in 2D)
            dofs = sum(
                d * (m.p.shape[1] + ((m.facets if d == 2 else m.edges).shape[1] if k == 2 else 0))
                for m, k in ((mesh1, args.degree), (mesh2, degree2))
            )
            option, value = "--mesh2", args.mesh2
        else:
            dofs = sum(
                strip_pair_dofs(args.length, args.height, args.split, n1, n2, args.degree, degree2)
            )
            option, value = ("--n2", n2) if args.n2 is not None and n2 >= n1 else ("--n1", n1)
        check_memory(
            option,
            value,
            dofs * (2 if args.compare_union else 1),
            TWO_BODIES_BYTES_PER_DOF
            + TWO_BODIES_BYTES_PER_DOF_STATE * (1 + round(args.T / args.tau)),
            what="unknowns",
        )
        if args.mesh1 is None:
            mesh1, mesh2 = strip_pair(args.length, args.height, args.split, n1, n2)
        axis = "xyz".index(args.direction)
        force, pulse = args.force, args.pulse

        def traction(t, x, n):
            out = np.zeros_like(x)
            if t < pulse:
                out[axis] = force * np.sin(np.pi * t / pulse) ** 2
            return out

        glued = GluedBodies(
            Body(mesh1, material1, degree=args.degree, clamped=(args.clamp,), name="body1"),
            [
                (
                    Body(
                        mesh2,
                        material2,
                        degree=degree2,
                        traction={args.load_part: traction},
                        name="body2",
                    ),
                    part1,
                    part2,
                )
            ],
            method=args.method,
            T=args.T,
        )
        union = None
        if args.compare_union:  # the reference, like eld-tip-mass's modal analysis: before
            problem = strip_union(
                args.length,
                args.height,
                args.split,
                n1,
                args.degree,
                material1,
                material2,
                traction={"right": traction},
                T=args.T,
            )
            union = (problem, run_eld(problem, **objects))
        comp = glued.components[0]
        space2 = comp.problem.space
        # the watched dof: body 2's node nearest the load part's centre, along the pulse
        loaded = space2.doflocs[:, space2.scalar_dofs_on((args.load_part,), "traction")]
        centre = loaded.mean(axis=1)
        node = int(np.argmin(np.linalg.norm(space2.doflocs - centre[:, None], axis=0)))
        tip = int(np.searchsorted(comp.free, space2.dim * node + axis))
        itf = glued.interfaces[0]

        def summarize(summary, trajs, completed):
            traj = trajs["bodies"]
            q = np.asarray(traj["q"])
            reaction = np.asarray(traj[f"reaction_{part1}"])
            clamp = np.asarray(traj[f"reaction_{args.clamp}"])
            steps = summary["accepted_steps"]
            summary.update(
                ndofs=[summary.get("ndofs", glued.base.space.ndofs), comp.problem.space.ndofs],
                degree=[args.degree, degree2],
                material1=summary_material(args, TWO_BODIES_MATERIAL, material1),
                material2=material2.describe(),
                interface_method=itf.method,
                interface=itf.describe(),
                adaptive_body="body1" if self.adapt is not None else None,
                force=force,
                direction=args.direction,
                pulse=pulse,
                watch_point=space2.doflocs[:, node].tolist(),
                tip_deflection_max=float(np.abs(q[:, tip]).max()),
                tip_deflection_final=float(q[-1, tip]),
                interface_reaction_max=np.abs(reaction).max(axis=0).tolist(),
                clamp_reaction_max=np.abs(clamp).max(axis=0).tolist(),
                balance_max=float(np.abs(traj["balance"]).max()),
                constraint_max=float(np.abs(traj["constraint"]).max()),
                energy_final=float(traj["energy"][-1]),
                work_loads=float(traj["work_components"][-1]),
                seconds_per_step=summary["wall_time_s"] / max(steps, 1),
                # one series per body; an adaptive base's is a .pvd of VTU files
                paraview=[
                    f"{n}.pvd" if k == 0 and self.adapt is not None else f"{n}.xdmf"
                    for k, (n, _) in enumerate(glued.bodies())
                ],
            )
            final = self.results.get("bodies")
            if self.adapt is not None and final is not None:
                # the glue of the last mesh: matching while body 1's interface facets are as
                # they started, mortar once they are refined
                itf_final = final.stepper.system.couplings[0].interface
                summary.update(
                    interface_method_final=itf_final.method,
                    interface_final=itf_final.describe(),
                )
            # the strip's sizes or the mesh files (before: mesh1 = mesh2 = null on every strip
            # run without --compare-union, the else of the union's test)
            if args.mesh1 is None:
                summary.update(
                    n1=n1, n2=n2, length=args.length, height=args.height, split=args.split
                )
            else:
                summary.update(mesh1=args.mesh1, mesh2=args.mesh2, dim=space2.dim)
            if union is not None and completed:
                summary.update(self.union_fields(glued, traj, *union))

        def draw(stage, trajs, summary):
            # matplotlib is imported only for the figures
            from ..eld.figures import plot_comparison

            plot_comparison(
                {"glued bodies": trajs["bodies"]},
                stage / "fig_two_bodies.png",
                coordinate=tip,
                label=f"body 2: u_{args.direction} at {np.round(centre, 3).tolist()}",
                part=part1,
                axis=axis,
                title=f"eld-two-bodies ({itf.method} interface): interface reaction on body 1",
            )

        def outputs(stage, label, result):
            return write_bodies_result(result, glued, stage)

        return self.run(
            args, {"bodies": glued.system}, objects, summarize, draw, fields=True, outputs=outputs
        )
