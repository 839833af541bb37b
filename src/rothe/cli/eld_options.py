"""The options of the ELD commands, their checks, and the one place where names become objects.

``rothe run eld-*`` and ``rothe study eld-*`` take the scheme, the form, the step control, the
data and the lifting by name (``--scheme euler|bdf2``, ``--form regularized|original``,
``--control uniform|adaptive`` with ``--tau``, ``--tol``, ``--steps``, ``--data
points|means|differenced``, ``--lifting nodal|harmonic``); :func:`run_objects` turns them into
the objects :func:`rothe.eld.run_eld` takes (:mod:`rothe.eld.scheme`, :mod:`rothe.eld.form`,
:mod:`rothe.stepping.controllers`, :mod:`rothe.eld.data`), and :func:`space_adaptivity` the
``--adapt-space`` options into a :class:`~rothe.fem.adapt.SpaceAdaptivity`. Every help text
states the default the parser really uses.

Bad input is one line naming the option, checked before anything runs (the checks that need no
mesh are the commands' ``validate``, also run by ``rothe sweep``).
"""

from __future__ import annotations

from ..eld.constraint import LIFTINGS
from ..eld.damping import DAMPINGS, make_damping
from ..eld.data import DATA_MODES, DEFAULT_DATA
from ..eld.form import DEFAULT_FORM, Original, Regularized
from ..eld.materials import (
    ELASTIC_PAIRS,
    PLANES,
    PiecewiseMaterial,
    material_from,
    materials_from,
)
from ..eld.scheme import BDF2, DEFAULT_SCHEME, ImplicitEuler
from ..eld.studies import check_halvings, check_uniform_runs
from ..errors import check_choice, check_positive, described, fail
from ..fem.mesh import DUPLICATE_NODES, load_mesh, mesh_dim
from ..stepping.controllers import Adaptive, Given, Uniform
from .adapt_options import check_memory
from .common import float_option, given

#: the schemes and forms by their names on the command line
SCHEMES = {"euler": ImplicitEuler, "bdf2": BDF2}
FORMS = {"regularized": Regularized, "original": Original}
CONTROLS = ("uniform", "adaptive")
#: the library's defaults (those of rothe.eld.run_eld), by name: the help texts state them
SCHEME_DEFAULT = DEFAULT_SCHEME.name
FORM_DEFAULT = DEFAULT_FORM.name
LIFTING_DEFAULT = DEFAULT_FORM.lifting
DATA_DEFAULT = DEFAULT_DATA.name

#: default --max-dofs of eld-mms (2D) and eld-beam (3D): a --space-tol below what the time
#: step's error allows (the indicator sees the step's residual, time error included) refines
#: without end, until memory runs out; twice the initial mesh's dofs when that is more
ELD_MAX_DOFS = {"2d": 200_000, "3d": 300_000}
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
#: the most unknowns of a tip-mass body for the dense modal analysis behind its reference
#: frequencies (the built-in strip's cap in 2D P2): eld-tip-mass --mesh, study eld-tip-mass
TIP_MASS_MAX_DOFS = 16_000


# -- options ----------------------------------------------------------------------------------


def step_options(parser, tau_default: float, scheme_default: str = SCHEME_DEFAULT) -> None:
    """--form, --scheme, --tau and --control/--tol: every eld run command steps the same way."""
    form_option(parser)
    scheme_option(parser, scheme_default)
    float_option(
        parser,
        "--tau",
        default=tau_default,
        help=f"time step; must divide T (default {tau_default:g}); the first "
        "step with --control adaptive",
    )
    control_options(parser)


def form_option(parser, default: str = FORM_DEFAULT) -> None:
    """--form (its default stated in the help)."""
    parser.add_argument(
        "--form",
        default=default,
        help=f"{' | '.join(FORMS)}: the index-1 form (2.8) or the index-3 form "
        f"(2.7) (default {default})",
    )


