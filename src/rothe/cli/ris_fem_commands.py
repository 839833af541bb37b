"""CLI commands for finite-element RIS: ``run ris-2d``, ``run ris-3d``, ``run ris-front``,
``run ris-front-unique``, ``compare ris-2d``.

``run ris-2d`` is Example 7.2 of Andreia & Meyer (2022) on an N x N grid of the unit square
(default N = 40: 1681 nodes) or on any 2D mesh file; ``run ris-3d`` the same energy on the unit
cube or a 3D mesh file. Besides the outputs of every run (summary.json, trajectory.npz, figures)
they write the mesh into trajectory.npz (``nodes``, ``cells``), ``solution.xdmf`` + ``.h5`` (z
over s, for ParaView), the Fig. 4 analogue and snapshots of z. ``compare ris-2d`` draws Fig. 5
and writes ``compare.json``: one row per run with its work and the work ratios to the uniform
scheme at the same global residual (:func:`compare_rows`).
``run ris-front`` is a phase front crossing the unit square (space adaptivity pays there);
``run ris-front-unique`` a steep front of a strictly convex energy (a unique solution: the
benchmark problem of space adaptivity).

``--adapt-space`` (with ``--space-tol``, ``--refine-fraction``, ``--coarsen-fraction``,
``--max-dofs``, ``--adapt-every``, ``--refine-band``, ``--coarsen-delay``, ``--max-recoarsen``,
``--coarsen-batch``) adapts the mesh between steps
(:mod:`rothe.ris.adapt`); the run then writes every distinct mesh into trajectory.npz,
``solution.pvd`` + one VTU per state (its own mesh) instead of solution.xdmf, the dofs against
t and s (``fig_dofs.png``) and snapshots of mesh and z (``fig_mesh_snapshots.png``).
"""

from __future__ import annotations

import json
import time

import numpy as np

from ..errors import RotheInputError, RunFailed, check_choice, check_int, check_positive, fail
from ..fem.adapt import check_adaptable
from ..fem.linear import LINEAR_SOLVERS, ReusableSolver
from ..fem.mesh import DUPLICATE_NODES, load_mesh
from ..io.atomic import atomic_write_text
from ..io.mesh_series import write_vtu_series
from ..io.xdmf import write_series
from ..parallel import Task, TaskFailed
from ..ris import examples
from ..ris.adapt import HYSTERESIS
from ..ris.inner import InnerOptions, amg_threshold_for
from ..ris.run import run_ris, stored_states
from ..ris.summary import (
    compare_rows,
    describe_branch,
    equidistribution_bound,
    finest_uniform_bound,
    format_jump_times,
    ris_summary,
)
from .adapt_options import (
    add_space_options,
    check_memory,
    fit_default_cap,
    space_adaptivity,
)
from .common import (
    _jsonable,
    add_output_options,
    add_parallel_options,
    executor_from_args,
    float_option,
    given,
    output_dir,
    parse_float_list,
    peak_memory_mb,
    progress_of,
    write_summary,
    write_table,
)
from .registry import command
from .ris_commands import RISRunBase, check_step, compare_rows_of, control_object, run_cost

#: ReusableSolver.kind_used for each resolved method (kept in sync by tests/cli/test_cli_ris_fem.py)
LINEAR_KINDS = {"direct": "splu", "amg": "pyamg-sa"}
#: uniform steps of ``compare ris-2d``: 0.01 / 2^k, k = 0..8, so that the uniform global residuals
#: (about 1.2 ... 0.0047 on Example 7.2, 40 x 40) bracket those of adaptive, order2 and regime at
#: tol = 1e-4 ... 1e-6 (0.093 ... 0.0083); k = 7 alone (0.0095) left tol = 1e-6 unbracketed
COMPARE_TAUS = tuple(0.01 / 2**k for k in range(9))
#: the step controllers ``compare ris-2d`` runs besides uniform
COMPARE_CONTROLS = ("adaptive", "order2", "regime")


#: the summary lines of an --adapt-space run's mesh changes (printed when summary.json has them)
MESH_CHANGE_KEYS = (
    "space_adaptations",
    "transfer_energy_abs_sum",
    "relax_energy_sum",
    "dissipation_sum",
    "max_recoarsened",
    "relax_refused",
)


def linear_solver_used(traj, problem, method: str = "auto") -> str:
    """The linear solver of the run's Newton systems.

    Taken from ``traj.meta['linear_solver']`` when the stepper records it; otherwise the kind
    that :class:`~rothe.fem.linear.ReusableSolver` selects for this many unknowns (its
    choice is a deterministic function of the method and the size, so this is what ran).
    """
    if traj.meta.get("linear_solver"):
        return str(traj.meta["linear_solver"])

    o = InnerOptions(linear_solver=method)
    solver = ReusableSolver(o.linear_solver, amg_threshold=amg_threshold_for(problem, o))
    kind = solver.resolve_kind(problem.n)
    return LINEAR_KINDS[kind]


