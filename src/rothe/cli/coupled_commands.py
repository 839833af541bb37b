"""CLI commands for elastic bodies coupled to other dynamical systems (issue 19):
``rothe run eld-tip-mass``.

Outputs: ``summary.json`` (the frequencies measured from the run against the analytic and the
discrete ones, the energy ledger's closure, steps), ``trajectory.npz`` (the component's q, p,
the reactions on every constrained part, the whole-system ledger per state, the steps; see
:class:`rothe.eld.coupled_run.CoupledResult`) and ``fig_tip_mass.png`` unless ``--no-plots``.
Bad input is one line and exit status 2; a run that fails midway exits 1. Coupled runs have no
checkpoints, space adaptivity or ParaView output yet (docs/coupling.md, Sec. 12).
"""

from __future__ import annotations

import numpy as np

from ..eld.coupled_run import run_coupled
from ..eld.examples import tip_mass_problem
from ..errors import check_int, check_positive, described, fail
from .common import (
    add_output_options,
    output_dir,
    parse_float,
    peak_memory_mb,
    print_summary,
    progress_of,
    write_summary,
)
from .eld_options import (
    MESH_PARAMETERS,
    body_material,
    body_mesh,
    check_eld_step,
    check_mesh_options,
    control_of,
    form_of,
    lifting_option,
    material_fields,
    material_of,
    material_options,
    mesh_fields,
    mesh_options,
    parts_of,
    scheme_of,
    step_options,
)
from .registry import command

#: the strip's material (nu = 0: the axial motion is the 1D bar's, the analytic frequencies are
#: exact for it)
TIP_MASS_MATERIAL = {"E": 100.0, "nu": 0.0}
#: the most cells the dense modal analysis behind the reference frequencies takes
TIP_MASS_MAX_CELLS = 4000
#: the most unknowns of a --mesh body for that analysis (the built-in strip's cap in 2D P2)
TIP_MASS_MAX_DOFS = 16_000


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


TIP_MASS_KEYS = (
    "example",
    "scheme",
    "form",
    "control",
    "accepted_steps",
    "rejected_steps",
    "ndofs",
    "frequency_analytic",
    "frequency_discrete",
    "frequency_measured",
    "frequency_error_measured",
    "energy_drift",
    "balance_max",
    "wall_time_s",
)


def crossing_frequency(t: np.ndarray, y: np.ndarray) -> float:
    """pi / the mean time between the zero crossings of y(t) (linear interpolation); nan with
    fewer than two crossings."""
    s = np.sign(y)
    k = np.flatnonzero(s[:-1] * s[1:] < 0)
    if k.size < 2:
        return float("nan")
    tz = t[k] - y[k] * (t[k + 1] - t[k]) / (y[k + 1] - y[k])
    return float(np.pi / np.mean(np.diff(tz)))