def scheme_option(parser, default: str = SCHEME_DEFAULT) -> None:
    """--scheme (its default stated in the help)."""
    parser.add_argument(
        "--scheme",
        default=default,
        help="euler | bdf2: implicit Euler (3.4), the paper's scheme, or "
        f"variable-step BDF2 (second order) (default {default})",
    )


def control_options(parser) -> None:
    """--control and --tol."""
    parser.add_argument(
        "--control",
        default=CONTROLS[0],
        help="uniform | adaptive: equal steps tau (must divide T), or steps chosen "
        "by the local error estimate (then --tau is the first step) "
        f"(default {CONTROLS[0]})",
    )
    float_option(
        parser,
        "--tol",
        default=None,
        help="tolerance of --control adaptive: the local error of each step (what one step "
        "adds) in the energy norm, relative to the run's energy-norm scale (with controllers: "
        "also their states z, relative to the largest z so far); not a bound on "
        "the error at T, which is the steps' errors added up (docs/eld.md, Step control)",
    )


def data_options(parser) -> None:
    """--data and --lifting (the regularized form's right inverse of B)."""
    parser.add_argument(
        "--data",
        default=DATA_DEFAULT,
        help=f"{' | '.join(DATA_MODES)}: how F, G, G', G'' enter (3.3)/(3.1) "
        f"(default {DATA_DEFAULT})",
    )
    lifting_option(parser)


def lifting_option(parser) -> None:
    """--lifting (its default stated in the help)."""
    parser.add_argument(
        "--lifting",
        default=LIFTING_DEFAULT,
        help=f"right inverse of B for the regularized form: {' | '.join(LIFTINGS)} "
        f"(default {LIFTING_DEFAULT})",
    )


def keep_option(parser, default: int) -> None:
    """--keep-every with the command's default."""
    parser.add_argument(
        "--keep-every",
        type=int,
        default=default,
        help=f"keep u, v, a, lambda of every k-th step in trajectory.npz and the "
        f"XDMF files (default {default}; t = 0 and the last step always)",
    )


def damping_options(parser, default: str = "nonlinear", default_b: float = 0.01) -> None:
    """--damping (with the command's default) and its parameters."""
    parser.add_argument(
        "--damping",
        default=default,
        help="nonlinear | rayleigh | none (nonlinear: D v = b K v - d0 M v + "
        f"d_nl v/sqrt(1+|v|^2/v_ref^2)) (default {default})",
    )
    float_option(parser, "--rho", default=1.0, help="density (default 1)")
    float_option(
        parser,
        "--d0",
        default=0.5,
        help="L2 anti-damping constant d0 of the nonlinear damping (default 0.5)",
    )
    float_option(
        parser,
        "--d-nl",
        default=1.0,
        help="coefficient d_nl of the saturating part (default 1)",
    )
    float_option(
        parser,
        "--v-ref",
        default=1.0,
        help="saturation velocity v_ref (default 1)",
    )
    float_option(
        parser,
        "--b",
        default=default_b,
        help=f"stiffness-proportional coefficient b (default {default_b:g})",
    )
    float_option(
        parser,
        "--a",
        default=0.0,
        help="mass-proportional coefficient a of Rayleigh damping (default 0)",
    )


def mms_options(parser, n: int = 8, plane: bool = True) -> None:
    """The manufactured problem's mesh, material (``--plane`` unless ``plane`` is False), data
    and damping."""
    parser.add_argument(
        "--n", type=int, default=n, help=f"cells per side of the unit square (default {n})"
    )
    parser.add_argument("--degree", type=int, default=2, help="1 or 2 (default 2: exact in space)")
    material_options(parser, MMS_MATERIAL, plane="strain" if plane else None)
    float_option(parser, "--T", default=1.0, help="end time (default 1)")
    data_options(parser)
    damping_options(parser)


#: the manufactured solution's material (rothe.eld.examples.mms_problem), the pulse's
MMS_MATERIAL = {"lam": 2.0, "mu": 1.0}