#: values of --xdmf-time
XDMF_TIME = ("s", "t")

#: peak memory per mesh node of ``run ris-2d`` / ``ris-3d`` (bytes), to refuse a --n that
#: cannot fit before anything is allocated. Measured (peak_memory_mb of summary.json minus the
#: ~90 MB of the interpreter and libraries; uniform tau 0.25, auto solver): 2D 2.0-2.5 kB/node
#: at N = 200 and 400 (sparse LU), 2.7 GB at 10^6 nodes; 3D 11-12 kB/node at N = 30 and 36
#: (LU fill of 3D stencils, up to 50k unknowns), 3.4 kB/node at N = 50 (AMG). An estimate to
#: refuse the impossible (N = 100000 asks for 30 TB), not a budget.
RIS_BYTES_PER_NODE = {2: 3000, 3: 12000}


def grid_nodes(n: int, dim: int) -> int:
    """Nodes of the built-in grid with n cells per side in ``dim`` dimensions."""
    return (n + 1) ** dim


def _as_option_error(exc, args):
    """A problem-level input error caused by --z0 or --amplitude, renamed after the option."""
    text = str(exc)
    for prefix, option in (
        ("load", "--amplitude"),
        ("F(z0)", "--z0"),
        ("dF(z0)", "--z0"),
        ("d2F(z0)", "--z0"),
        ("z0", "--z0"),
    ):
        if text.startswith(prefix):
            value = args.amplitude if option == "--amplitude" else args.z0
            return fail(option, value, f"gives non-finite data ({text})")
    return exc


def last_state_per_time(t: np.ndarray, T: float) -> np.ndarray:
    """Indices of the last state of each run of states with equal t (within 1e-12 max(1, T)).

    With physical time on ParaView's slider, the states of a viscous jump (t^ constant) would
    share one time value; only the jump's end state is kept, the state at that t after it.
    """
    t = np.asarray(t, dtype=float)
    if t.size == 0:
        return np.zeros(0, dtype=np.int64)
    later = np.diff(t) > 1e-12 * max(1.0, T)
    return np.nonzero(np.append(later, True))[0]


