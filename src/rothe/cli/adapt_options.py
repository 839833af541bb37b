"""The command line's space-adaptivity options, one builder for every ``run`` command.

``--adapt-space`` (off by default, or on with ``--no-adapt-space`` where a command adapts by
default) and its options ``--space-tol``, ``--refine-fraction``, ``--coarsen-fraction``,
``--max-dofs``, ``--adapt-every`` become one :class:`rothe.fem.adapt.SpaceAdaptivity`; an option
given without adaptation is refused in one line. The convention of ``--max-dofs`` is the same for
every command: the **degrees of freedom of the finite-element space** of the unknown field after
an adaptation (RIS's P1 scalar field: its nodes; ELD's P_k vector field: components x nodes of
degree k; the multiplier is not counted). Its default is the command's cap, or twice the initial
mesh's dofs when that is more (:func:`fit_default_cap`).

A family whose adapt cycle has hysteresis (RIS: ``hysteresis=`` its defaults) also gets
``--refine-band``, ``--coarsen-delay``, ``--max-recoarsen``, ``--coarsen-batch``
(:mod:`rothe.fem.adapt.hysteresis`, :mod:`rothe.fem.adapt.marking`); the others' options and
help stay without them.
"""

from __future__ import annotations

import argparse
import os

from ..errors import check_choice, fail
from ..fem.adapt import SpaceAdaptivity
from ..fem.adapt.marking import NORMS
from .common import float_option, parse_int

#: the options of space adaptivity (refused without --adapt-space)
SPACE_OPTIONS = (
    "--space-tol",
    "--refine-fraction",
    "--coarsen-fraction",
    "--max-dofs",
    "--adapt-every",
)
#: the hysteresis options of a family that has them (``hysteresis=``; unset: its defaults)
HYSTERESIS_OPTIONS = ("--refine-band", "--coarsen-delay", "--max-recoarsen", "--coarsen-batch")
#: defaults of the marking options (those of SpaceAdaptivity: the help texts state them)
MARKING_DEFAULTS = {
    "refine_fraction": SpaceAdaptivity.refine_fraction,
    "coarsen_fraction": SpaceAdaptivity.coarsen_fraction,
    "adapt_every": SpaceAdaptivity.adapt_every,
}


def _number(n: int | None) -> str:
    return "none" if n is None else f"{n:,}".replace(",", " ")


def add_space_options(
    parser,
    *,
    on: bool = False,
    default_tol: float | None = None,
    default_max_dofs: int | None = None,
    indicator: str = "the step's residual indicator",
    hysteresis: dict | None = None,
    default_adapt_every: int | None = None,
    norms: bool = False,
) -> None:
    """--adapt-space (``on``: adapting by default, --no-adapt-space keeps the mesh) and its
    options, read by :func:`space_adaptivity`; help texts state the defaults the run uses.
    ``hysteresis``: the family's defaults of the hysteresis options (``coarsen_delay``,
    ``max_recoarsen``, ``refine_band``, ``coarsen_batch``; missing ones: off), which adds
    those options; None: a family without them (a default given as a string is the help
    text of a default the family computes, e.g. ELD's band). ``default_adapt_every``: the
    command's default of --adapt-every (None: SpaceAdaptivity's). ``norms``: the family's
    indicator can estimate the L2 norm too (adds --space-norm)."""
    parser.add_argument(
        "--adapt-space",
        action=argparse.BooleanOptionalAction if on else "store_true",
        default=on,
        help="adapt the mesh (refine and coarsen by bisection) after every --adapt-every-th "
        f"accepted step, by {indicator}"
        + ("; on by default, --no-adapt-space keeps the mesh" if on else ""),
    )
    float_option(
        parser,
        "--space-tol",
        default=None,
        help="tolerance of the estimate eta of a step (refine while above; "
        + ("required with --adapt-space)" if default_tol is None else f"default {default_tol:g})"),
    )
    float_option(
        parser,
        "--refine-fraction",
        default=None,
        help="Doerfler bulk fraction of eta^2 to refine, in (0, 1) "
        f"(default {MARKING_DEFAULTS['refine_fraction']:g})",
    )
    float_option(
        parser,
        "--coarsen-fraction",
        default=None,
        help="share of max(eta, space-tol)^2 the coarsened cells may carry, in (0, 1) "
        f"(default {MARKING_DEFAULTS['coarsen_fraction']:g})",
    )
    parser.add_argument(
        "--max-dofs",
        type=parse_int("--max-dofs", 1),
        default=None,
        help="cap on the degrees of freedom of the finite-element space after an adaptation "
        f"(default {_number(default_max_dofs)}"
        + (
            ")"
            if default_max_dofs is None
            else ", or twice the initial mesh's dofs when that is more: the indicator of a "
            "non-smooth state may never fall below --space-tol, and without a cap the mesh "
            "grows until memory runs out)"
        ),
    )
    parser.add_argument(
        "--adapt-every",
        # 'auto' is refused by the parser: no family has a cost model to choose k from
        type=parse_int("--adapt-every", 1),
        default=None,
        help="adapt after every k-th accepted step, an integer >= 1 (default "
        f"{default_adapt_every or MARKING_DEFAULTS['adapt_every']})",
    )
    if norms:
        parser.add_argument(
            "--space-norm",
            default=None,
            help="the norm the indicator estimates: energy (the step's energy norm) or l2 (the "
            "L2 norm of u: eta_K h_K/h_0, for runs judged by the error in u) (default energy)",
        )
    if hysteresis is None:
        return
    delay, recoarsen = hysteresis.get("coarsen_delay", 0), hysteresis.get("max_recoarsen")
    band = hysteresis.get("refine_band", 0)
    float_option(
        parser,
        "--refine-band",
        default=None,
        help="refine a band of this width around the refined cells with them, a length >= 0 "
        f"(default {band if isinstance(band, str) else format(band, 'g')})",
    )
    parser.add_argument(
        "--coarsen-delay",
        type=parse_int("--coarsen-delay", 0),
        default=None,
        help=f"cells refined in the last k adaptations do not coarsen (default {delay})",
    )
    parser.add_argument(
        "--max-recoarsen",
        type=parse_int("--max-recoarsen", 0),
        default=None,
        help="a cell is refined and coarsened again at most k times "
        f"(default {_number(recoarsen)})",
    )
    float_option(
        parser,
        "--coarsen-batch",
        default=None,
        help="an adaptation that only coarsens needs this share of the cells marked "
        f"(default {hysteresis.get('coarsen_batch', 0):g})",
    )