def material_options(
    parser, default: dict, *, rho: float | None = None, plane: str | None = None
) -> None:
    """``--E``/``--nu`` or ``--lam``/``--mu`` (one pair; ``default`` where none is given:
    :func:`rothe.eld.materials.material_from`), ``--rho`` when ``rho`` is its default (the
    commands with a damping get it from :func:`damping_options`) and ``--plane`` on the 2D
    commands (``plane``: the default model)."""
    pair = ELASTIC_PAIRS[0] if "E" in default else ELASTIC_PAIRS[1]
    other = ELASTIC_PAIRS[1] if pair == ELASTIC_PAIRS[0] else ELASTIC_PAIRS[0]
    names = {"E": "Young's modulus E", "nu": "Poisson ratio", "lam": "Lamé lambda", "mu": "Lamé mu"}
    for key in pair:
        mate = "--" + [k for k in pair if k != key][0]
        float_option(
            parser,
            "--" + key,
            default=None,
            help=f"{names[key]} (default {default[key]:g}); with {mate}, or give "
            f"--{other[0]} and --{other[1]} instead (not both pairs)",
        )
    described_default = ", ".join(f"{k} = {default[k]:g}" for k in pair)
    for key in other:
        float_option(
            parser,
            "--" + key,
            default=None,
            help=f"{names[key]}: the other way to give the material, with "
            f"--{[k for k in other if k != key][0]} (default: that of {described_default}; "
            f"not with --{pair[0]}/--{pair[1]})",
        )
    if rho is not None:
        float_option(parser, "--rho", default=rho, help=f"density (default {rho:g})")
    if plane is not None:
        parser.add_argument(
            "--plane",
            default=plane,
            help=f"{' | '.join(PLANES)}: the 2D model, plane strain (eps_zz = 0) or plane "
            f"stress (sigma_zz = 0) (default {plane})",
        )


# -- names -> objects -----------------------------------------------------------------------------


def scheme_of(args):
    """The scheme object of --scheme."""
    return SCHEMES[check_choice("--scheme", args.scheme, tuple(SCHEMES))]()


def form_of(args):
    """The form object of --form (and --lifting, checked whatever the form; given with --form
    original, which has no lifting, it is refused as an option the run does not read)."""
    name = check_choice("--form", args.form, tuple(FORMS))
    lifting = check_choice("lifting", getattr(args, "lifting", LIFTING_DEFAULT), LIFTINGS)
    if name == "original" and given(args, "--lifting"):
        raise fail(
            "--lifting",
            lifting,
            "is used by --form regularized only (the original form (2.7) has no lifting)",
        )
    return Regularized(lifting) if name == "regularized" else Original()


def control_of(args):
    """The step-control object of --control, --tau, --tol and --steps (one-line errors naming
    the options)."""
    control = check_choice("--control", args.control, CONTROLS)
    tau = check_positive("--tau", args.tau)
    tol = args.tol
    steps = getattr(args, "steps", None)
    if control == "adaptive":
        if tol is None:
            raise fail("--tol", None, "must be given (> 0) with --control adaptive")
        tol = check_positive("--tol", tol)
        if steps is not None:
            raise fail(
                "--steps",
                described("a step sequence"),
                "is a fixed grid: not with --control adaptive",
            )
        return Adaptive(tol, tau=tau)
    if tol is not None:
        raise fail("--tol", tol, "is used by --control adaptive only (this run has uniform steps)")
    return Given(steps) if steps is not None else Uniform(tau)


def material_of(args, default: dict, dim: int = 2):
    """The :class:`~rothe.eld.materials.Material` of ``--E``/``--nu`` or ``--lam``/``--mu``,
    ``--rho`` and ``--plane`` (where the command has it; plane strain in 3D unless given):
    :func:`rothe.eld.materials.material_from`, whose refusals name the API parameters the
    command line renames to the options."""
    plane = getattr(args, "plane", None) or "strain"
    if dim == 3 and not given(args, "--plane"):
        plane = "strain"
    return material_from(
        rho=args.rho,
        E=getattr(args, "E", None),
        nu=getattr(args, "nu", None),
        lam=getattr(args, "lam", None),
        mu=getattr(args, "mu", None),
        dim=dim,
        plane=plane,
        default=default,
    )