class _RunRISFem(RISRunBase):
    dim = 2
    #: API parameters whose option has another name (the command line renames refusals)
    parameter_options = {"adapt": "--adapt-space"}
    default_tau = 0.1
    default_n = 40
    default_z0 = 0.0
    default_amplitude = -200.0
    #: default --space-tol: about half the estimate of the default grid at T, so an adapted run is
    #: at least as fine as the default grid where the step needs it. Example 7.2's residual grows
    #: with the load (A t^3) and is O(h) over the whole domain: the estimate of the 40 x 40 grid
    #: is 0.1 at the jump (t = 0.2) and 5.4 at T (2.7 on 80 x 80). The former default 1 asked for
    #: h ~ 1/220 at T: the mesh grew to 28 000-30 000 nodes and no residual control reached T in
    #: 5 minutes; at 2.5 the adaptive control reaches T in 96 s with 6 mesh changes and at most
    #: 4 954 nodes (docs/ris_fem.md). The indicator overestimates the energy error about 5x.
    default_space_tol = 2.5
    #: defaults of --adapt-every and --refine-band (None: SpaceAdaptivity's and the family's)
    default_adapt_every = None
    default_refine_band = None
    #: default --max-dofs: Example 7.2's state has kinks (sticking/moving interfaces) that keep
    #: the estimate above any tolerance, so an uncapped 3D run went from 27 to 740 000 unknowns
    #: (4.7 GB) before t = 0.64 at --n 4
    default_max_dofs = 100_000
    #: the choices of --quadrature (rothe.ris.fem_problem.QUADRATURES)
    quadratures = ("lumped", "consistent")

    def add_example_options(self, parser) -> None:
        """The grid or mesh file, Dirichlet parts, z0, load, linear solver, outputs, meshes."""
        what = "N x N cells of the unit square" if self.dim == 2 else "N^3 cubes of the unit cube"
        parser.add_argument(
            "--n", type=int, default=None, help=f"grid of {what} (default {self.default_n})"
        )
        parser.add_argument(
            "--mesh",
            default=None,
            help="mesh file instead of the grid: anything meshio reads (gmsh .msh "
            "2.2/4.x, .vtu, .xdmf, ...), " + ("triangle" if self.dim == 2 else "tetra") + " cells",
        )
        parser.add_argument(
            "--dirichlet",
            default=None,
            help="comma-separated boundary parts (gmsh physical groups, or left,"
            "right,bottom,top"
            + (",front,back" if self.dim == 3 else "")
            + " on the grid) where z = 0; default: the whole boundary",
        )
        float_option(
            parser,
            "--z0",
            default=self.default_z0,
            help=f"initial state at every interior node (default {self.default_z0:g})",
        )
        float_option(
            parser,
            "--amplitude",
            default=self.default_amplitude,
            help=self.amplitude_help,
        )
        parser.add_argument(
            "--quadrature",
            default=None,
            help=" | ".join(self.quadratures)
            + ": the quadrature of int g(z) (and of a load density); default lumped (vertex "
            "rule), with --adapt-space consistent (a cell rule of degree 4: a refinement "
            "does not change the energy, docs/ris_fem.md)"
            if len(self.quadratures) > 1
            else "lumped (the only quadrature of this example: its energy is quadratic)",
        )
        parser.add_argument(
            "--linear-solver",
            default="auto",
            help="auto | direct | amg: solver of the Newton systems (default auto: "
            "sparse LU up to 400k unknowns in 2D, 50k in 3D, "
            "AMG-preconditioned Krylov above)",
        )
        parser.add_argument(
            "--duplicate-nodes",
            default="error",
            help="coincident nodes of a --mesh file used by different cells (a "
            "cut, like a crack): error (default) | merge (glue them) | keep "
            "(the cut is intended)",
        )
        parser.add_argument(
            "--xdmf-time",
            default="s",
            help="time axis of solution.xdmf (ParaView's time slider): s "
            "(default: the curve parameter, every state incl. the viscous "
            "jumps) | t (physical time: one state per t, a jump shows as "
            "its end state); with --adapt-space the same for solution.pvd",
        )
        add_space_options(
            parser,
            default_tol=self.default_space_tol,
            default_max_dofs=self.default_max_dofs,
            indicator="the step's residual indicator (docs/ris_fem.md)",
            hysteresis=(
                HYSTERESIS
                if self.default_refine_band is None
                else {**HYSTERESIS, "refine_band": self.default_refine_band}
            ),
            default_adapt_every=self.default_adapt_every,
        )

    amplitude_help = (
        "load <l(t), z> = A t^3 int z (default A = -200; its sign picks the branch z < 0 or z > 0)"
    )

    # hooks -----------------------------------------------------------------------------------
    def validate(self, args):
        """The FE options (memory for --n, --adapt-space), then the common checks."""
        check_choice("--linear-solver", args.linear_solver, LINEAR_SOLVERS)
        quadrature = args.quadrature
        if quadrature is None:
            # an adapted run's energy must not change when the mesh does (issue 18)
            adapted = args.adapt_space and "consistent" in self.quadratures
            quadrature = "consistent" if adapted else "lumped"
        check_choice("--quadrature", quadrature, self.quadratures)
        self._quadrature = quadrature
        check_choice("--duplicate-nodes", args.duplicate_nodes, DUPLICATE_NODES)
        check_choice("--xdmf-time", args.xdmf_time, XDMF_TIME)
        if args.mesh is None and given(args, "--duplicate-nodes"):
            raise fail(
                "--duplicate-nodes",
                args.duplicate_nodes,
                "is only used with --mesh (the built-in grids have no duplicate nodes)",
            )
        if args.mesh is not None and args.n is not None:
            raise fail("--n", args.n, "cannot be combined with --mesh (the mesh fixes the grid)")
        n = check_int("--n", args.n if args.n is not None else self.default_n, minimum=2)
        if args.mesh is None:
            check_memory(
                "--n", n, grid_nodes(n, self.dim), RIS_BYTES_PER_NODE[self.dim], what="nodes"
            )
        if args.adapt_space and args.mesh is not None:  # before loading: a quad file is named so
            check_adaptable(args.mesh, "--adapt-space")
        self._adapt = space_adaptivity(
            args,
            default_tol=self.default_space_tol,
            default_max_dofs=self.default_max_dofs,
            hysteresis=True,
            default_adapt_every=self.default_adapt_every,
        )
        if self._adapt is not None and args.refine_band is None:
            if self.default_refine_band is not None:
                self._adapt.refine_band = self.default_refine_band
        if self._adapt is not None and args.max_dofs is not None:
            check_memory("--max-dofs", args.max_dofs, args.max_dofs, RIS_BYTES_PER_NODE[self.dim])
        return super().validate(args)

    def run_options(self, args) -> dict:
        """``adapt=`` with --adapt-space."""
        return {} if self._adapt is None else {"adapt": self._adapt}

    def make_problem(self, n, mesh, args, dirichlet):
        """Example 7.2 (or its 3D analogue) on the grid or the mesh."""
        factory = examples.example_7_2 if self.dim == 2 else examples.example_7_2_3d
        return factory(
            n,
            mesh,
            amplitude=args.amplitude,
            z0=args.z0,
            dirichlet=dirichlet,
            quadrature=self._quadrature,
        )

    # hooks -----------------------------------------------------------------------------------
    def build_problem(self, args):
        """The problem of the options (a --mesh file loaded here); refusals name the option."""
        n = args.n if args.n is not None else self.default_n
        mesh = None
        if args.mesh is not None:
            mesh = load_mesh(
                args.mesh, dim=self.dim, name="--mesh", duplicate_nodes=args.duplicate_nodes
            )
        dirichlet = None
        if args.dirichlet is not None:
            dirichlet = [x.strip() for x in args.dirichlet.split(",") if x.strip()]
        t0 = time.perf_counter()
        try:
            problem = self.make_problem(n, mesh, args, dirichlet)
        except RotheInputError as exc:
            raise _as_option_error(exc, args) from None
        if self._adapt is not None:
            problem.check_movable()
            fit_default_cap(args, self._adapt, problem.n_nodes)
            if self._adapt.max_dofs < problem.n_nodes:
                raise fail(
                    "--max-dofs",
                    self._adapt.max_dofs,
                    f"must be >= the {problem.n_nodes} dofs of the initial mesh",
                )
        self._setup_time = time.perf_counter() - t0
        self._grid = None if mesh is not None else n
        return problem

    def inner_options(self, args):
        """--linear-solver."""
        return InnerOptions(linear_solver=args.linear_solver)

    def extra_summary(self, args, problem, traj) -> dict:
        """The mesh, solver, memory, the branch and, with --adapt-space, the meshes."""
        extra = {
            "mesh": args.mesh if args.mesh is not None else f"{self._grid}^{self.dim} grid",
            "n_nodes": problem.n_nodes,
            "n_cells": int(problem.mesh.t.shape[1]),
            "n_unknowns": problem.n,
            "linear_solver": linear_solver_used(traj, problem, args.linear_solver),
            "setup_time_s": getattr(self, "_setup_time", None),
            "peak_memory_mb": peak_memory_mb(),  # updated at the very end (summary_at_end)
            "z0": args.z0,
            "amplitude": args.amplitude,
            "quadrature": getattr(problem, "quadrature", "lumped"),
        }
        extra.update(describe_branch(problem, traj))
        if traj.meshes is not None:
            dofs = np.asarray(traj["n_dofs"])
            extra.update(
                # with the hysteresis the run used (the family's defaults where not given)
                adapt_space=self._adapt.describe() | (traj.meta.get("hysteresis") or {}),
                space_adaptations=traj.meta.get("space_adaptations"),
                transfer_failures=traj.meta.get("transfer_failures"),
                n_meshes=len(traj.meshes),
                n_dofs_initial=int(dofs[0]),
                n_dofs_final=int(dofs[-1]),
                n_dofs_max=int(dofs.max()),
                dofs_summed=int(dofs[1:].sum()),
                transfer_energy_sum=float(np.sum(traj["transfer_energy"])),
                # the ledger of the mesh changes against the path's own dissipation
                # (rothe.ris.adapt: the relaxation at fixed t is no step of the path)
                transfer_energy_abs_sum=float(np.sum(np.abs(traj["transfer_energy"]))),
                relax_energy_sum=float(np.sum(traj["relax_energy"])),
                relax_dissipation_sum=float(np.sum(traj["relax_dissipation"])),
                dissipation_sum=float(np.sum(traj["dissipation"])),
                relax_refused=traj.meta.get("relax_refused"),
                max_recoarsened=traj.meta.get("max_recoarsened"),
            )
        return extra

    def summary_at_end(self, args) -> dict:
        """The peak memory of the whole process."""
        # after the XDMF file and the figures: the peak of the whole process
        return {"peak_memory_mb": peak_memory_mb()}

    def summary_keys_extra(self):
        """The mesh (with --adapt-space the initial, final and largest dofs), the branch, with
        --adapt-space the ledger of the mesh changes (issue 18: how many, the transfer and the
        relaxation energy against the path's dissipation, the most re-coarsenings of a cell;
        only summary.json had them), the solver and the memory."""
        return (
            "n_nodes",
            "n_dofs_final",
            "energy_final",
            "z_min",
            "z_max",
            "n_viscous_jumps",
            "branch",
            *MESH_CHANGE_KEYS,
            "linear_solver",
            "peak_memory_mb",
        )

    def npz_extra(self, problem) -> dict:
        """``nodes`` and ``cells`` of a fixed mesh."""
        if self._adapt is not None:  # the meshes are in the trajectory's mesh series
            return {}
        return {"nodes": problem.nodes, "cells": problem.cells}

    def write_extra(self, args, problem, traj, out) -> None:
        """solution.xdmf (fixed mesh) or solution.pvd with one VTU per state (--adapt-space)."""
        s, t, z = stored_states(traj)
        if traj.meshes is not None:
            ids = np.asarray(traj["z_mesh_id"])
            keep = (
                last_state_per_time(t, problem.T)
                if getattr(args, "xdmf_time", "s") == "t"
                else np.arange(len(z))
            )
            times, other = (t, s) if getattr(args, "xdmf_time", "s") == "t" else (s, t)
            write_vtu_series(
                out,
                "solution",
                traj.meshes,
                ids[keep],
                times[keep],
                [
                    {"z": z[i], "t" if other is t else "s": np.full(len(z[i]), other[i])}
                    for i in keep
                ],
            )
            return
        if getattr(args, "xdmf_time", "s") == "t":
            keep = last_state_per_time(t, problem.T)
            write_series(
                out / "solution.xdmf",
                problem.nodes,
                problem.cells,
                t[keep],
                {"z": z[keep]},
                {"s": s[keep]},
            )
        else:
            write_series(out / "solution.xdmf", problem.nodes, problem.cells, s, {"z": z}, {"t": t})

    def plot(self, args, problem, runs, out) -> None:
        """Fig. 4, fig1_path.png, snapshots of z (with their meshes under --adapt-space)."""
        # matplotlib only when figures are drawn (start-up time of the command line)
        from ..ris.figures import plot_fig4, plot_path, plot_snapshots

        traj = runs[-1]
        label = f"{self.name}, {problem.n_nodes} nodes, {traj.meta.get('control')}"
        if traj.meta.get("tol") is not None and traj.meta.get("control") != "uniform":
            label += f", tol={traj.meta['tol']:g}"
        plot_fig4(runs, out / "fig4_steps.png", title=f"{self.name}: physical time and step size")
        plot_path(traj, out / "fig1_path.png", title=label)
        s, t, z = stored_states(traj)
        if traj.meshes is not None:
            # matplotlib, as above
            from ..plotting.adapt import plot_dofs, plot_mesh_snapshots
            from ..ris.figures import snapshot_indices

            plot_dofs(
                out / "fig_dofs.png",
                traj["t"],
                traj["n_dofs"],
                s=traj["s"],
                title=f"{self.name}: unknowns of the adapted meshes",
            )
            plot_mesh_snapshots(
                out / "fig_mesh_snapshots.png",
                traj.meshes,
                traj["z_mesh_id"],
                t,
                z,
                snapshot_indices(s),
                title=label,
            )
            return
        plot_snapshots(
            problem.nodes, problem.cells, s, t, z, out / "fig_snapshots.png", title=label
        )