def space_adaptivity(
    args,
    *,
    default_tol: float | None = None,
    default_max_dofs: int | None = None,
    hysteresis: bool = False,
    default_adapt_every: int | None = None,
) -> SpaceAdaptivity | None:
    """The SpaceAdaptivity of the --adapt-space options, or None without --adapt-space (an
    option given then is refused in one line). Bad values are refused by SpaceAdaptivity itself
    and renamed to their option by the command line. ``hysteresis``: the parser has the
    hysteresis options (:func:`add_space_options`); unset ones stay None (the family's
    defaults). ``default_adapt_every``: the command's default of --adapt-every."""
    options = SPACE_OPTIONS + (HYSTERESIS_OPTIONS if hysteresis else ())
    if hasattr(args, "space_norm"):
        options += ("--space-norm",)
    values = {o: getattr(args, o.lstrip("-").replace("-", "_")) for o in options}
    if not args.adapt_space:
        for option, value in values.items():
            if value is not None:
                raise fail(option, value, "is used by --adapt-space only (this run keeps its mesh)")
        return None
    tol = values["--space-tol"] if values["--space-tol"] is not None else default_tol
    if tol is None:
        raise fail("--space-tol", None, "must be given (> 0) with --adapt-space")
    kw = {
        key: values["--" + key.replace("_", "-")]
        for key in MARKING_DEFAULTS
        if values["--" + key.replace("_", "-")] is not None
    }
    if default_adapt_every is not None and values["--adapt-every"] is None:
        kw["adapt_every"] = default_adapt_every
    if hysteresis:
        kw.update({o.lstrip("-").replace("-", "_"): values[o] for o in HYSTERESIS_OPTIONS})
    if values.get("--space-norm") is not None:
        kw["norm"] = check_choice("--space-norm", values["--space-norm"], NORMS)
    max_dofs = values["--max-dofs"] if values["--max-dofs"] is not None else default_max_dofs
    return SpaceAdaptivity(space_tol=tol, max_dofs=max_dofs, **kw)


def fit_default_cap(args, adapt: SpaceAdaptivity | None, initial: int) -> None:
    """--adapt-space without --max-dofs: the command's default cap, or twice the initial mesh's
    dofs when that is more. A --max-dofs the user gave is checked against the initial mesh
    (:meth:`SpaceAdaptivity.check_mesh`) where the run starts instead."""
    if adapt is not None and args.max_dofs is None and adapt.max_dofs is not None:
        adapt.max_dofs = max(adapt.max_dofs, 2 * int(initial))


# -- memory -------------------------------------------------------------------------------------


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation: MemAvailable of /proc/meminfo (Linux),
    else physical memory by os.sysconf; None if neither is known."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return None


def _bytes(x: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if x < 1000 or unit == "PB":
            return f"{x:.3g} {unit}"
        x /= 1000
    return f"{x:.3g} PB"  # pragma: no cover


def check_memory(option: str, value, count: int, bytes_each: float, what: str = "dofs") -> None:
    """Refuse, before allocating, a size whose estimated peak (``count`` x ``bytes_each``)
    exceeds the available memory; one line naming ``option`` and ``value``."""
    need = float(count) * bytes_each
    have = available_memory()
    if have is not None and need > have:
        raise fail(
            option,
            value,
            f"needs about {_bytes(need)} ({count:.3g} {what}, estimated), "
            f"more than the {_bytes(have)} of memory available",
        )