def material_fields(args, default: dict, material) -> dict:
    """The material of a run for its summary: the pair it was built from as given (or the
    default), the other pair derived, rho and the model."""
    used = [k for k in ("E", "nu", "lam", "mu") if getattr(args, k, None) is not None]
    pair = (
        ELASTIC_PAIRS[0]
        if any(k in ELASTIC_PAIRS[0] for k in used) or (not used and "E" in default)
        else ELASTIC_PAIRS[1]
    )
    E, nu = material.young
    out = {"E": E, "nu": nu, "lam": material.lam, "mu": material.mu}
    for key in pair:
        value = getattr(args, key, None)
        out[key] = float(value if value is not None else default.get(key, out[key]))
    out.update(rho=material.rho, plane=material.plane)
    return out


def summary_material(args, default: dict, material) -> dict:
    """The material of a run for its summary, chosen in one place for every ``run eld-*``
    command: several materials (``--material``, eld-two-bodies' ``--material1``) give the
    materials, their regions and the reference density (``PiecewiseMaterial.describe``), one
    material :func:`material_fields` of ``--E/--nu`` or ``--lam/--mu`` (``default`` where none
    is given)."""
    if isinstance(material, PiecewiseMaterial):
        return material.describe()
    return material_fields(args, default, material)


#: API parameters of the --mesh commands whose names are not their options
MESH_PARAMETERS = {"materials": "--material", "regions": "--region", "adapt": "--adapt-space"}


def mesh_options(parser, *, dirichlet: str | None, dirichlet_help: str = "") -> None:
    """``--mesh FILE`` (anything meshio reads; parts and regions by gmsh physical-group
    name), ``--duplicate-nodes``, ``--dirichlet PART[,PART]`` (default ``dirichlet``; none
    with ``dirichlet=None``: a body held by its couplings only), ``--material
    NAME:KEY=VALUE,...`` and ``--region NAME=GROUP[,GROUP]`` (both repeatable)."""
    parser.add_argument(
        "--mesh",
        default=None,
        metavar="FILE",
        help="mesh file instead of the built-in grid: anything meshio reads (gmsh .msh 2.2/4.x, "
        ".vtu, .xdmf, ...), triangles (2D) or tetrahedra (3D); boundary parts and material "
        "regions are its physical groups (cell sets) by name",
    )
    parser.add_argument(
        "--duplicate-nodes",
        default="error",
        help="coincident nodes of a --mesh file used by different cells (a cut, like a crack): "
        "error (default) | merge (glue them) | keep (the cut is intended)",
    )
    if dirichlet is not None:
        parser.add_argument(
            "--dirichlet",
            default=dirichlet,
            metavar="PART[,PART]",
            help=f"{dirichlet_help} (default {dirichlet})",
        )
    parser.add_argument(
        "--material",
        action="append",
        default=None,
        metavar="NAME:KEY=VALUE,...",
        help="with --mesh: a material by name, e.g. steel:E=210e9,nu=0.3,rho=7800 (keys E, nu "
        "or lam, mu, and rho; rho defaults to --rho); repeat it for several materials; without "
        "--region a material fills the physical group of its NAME; instead of --E/--nu/--lam/--mu",
    )
    parser.add_argument(
        "--region",
        action="append",
        default=None,
        metavar="NAME=GROUP[,GROUP]",
        help="with --material: the physical groups (cell regions) of the mesh that material "
        "NAME fills, e.g. steel=Volume1,Volume3; repeatable; every cell must get one material",
    )


def part_option(parser, option: str, default: str, what: str) -> None:
    """A boundary part by name (``--tip``, ``--base``, ...): a part of the built-in grid or a
    physical group of the ``--mesh`` file."""
    parser.add_argument(
        option,
        default=default,
        metavar="PART",
        help=f"{what}: a boundary part (a physical group with --mesh) (default {default})",
    )