@command("run", "ris-2d")
class RunRIS2D(_RunRISFem):
    """``rothe run ris-2d``: Example 7.2."""

    help = (
        "Example 7.2 of Andreia & Meyer (2022): P1 finite elements on the unit square "
        "(N x N grid, default 40: 1681 nodes) or a mesh file"
    )
    name = "ris-2d"
    dim = 2
    default_n = 40


@command("run", "ris-3d")
class RunRIS3D(_RunRISFem):
    """``rothe run ris-3d``: the energy of Example 7.2 on the unit cube."""

    help = (
        "The energy of Example 7.2 on the unit cube (P1 tetrahedra, N^3 cubes, default 12) "
        "or a 3D mesh file"
    )
    name = "ris-3d"
    dim = 3
    default_n = 12
    #: half the estimate of the default 12^3 grid at T (24.4; 40 on 8^3, 93 on 4^3), as in 2D
    default_space_tol = 12.0
    default_max_dofs = 50_000


@command("run", "ris-front")
class RunRISFront(_RunRISFem):
    """``rothe run ris-front``: a phase front crossing the unit square."""

    help = (
        "A phase front crossing the unit square (double well of Example 7.2, a load growing "
        "from a corner): the example for --adapt-space"
    )
    name = "ris-front"
    dim = 2
    default_n = 16
    default_tau = 0.02
    default_z0 = 1.0
    default_amplitude = -120.0
    #: default --control uniform (tau = 0.02 in s): the double-well front crosses any grid by
    #: lattice jumps (233 on the fixed 16 x 16 grid), and the residual controllers resolve each
    #: of them (adaptive, tol 1e-4: 5 585 accepted and 4 254 rejected steps, 122 s on 289 nodes
    #: without any mesh change); the example is about space, so its steps are fixed in s like
    #: those of the space-adaptivity benchmark (docs/ris_fem.md, issue 18 item 0)
    default_control = "uniform"
    #: --tol 1e-3 for the residual controls (1e-4 elsewhere): on the fixed 4 x 4 grid their
    #: paths stay within 1e-3 of a fine uniform one (relative V-distance of z(t); the default
    #: uniform tau = 0.02: 1.2e-2) at 1/2.6-1/3.2 of the CPU seconds of 1e-4, and with
    #: --adapt-space all three reach T in a few minutes, which at 1e-4 only order2 and regime
    #: do, in 215-251 s (docs/adaptivity.md, "Should ris-front's residual controls default to
    #: --tol 1e-3?")
    default_tol = 1e-3
    #: --tols 1e-2,1e-3 for nested: its last pass at the residual controls' --tol (the default
    #: 1e-3,1e-4,1e-5 had not reached T with --adapt-space after 20 minutes, its 1e-5 pass at
    #: t = 0.2; docs/adaptivity.md, "ris-front's nested control")
    default_tols = (1e-2, 1e-3)
    #: default --space-tol 3, --adapt-every 4, --refine-band 0.08: at tol 1 the indicator
    #: resolves the 0.023-wide interface and the static boundary layer at x = 1 to 8 000 nodes
    #: by t = 0.42 (126 s); at 3 the mesh stays under 2 000 nodes; adapting every 4th step with
    #: a band that covers the front's travel (1.6 x 4 x 0.02 x t') cut the adapt phase from 49 s
    #: to 17 s (docs/ris_fem.md)
    default_space_tol = 3.0
    default_adapt_every = 4
    default_refine_band = 0.08
    amplitude_help = (
        "plateau A of the load density A/2 (1 + tanh((v t - |x|)/w)) (default "
        "-120: beyond max |g'| = 73.9 + kappa, so the state flips to the well "
        "near -1 behind the front)"
    )
    #: the example's parameters (the default of --coefficient)
    defaults = examples.FRONT_DEFAULTS
    coefficient_help = (
        "c of 1/2 int c |grad z|^2 (default 0.1; the interface is about sqrt(c/192) wide)"
    )

    def add_example_options(self, parser) -> None:
        """The options of ris-2d and --coefficient."""
        super().add_example_options(parser)
        float_option(parser, "--coefficient", default=None, help=self.coefficient_help)

    def validate(self, args):
        """--coefficient > 0, then the checks of ris-2d."""
        default = self.defaults["coefficient"]
        self._coefficient = check_positive(
            "--coefficient", default if args.coefficient is None else args.coefficient
        )
        return super().validate(args)

    def make_problem(self, n, mesh, args, dirichlet):
        """The front example (z = 0 on the right side unless --dirichlet says otherwise)."""
        return examples.example_front(
            n,
            mesh,
            amplitude=args.amplitude,
            z0=args.z0,
            coefficient=self._coefficient,
            dirichlet=("right",) if dirichlet is None else dirichlet,
            quadrature=self._quadrature,
        )