@command("run", "eld-tip-mass")
class RunEldTipMass:
    """``rothe run eld-tip-mass``: a clamped bar carrying a mass-spring at its tip."""

    help = (
        "Clamped plane-stress bar carrying a mass on a spring at its free end (a coupled "
        "component, B u = q on the end): the first axial frequency measured from the run "
        "against the bar-with-tip-mass equation"
    )
    name = "eld-tip-mass"
    #: the library's parameters by their options (the tip's coupling is couplings[0])
    parameter_options = {**MESH_PARAMETERS, "couplings[0].part": "--tip"}

    def configure(self, parser) -> None:
        """Add the eld-tip-mass options (step, lifting, bar, material, mass, spring, damper)."""
        step_options(parser, 0.005, scheme_default="bdf2")
        lifting_option(parser)
        parser.add_argument(
            "--n", type=int, default=2, help="cells across the bar (default 2; n L/H along)"
        )
        parser.add_argument("--degree", type=int, default=2, help="1 or 2 (default 2)")
        parser.add_argument(
            "--length", type=parse_float("--length"), default=1.0, help="bar length L (default 1)"
        )
        parser.add_argument(
            "--height",
            type=parse_float("--height"),
            default=0.25,
            help="bar height H, the cross-section per unit thickness (default 0.25)",
        )
        material_options(parser, TIP_MASS_MATERIAL, rho=1.0, plane="stress")
        mesh_options(
            parser,
            dirichlet="left",
            dirichlet_help="the clamped boundary parts (u = 0)",
        )
        parser.add_argument(
            "--tip",
            default="right",
            metavar="PART",
            help="the boundary part tied to the mass (B u = q there) (default right)",
        )
        parser.add_argument(
            "--mass",
            type=parse_float("--mass"),
            default=0.25,
            help="tip mass m (default 0.25 = the bar's mass rho H L)",
        )
        parser.add_argument(
            "--spring",
            type=parse_float("--spring"),
            default=0.0,
            help="stiffness k of the spring from the tip mass to the ground (default 0)",
        )
        parser.add_argument(
            "--damper",
            type=parse_float("--damper"),
            default=0.0,
            help="damping c of the tip mass to the ground (default 0: no damping, the energy "
            "is kept up to the scheme's numerical dissipation)",
        )
        parser.add_argument(
            "--amplitude",
            type=parse_float("--amplitude"),
            default=0.01,
            help="initial tip displacement in the first axial mode (default 0.01)",
        )
        parser.add_argument(
            "--T",
            type=parse_float("--T"),
            default=2.0,
            help="end time (default 2: about 2.7 periods of the first mode)",
        )
        add_output_options(parser, self.name)

    def validate(self, args):
        """The checks that need no mesh: one line naming the option."""
        check_eld_step("--tau", args.tau, args.T)
        control = control_of(args)
        check_mesh_options(args, ("--n", "--length", "--height"))
        n = check_int("--n", args.n, minimum=1)
        if args.degree not in (1, 2):
            raise fail("--degree", args.degree, "must be 1 or 2")
        length = check_positive("--length", args.length)
        height = check_positive("--height", args.height)
        cells = 2 * n * max(1, round(n * length / height))
        if args.mesh is None and cells > TIP_MASS_MAX_CELLS:
            raise fail(
                "--n",
                n,
                f"gives {cells} cells, must give at most {TIP_MASS_MAX_CELLS} (the reference "
                "frequencies come from a dense modal analysis)",
            )
        parts_of(args)
        if args.mesh is None and not args.material:
            material_of(args, TIP_MASS_MATERIAL)  # (on a mesh: in its dimension, when loaded)
        return {"scheme": scheme_of(args), "form": form_of(args), "control": control}, n

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
        )
        out = output_dir(args, self.name)
        result = run_coupled(example.system, progress=progress_of(args), **objects)
        traj = result.trajectory
        t, q = traj["t"], np.asarray(traj["q"])
        measured = crossing_frequency(t, q[:, 0])
        energy = traj["energy"]
        control = objects["control"]
        summary = {
            "example": self.name,
            "status": "completed",
            "scheme": objects["scheme"].name,
            "form": objects["form"].name,
            "lifting": objects["form"].lifting,
            "control": type(control).__name__.lower(),
            "tau": args.tau,
            "tol": getattr(control, "tol", None),
            "accepted_steps": traj.stats.accepted_steps,
            "rejected_steps": traj.stats.rejected_steps,
            "n": n,
            "degree": args.degree,
            "ndofs": example.system.body.space.ndofs,
            "length": args.length,
            "height": args.height,
            **(
                {"material": material.describe()}
                if args.material
                else material_fields(args, TIP_MASS_MATERIAL, material)
            ),
            "mass": args.mass,
            "spring": args.spring,
            "damper": args.damper,
            "T": args.T,
            "frequency_analytic": example.analytic.tolist(),
            "frequency_discrete": example.discrete.tolist(),
            "frequency_error_discrete": (example.discrete / example.analytic - 1).tolist(),
            "frequency_measured": measured,
            "frequency_error_measured": measured / example.analytic[0] - 1,
            "frequency_error_measured_vs_discrete": measured / example.discrete[0] - 1,
            "energy_initial": float(energy[0]),
            "energy_drift": float(energy[-1] / energy[0] - 1),
            "balance_max": float(np.abs(traj["balance"]).max()),
            "wall_time_s": traj.stats.wall_time_s,
            "peak_memory_mb": peak_memory_mb(),
        }
        if mesh is not None:
            del summary["n"], summary["height"]
            summary.update(
                mesh_fields(args, mesh),
                dirichlet=list(parts_of(args)),
                tip=args.tip,
                length=example.length,
                area=example.area,
            )
        traj.save_npz(out / "trajectory.npz")
        if not args.no_plots:
            # matplotlib is imported only for the figures
            from ..eld.figures import plot_tip_mass

            plot_tip_mass(
                traj,
                out / "fig_tip_mass.png",
                title=f"eld-tip-mass, {summary['scheme']}, {summary['form']}, "
                f"m = {args.mass:g}, k = {args.spring:g}",
            )
        write_summary(out, summary)
        if not args.quiet:
            print(f"rothe run {self.name}: wrote {out}/")
            print_summary(summary, TIP_MASS_KEYS)
        return 0