def _split_list(text: str) -> list[str]:
    return [x.strip() for x in str(text).split(",") if x.strip()]


def parts_of(args) -> tuple:
    """The parts of ``--dirichlet`` (at least one)."""
    parts = tuple(_split_list(args.dirichlet))
    if not parts:
        raise fail("--dirichlet", args.dirichlet, "must name at least one boundary part")
    return parts


def material_constants(args) -> dict:
    """name -> {key: value} of the ``--material`` options (the syntax; the values are checked
    by :func:`rothe.eld.materials.materials_from`)."""
    out: dict = {}
    for spec in args.material or ():
        name, sep, rest = str(spec).partition(":")
        name = name.strip()
        pairs = [x.partition("=") for x in _split_list(rest)]
        if not (name and sep and pairs and all(eq and k.strip() for k, eq, _ in pairs)):
            raise fail("--material", spec, "must be NAME:KEY=VALUE,... (keys E, nu, lam, mu, rho)")
        if name in out:
            raise fail("--material", spec, f"names {name!r} a second time")
        values = {}
        for key, _, value in pairs:
            try:
                values[key.strip()] = float(value)
            except ValueError:
                raise fail(
                    "--material", spec, f"must give numbers ({key.strip()}={value!r})"
                ) from None
        out[name] = values
    return out


def region_map(args) -> dict | None:
    """group -> material name of the ``--region`` options (None without any)."""
    if not args.region:
        return None
    out: dict = {}
    for spec in args.region:
        name, sep, rest = str(spec).partition("=")
        groups = _split_list(rest)
        if not (name.strip() and sep and groups):
            raise fail("--region", spec, "must be NAME=GROUP[,GROUP] (a --material NAME)")
        for group in groups:
            if group in out and out[group] != name.strip():
                raise fail(
                    "--region", spec, f"puts {group!r} in a second material ({out[group]!r})"
                )
            out[group] = name.strip()
    return out


def check_mesh_options(args, grid_options: tuple[str, ...]) -> None:
    """The --mesh options that need no mesh: --duplicate-nodes, the built-in grid's options
    not with --mesh, --material/--region with --mesh only and not with the constants of one
    material, and their syntax."""
    check_choice("--duplicate-nodes", args.duplicate_nodes, DUPLICATE_NODES)
    if args.mesh is None:
        for option in ("--duplicate-nodes", "--material", "--region"):
            if given(args, option):
                raise fail(option, _value(args, option), "is used with --mesh only")
    else:
        for option in grid_options:
            if given(args, option):
                raise fail(
                    option,
                    _value(args, option),
                    "cannot be combined with --mesh (the mesh fixes the body)",
                )
    if args.region and not args.material:
        raise fail("--region", args.region[0], "needs --material (the materials it places)")
    if args.material:
        for option in ("--E", "--nu", "--lam", "--mu"):
            if given(args, option):
                raise fail(
                    option,
                    _value(args, option),
                    "must not be combined with --material (give the constants in each --material)",
                )
        material_constants(args)
        region_map(args)


def _value(args, option: str):
    value = getattr(args, option.lstrip("-").replace("-", "_"), None)
    return value[0] if isinstance(value, list) else value


def body_mesh(args):
    """The ``--mesh`` file as a mesh (None without it); refusals name ``--mesh``."""
    if args.mesh is None:
        return None
    return load_mesh(args.mesh, name="mesh", duplicate_nodes=args.duplicate_nodes)


def body_material(args, default: dict, mesh=None):
    """The material of a body: the ``--material``/``--region`` materials (a
    :class:`~rothe.eld.materials.PiecewiseMaterial`), or one :func:`material_of` in the
    mesh's dimension."""
    dim = 2 if mesh is None else mesh_dim(mesh)
    if args.material:
        plane = getattr(args, "plane", None) or "strain"
        if dim == 3 and not given(args, "--plane"):
            plane = "strain"
        return materials_from(
            material_constants(args), regions=region_map(args), dim=dim, plane=plane, rho=args.rho
        )
    return material_of(args, default, dim=dim)