@command("run", "ris-front-unique")
class RunRISFrontUnique(RunRISFront):
    """``rothe run ris-front-unique``: a steep front of a strictly convex RIS (unique solution)."""

    help = (
        "A steep front crossing the unit square whose evolution is unique (strictly convex "
        "energy c/2 |grad z|^2 + a/2 z^2, a load growing from a corner): the benchmark of "
        "--adapt-space"
    )
    name = "ris-front-unique"
    default_control = "adaptive"
    default_tol = 1e-4  # the benchmark's (not ris-front's double-well lattice jumps)
    default_tols = RISRunBase.default_tols
    default_n = 16
    default_tau = 0.02
    default_z0 = 0.0
    default_amplitude = examples.FRONT_UNIQUE_DEFAULTS["amplitude"]
    #: default --space-tol: the estimate of the defaults' state is about 0.1 at h = 1/32 along
    #: the front (0.05 reaches the accuracy of a 64 x 64 grid in benchmarks/space_adaptivity_ris.py)
    default_space_tol = 0.05
    #: adapt every 4th step with a band of 0.08 around the refined cells: the front moves about
    #: 0.05 in 4 steps of tau = 0.02; measured to halve the seconds of adapting every step at
    #: the same error (docs/adaptivity.md)
    default_adapt_every = 4
    default_refine_band = 0.08
    amplitude_help = (
        "plateau A of the load density A/2 (1 + tanh((v t - |x|)/w)) (default 3: behind the "
        "front z = (A - kappa)/a = 0.2)"
    )
    defaults = examples.FRONT_UNIQUE_DEFAULTS
    #: its energy is quadratic and its reference (front_unique_state) uses the lumped a z^2/2
    quadratures = ("lumped",)
    coefficient_help = (
        "c of 1/2 int c |grad z|^2 (default 0.001; the front is smoothed over sqrt(c/a))"
    )

    def add_example_options(self, parser) -> None:
        """The options of ris-front and --reaction."""
        super().add_example_options(parser)
        float_option(
            parser,
            "--reaction",
            default=None,
            help="a of int a/2 z^2 (default 10; a > 0 makes the energy strictly convex, "
            "so the solution is unique)",
        )

    def validate(self, args):
        """--reaction > 0, then the checks of ris-front."""
        default = self.defaults["reaction"]
        self._reaction = check_positive(
            "--reaction", default if args.reaction is None else args.reaction
        )
        return super().validate(args)

    def make_problem(self, n, mesh, args, dirichlet):
        """The unique front (z = 0 on the right side unless --dirichlet says otherwise)."""
        return examples.example_front_unique(
            n,
            mesh,
            amplitude=args.amplitude,
            z0=args.z0,
            coefficient=self._coefficient,
            reaction=self._reaction,
            dirichlet=("right",) if dirichlet is None else dirichlet,
        )


# -- compare ris-2d (Fig. 5) --------------------------------------------------------------------


def compare_ris_2d_row(
    n: int, mesh, control: str, tol: float | None, tau: float, progress=False
) -> dict:
    """One run of ``compare ris-2d`` (a task: builds Example 7.2 itself); its table row.

    A uniform row also holds its ``equidistribution_bound`` (:func:`equidistribution_bound`).
    """
    problem = examples.example_7_2(n, mesh)
    try:
        traj = run_ris(
            problem, control_object(control, tol=tol, tau=tau), progress=progress
        ).trajectory
        failure = None
    except RunFailed as exc:  # keep the table: a failed run is a row with its status
        traj, failure = exc.trajectory, exc
    row = ris_summary(traj, "ris-2d", describe_branch(problem, traj))
    row.update(
        tau0=tau,
        status="completed" if failure is None else f"failed: {failure}",
        n_nodes=problem.n_nodes,
    )
    if control == "uniform":
        row["equidistribution_bound"] = equidistribution_bound(traj["I1"] + traj["I2"])
    if failure is not None:
        raise TaskFailed(str(failure), value=row)
    return row


def compare_ris_2d(
    n: int = 40,
    tols=(1e-4, 1e-5, 1e-6),
    taus=COMPARE_TAUS,
    tau0: float = 0.1,
    controls=COMPARE_CONTROLS,
    mesh=None,
    progress=False,
    executor=None,
) -> list[dict]:
    """The ``controls`` over ``tols`` and uniform over ``taus`` on Example 7.2; one row each
    (:func:`compare_ris_2d_row`).

    The runs are independent tasks of ``executor`` (:class:`rothe.parallel.Executor`; default:
    one after another in this process); a run that fails is a row with its status.
    """
    runs = [(c, tol, tau0) for c in controls for tol in tols] + [("uniform", None, t) for t in taus]
    # a run's own progress only in this process (a worker's stderr is not the user's)
    inner_progress = progress if executor is None or executor.in_process else False
    tasks = [
        Task(
            f"{c} tol={tol:g}" if tol is not None else f"{c} tau={tau:g}",
            compare_ris_2d_row,
            {
                "n": n,
                "mesh": mesh,
                "control": c,
                "tol": tol,
                "tau": tau,
                "progress": inner_progress,
            },
            cost=run_cost(tol, tau),
        )
        for c, tol, tau in runs
    ]
    return compare_rows_of(tasks, executor)