def mesh_fields(args, mesh) -> dict:
    """The mesh of a --mesh run for its summary: file, nodes, cells, dimension."""
    return {
        "mesh": str(args.mesh),
        "mesh_nodes": int(mesh.p.shape[1]),
        "mesh_cells": int(mesh.t.shape[1]),
        "dim": mesh_dim(mesh),
    }


def data_of(args):
    """The data-mode object of --data (points where the command has no --data)."""
    return DATA_MODES[
        check_choice("data", getattr(args, "data", DATA_DEFAULT), tuple(DATA_MODES))
    ]()


def run_objects(args) -> dict:
    """``scheme``, ``form``, ``control`` and ``data`` for :func:`rothe.eld.run_eld`, from the
    command line (the one place where the ELD commands map names to objects)."""
    scheme = scheme_of(args)
    control = control_of(args)
    return {"scheme": scheme, "form": form_of(args), "control": control, "data": data_of(args)}


def check_space_data(args, space) -> None:
    """--adapt-space needs --data points."""
    if space is not None and args.data != "points":
        raise fail(
            "--data",
            args.data,
            "must be points with --adapt-space (the data of t_j is "
            "re-evaluated on the new Dirichlet nodes)",
        )


# -- checks -------------------------------------------------------------------------------------


def check_damping_options(args) -> None:
    """--damping is a known damping, and no damping parameter it ignores was given."""
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


def damping_of(args):
    """The damping object of --damping and its parameters."""
    kind = check_choice("--damping", args.damping, DAMPINGS)
    return make_damping(kind, a=args.a, b=args.b, d0=args.d0, d_nl=args.d_nl, v_ref=args.v_ref)


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
    """The study options that rothe.eld.studies also checks, named as on the command line (the
    perturbation studies check --targets, --seed, --delta themselves, against their own
    targets: StudyEldPerturbation.execute)."""
    if hasattr(args, "halvings"):
        check_halvings("--halvings", args.halvings, args.tau0, args.T)


def check_convergence_runs(args, scheme, data) -> None:
    """What every run of ``rothe study eld-convergence`` would refuse, checked once before its
    cluster starts or --out is made (:func:`rothe.eld.studies.check_uniform_runs`: the
    manufactured problem, the data mode with the scheme, the largest step; each run failed on
    its own after the cluster had started). The parameters it names are the command's options
    by the option table (``tau0`` is ``--tau0``)."""
    material = material_of(args, MMS_MATERIAL)
    check_uniform_runs(
        args.tau0,
        scheme,
        data,
        args.n,
        args.degree,
        damping=damping_of(args),
        rho=args.rho,
        lam=material.lam,
        mu=material.mu,
        T=args.T,
    )


def check_mms_size(n: int, degree: int) -> None:
    """Refuse an --n whose 2D problem cannot fit in memory."""
    if degree in (1, 2):
        dofs = 2 * (degree * n + 1) ** 2
        check_memory("--n", n, dofs, ELD_BYTES_PER_DOF["2d"], what="unknowns")


def beam_unknowns(n: int, length: float, degree: int) -> int:
    """The dofs of the beam of ``rothe run eld-beam`` (round(length n) x n x n cubes, P1/P2)."""
    nx = max(1, round(length * n))
    return 3 * (degree * nx + 1) * (degree * n + 1) ** 2


def check_beam_size(n: int, length: float, degree: int, solver: str) -> None:
    """Refuse an --n whose beam (with its solver) cannot fit in memory."""
    if degree in (1, 2) and length > 0:
        dofs = beam_unknowns(n, length, degree)
        lu = solver == "direct" or (solver == "auto" and dofs <= BEAM_LU_LIMIT)
        check_memory(
            "--n", n, dofs, ELD_BYTES_PER_DOF["3d-lu" if lu else "3d-amg"], what="unknowns"
        )