def format_table(rows) -> str:
    """The table of ``compare ris-2d``: one line per run, work ratios from :func:`compare_rows`."""
    ratios = compare_rows(rows)
    head = (
        f"{'control':<9} {'tol/tau':>8} {'accepted':>8} {'rejected':>8} {'solves':>7} "
        f"{'newton':>7} {'max_k(I1+I2)':>12} {'sum_k(I1+I2)':>12} {'energy':>10} "
        f"{'z_min':>8} {'z_max':>8} {'viscous jumps at t':<18} {'seconds':>8} "
        f"{'steps/u':>7} {'solves/u':>8} {'sec/u':>6}"
    )
    lines = [head, "-" * len(head)]

    def fmt(x, width):
        return f"{x:>{width}.3f}" if x is not None else f"{'-':>{width}}"

    for r, q in zip(rows, ratios, strict=True):
        par = r["tau0"] if r["control"] == "uniform" else r["tol"]
        if "accepted_steps" not in r:  # a run that produced nothing (error, lost): status only
            lines.append(f"{r['control']:<9} {par:>8.3g}  {r['status']}")
            continue
        jumps = format_jump_times(r["viscous_jumps"], shown=2, sep=",")
        line = (
            f"{r['control']:<9} {par:>8.3g} {r['accepted_steps']:>8d} "
            f"{r['rejected_steps']:>8d} {r['inner_solves']:>7d} {r['newton_iterations']:>7d} "
            f"{r['max_residual']:>12.3e} {r['sum_residual']:>12.3e} "
            f"{r['energy_final']:>10.4f} {r['z_min']:>8.4f} {r['z_max']:>8.4f} "
            f"{jumps:<18} {r['wall_time_s']:>8.2f} {fmt(q['ratio_steps'], 7)} "
            f"{fmt(q['ratio_solves'], 8)} {fmt(q['ratio_seconds'], 6)}"
        )
        if r["status"] != "completed":
            line += "  " + r["status"]
        lines.append(line)
    lines.append("")
    lines.append(
        "steps/u, solves/u, sec/u: accepted steps, inner solves and seconds of the run "
        "divided by the uniform scheme's at the same global residual sum_k(I1+I2), "
        "interpolated log-log between the two uniform runs that bracket it ('-': uniform, "
        "or outside their range)"
    )
    bound = finest_uniform_bound(rows)
    if bound is not None:
        lines.append(
            f"equidistribution bound (finest uniform run, tau = {bound[0]:.3g}): no step "
            f"sequence needs fewer than {bound[1]:.3f} of uniform's accepted steps (hence "
            "solves) at equal global residual while I ~ C(s) tau^2"
        )
    return "\n".join(lines)


@command("compare", "ris-2d")
class CompareRIS2D:
    """``rothe compare ris-2d``: Fig. 5 and compare.json."""

    help = (
        "Fig. 5 of Andreia & Meyer: local and global residual against steps, adaptive, order2 "
        "and regime vs uniform (Example 7.2); compare.json with the work ratios"
    )

    def configure(self, parser) -> None:
        """The grid, tolerances, uniform steps, controllers, outputs and the executor."""
        parser.add_argument(
            "--n", type=int, default=None, help="N x N grid (default 40: 1681 nodes)"
        )
        parser.add_argument("--mesh", default=None, help="2D mesh file instead of the grid")
        parser.add_argument(
            "--tols",
            type=parse_float_list("--tols"),
            default=[1e-4, 1e-5, 1e-6],
            help="tolerances of the step controllers (default 1e-4,1e-5,1e-6)",
        )
        parser.add_argument(
            "--taus",
            type=parse_float_list("--taus"),
            default=list(COMPARE_TAUS),
            help="steps of the uniform scheme (default 0.01/2^k, k = 0..8)",
        )
        parser.add_argument(
            "--controls",
            default=",".join(COMPARE_CONTROLS),
            help="step controllers besides uniform, from adaptive, order2, regime "
            "(default all three)",
        )
        float_option(
            parser,
            "--tau",
            default=0.1,
            help="first step of the step controllers (default 0.1)",
        )
        add_output_options(parser, "compare-ris-2d")
        add_parallel_options(parser)

    def execute(self, args) -> int:
        """Run every comparison; write the table, summary, compare.json and Fig. 5."""
        tols = [check_positive("--tols", x) for x in args.tols]
        taus = [check_step("--taus", x, 1.0) for x in args.taus]
        tau0 = check_step("--tau", args.tau, 1.0)
        if len(taus) < 2:
            raise fail("--taus", ",".join(map(str, taus)), "needs at least two step sizes")
        controls = [c.strip() for c in args.controls.split(",") if c.strip()]
        if not controls:  # it ran uniform alone: no comparison, and exit status 0
            raise fail(
                "--controls",
                args.controls,
                f"must name at least one of {', '.join(COMPARE_CONTROLS)} (uniform always runs)",
            )
        for c in controls:
            check_choice("--controls", c, COMPARE_CONTROLS)
        if args.mesh is not None and args.n is not None:
            raise fail("--n", args.n, "cannot be combined with --mesh")
        n = check_int("--n", args.n if args.n is not None else 40, minimum=2)
        if args.mesh is None:
            check_memory("--n", n, grid_nodes(n, 2), RIS_BYTES_PER_NODE[2], what="nodes")
        mesh = load_mesh(args.mesh, dim=2, name="--mesh") if args.mesh is not None else None
        executor = executor_from_args(args, "rothe compare ris-2d")
        out = output_dir(args, "compare-ris-2d")
        t0 = time.perf_counter()
        rows = compare_ris_2d(
            n,
            tols,
            taus,
            tau0,
            tuple(controls),
            mesh,
            progress=progress_of(args),
            executor=executor,
        )
        table = format_table(rows)
        write_table(out, table + "\n")
        n_nodes = next((r["n_nodes"] for r in rows if "n_nodes" in r), None)
        summary = {
            "example": "ris-2d",
            "n_nodes": n_nodes,
            "rows": rows,
            "wall_time_s": time.perf_counter() - t0,
            "peak_memory_mb": peak_memory_mb(),
        }
        write_summary(out, summary)
        bound = finest_uniform_bound(rows)
        atomic_write_text(
            out / "compare.json",
            json.dumps(
                _jsonable(
                    {
                        "example": "ris-2d",
                        "n_nodes": n_nodes,
                        "rows": compare_rows(rows),
                        "equidistribution_bound": None
                        if bound is None
                        else {"tau": bound[0], "ratio_steps": bound[1]},
                    }
                ),
                indent=2,
            )
            + "\n",
        )
        if not args.no_plots:
            # matplotlib only when figures are drawn (start-up time of the command line)
            from ..ris.figures import plot_residual_vs_steps

            plot_residual_vs_steps(
                [r for r in rows if r["status"] == "completed"],
                out / "fig5_residuals.png",
                title=f"Example 7.2 ({n_nodes} nodes): residuals against steps",
            )
        if not args.quiet:
            print(table)
            print(f"wrote {out}/")
        return 0 if all(r["status"] == "completed" for r in rows) else 1


__all__ = [
    "RunRIS2D",
    "RunRIS3D",
    "RunRISFront",
    "CompareRIS2D",
    "compare_ris_2d",
    "format_table",
    "linear_solver_used",
]
