"""The one adapt cycle of both families: estimate -> mark -> refine/coarsen -> rebuild -> transfer.

A Rothe step is a stationary problem on whatever mesh it uses; what connects two steps is the
transfer of the history. After an accepted step (and, for the in-step rounds of elastodynamics,
after a step whose own estimate is too large) the family's stepper calls
:meth:`MeshAdaptation.cycle` with a *family* object that knows the problem and the state:

1. **estimate**: ``family.indicators(problem, target) -> eta`` (one value >= 0 per cell of the
   current mesh; the residual indicators of :mod:`rothe.ris.indicator` or
   :mod:`rothe.eld.indicator`);
2. **mark**: :meth:`SpaceAdaptivity.mark` (Doerfler refinement while eta > space_tol, coarsening
   of the cells carrying a coarsen_fraction share), or refinement only (``refine_only``); with
   the hysteresis (:mod:`.hysteresis`), the refinement band, the coarsening batch
   (:mod:`.marking`) and, if the family has it, ``family.keep_cells(problem, target, amesh)``
   (a mask of cells that must not coarsen);
3. **refine/coarsen**: :meth:`AdaptiveMesh.adapt` under the dof cap; nothing changed -> the cycle
   ends here and the run goes on exactly as on a fixed mesh;
4. **rebuild**: ``family.rebuild(problem, mesh) -> new_problem`` (the same problem on the new
   mesh: operators, constraint, loads; the stepper's linear system with it);
5. **transfer**: ``family.transfer(state, change, problem, new_problem) -> new_state`` (the
   history through ``change.transfer``: exact on refinement, an injection on coarsening);
6. **relax** (if the family has it): ``family.relax(new_problem, new_state) -> new_state``
   (RIS: the transferred state made consistent with the step's equations again).

Any exception in 1-6 (or a non-finite estimate) rolls the mesh hierarchy back to where it was
and raises :class:`AdaptationFailed`: a failed adaptation never replaces the accepted state. The
family decides what follows (RIS goes on on the step's mesh, ELD stops the run). A
``BaseException`` (a stop signal abandoning the attempt in the relaxation,
:mod:`rothe.stepping.interrupt`; a ``KeyboardInterrupt``) rolls the hierarchy back too and
passes through unchanged.

Each phase is timed into ``times`` (a :class:`~rothe.timing.PhaseTimes`, by the names above),
which the evolve loop adds to ``trajectory.stats.seconds``.
"""

from __future__ import annotations

import ctypes
import math
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from ...errors import RotheInputError, described, fail
from ...timing import PhaseTimes
from .bisection import AdaptiveMesh, MeshChange, _compose
from .hysteresis import VertexHistory
from .marking import SpaceAdaptivity, band_marking, doerfler_marking


class AdaptationFailed(RuntimeError):
    """An adaptation that could not be completed; the mesh hierarchy is rolled back.

    ``cause`` is the exception raised inside the cycle (None for a non-finite estimate)."""

    def __init__(self, message: str, cause: BaseException | None = None):
        super().__init__(message)
        self.cause = cause


@dataclass
class Adaptation:
    """What one cycle did: ``changed`` False means the mesh (and everything else) stayed.

    ``estimate`` is eta = (sum eta_K^2)^(1/2) on the mesh before the change; with ``changed``,
    ``problem`` and ``state`` live on the new mesh, ``change`` is the
    :class:`~rothe.fem.adapt.bisection.MeshChange`.
    """

    changed: bool
    estimate: float
    problem: object = None
    state: object = None
    change: MeshChange | None = None
    eta: np.ndarray | None = field(default=None, repr=False)

    @property
    def bisections(self) -> int:
        return int(self.change.bisections) if self.change is not None else 0

    @property
    def merges(self) -> int:
        return int(self.change.merges) if self.change is not None else 0


class MeshAdaptation:
    """The adaptive mesh of one run, its options, and the adapt cycle (module docstring).

    Parameters
    ----------
    mesh : scikit-fem MeshTri or MeshTet
        The run's initial mesh (named boundary parts and subdomains are inherited).
    options : SpaceAdaptivity
    degree, components : int
        The finite element whose dofs ``max_dofs`` counts (P``degree``, ``components`` fields).
    times : PhaseTimes, optional
        Where the phases are timed (a new one by default).
    hysteresis : dict, optional
        The family's defaults of ``coarsen_delay``, ``max_recoarsen``, ``refine_band`` and
        ``coarsen_batch`` (used where the options leave them None; :mod:`.hysteresis`,
        :mod:`.marking`); none: no hysteresis, no band, no batch.
    """

    def __init__(
        self,
        mesh,
        options: SpaceAdaptivity,
        *,
        degree: int = 1,
        components: int = 1,
        times: PhaseTimes | None = None,
        hysteresis: dict | None = None,
    ):
        if not isinstance(options, SpaceAdaptivity):
            raise fail(
                "adapt",
                described(type(options).__name__),
                "must be a rothe.fem.adapt.SpaceAdaptivity (or None for a fixed mesh)",
            )
        self.options = options
        self.degree = int(degree)
        self.components = int(components)
        self.amesh = AdaptiveMesh(mesh)
        options.check_mesh(self.amesh, self.degree, self.components)
        self.times = times if times is not None else PhaseTimes()
        defaults = dict(hysteresis or {})

        def option(key, default):
            value = getattr(options, key)
            return value if value is not None else defaults.get(key, default)

        self.coarsen_delay = int(option("coarsen_delay", 0))
        self.max_recoarsen = option("max_recoarsen", None)
        self.refine_band = float(option("refine_band", 0.0))
        self.coarsen_batch = float(option("coarsen_batch", 0.0))
        self.history = VertexHistory(self.amesh.n_vertices)
        self._band = None  # (barycentres, target generations) of the band's core, when refining
        #: the MeshChange of the cycle under way (set before the family's rebuild: an
        #: incremental rebuild reuses what belongs to its unchanged cells)
        self.change = None

    @property
    def mesh_id(self) -> int:
        return int(self.amesh.mesh_id)

    @property
    def mesh(self):
        return self.amesh.mesh

    def due(self, accepted_steps: int) -> bool:
        """Whether to adapt after the accepted step with this (1-based) number."""
        return self.options.due(accepted_steps)

    def cycle(
        self,
        family,
        problem,
        target,
        state,
        *,
        refine_only: bool = False,
        refine_above: float | None = None,
    ) -> Adaptation:
        """One adaptation (module docstring): the indicators of ``target`` on ``problem``'s
        mesh decide the new mesh; ``state`` is what moves to it.

        ``refine_only``: refine (Doerfler) while eta > ``refine_above`` (default space_tol),
        never coarsen. Returns an :class:`Adaptation`; raises :class:`AdaptationFailed`
        (hierarchy rolled back)."""
        opts, times = self.options, self.times
        snapshot = history = None  # taken once the marks say the mesh may change
        self._band = None
        try:
            with times.phase("estimate"):
                eta = np.asarray(family.indicators(problem, target), dtype=float)
            if eta.shape != (self.amesh.n_cells,) or not np.all(np.isfinite(eta)):
                raise AdaptationFailed("the error indicators are not finite (or not one per cell)")
            estimate = float(np.sqrt(np.sum(eta * eta)))
            with times.phase("mark"):
                if refine_only:
                    above = opts.space_tol if refine_above is None else refine_above
                    refine = (
                        doerfler_marking(eta, opts.refine_fraction) if estimate > above else None
                    )
                    coarsen = None
                    if refine is not None and self.refine_band > 0.0:
                        self._band = self._deep_band(refine, estimate / above)
                else:
                    keep = getattr(family, "keep_cells", None)
                    refine, coarsen = self._mark(
                        eta, None if keep is None else keep(problem, target, self.amesh)
                    )
            if refine is None or not (np.any(refine) or (coarsen is not None and np.any(coarsen))):
                self.history.cycles += 1
                return Adaptation(False, estimate, eta=eta)
            with times.phase("refine"):
                snapshot = self.amesh.checkpoint_state()
                history = self.history.checkpoint_state()
                change = self.amesh.adapt(
                    refine=refine,
                    coarsen=coarsen,
                    coarsen_rounds=opts.coarsen_rounds if coarsen is not None else 1,
                    max_dofs=opts.max_dofs,
                    degree=self.degree,
                    components=self.components,
                    priority=eta,
                    max_level=opts.max_level,
                )
                if self._band is not None and change.changed:
                    change = self._refine_band(change)
            if not change.changed:
                self.history.cycles += 1
                return Adaptation(False, estimate, eta=eta)
            self.history.observe(change)
            self.history.cycles += 1
            # what the family's rebuild may reuse (the cells that did not change)
            self.change = change
            with times.phase("rebuild"):
                new_problem = family.rebuild(problem, self.amesh.mesh)
            with times.phase("transfer"):
                new_state = family.transfer(state, change, problem, new_problem)
            relax = getattr(family, "relax", None)
            if relax is not None:
                with times.phase("relax"):
                    new_state = relax(new_problem, new_state)
        except BaseException as exc:  # any failure: the accepted state stands
            if snapshot is not None:
                self.amesh = AdaptiveMesh.restore_state(snapshot)
                self.history = VertexHistory.restore_state(history)
            if not isinstance(exc, Exception):  # e.g. a stop signal that abandons the attempt
                raise
            if isinstance(exc, AdaptationFailed):
                raise
            if isinstance(exc, RotheInputError):
                detail = str(exc)
            else:
                detail = f"{type(exc).__name__}: {exc}"
            raise AdaptationFailed(detail, exc) from exc
        return Adaptation(True, estimate, new_problem, new_state, change, eta)

    def _mark(self, eta: np.ndarray, keep: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`SpaceAdaptivity.mark` with the hysteresis, the refinement band, the
        coarsening batch (:mod:`.marking`, :mod:`.hysteresis`) and the cells the family keeps
        from coarsening (``keep``, a mask or None)."""
        opts, amesh = self.options, self.amesh
        frozen = None if keep is None else np.asarray(keep, dtype=bool)
        if self.coarsen_delay > 0 or self.max_recoarsen is not None:
            held = self.history.frozen_cells(
                amesh.points, amesh.cells, self.coarsen_delay, self.max_recoarsen
            )
            frozen = held if frozen is None else (frozen | held)
        self._band = None
        if self.refine_band > 0.0:
            core = doerfler_marking(eta, opts.refine_fraction)
            points, cells, levels = amesh.points, amesh.cells, amesh.levels
            estimate = float(np.sqrt(np.sum(eta * eta)))
            centres, target = self._deep_band(core, estimate / opts.space_tol)
            band, behind = band_marking(points, cells, levels, centres, target, self.refine_band)
            frozen = band if frozen is None else (frozen | band)
            self._band = (centres, target)
        refine, coarsen = opts.mark(eta, frozen)
        if self._band is not None and refine.any():
            refine = refine | behind
        else:
            self._band = None  # the band is refined only when the estimate asks to refine
        if (
            not refine.any()
            and self.coarsen_batch > 0.0
            and np.count_nonzero(coarsen) < self.coarsen_batch * len(eta)
        ):
            coarsen = np.zeros_like(coarsen)
        return refine, coarsen

    def _deep_band(self, core: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray]:
        """The band of a refine-only round (``refine_band`` > 0): the Doerfler set ``core`` and
        the cells within refine_band of it go b generations deeper in one mesh change, b the
        bisections after which the estimate of a P``degree`` field in d dimensions would meet
        the threshold if the core carried all of it: eta_K^2 shrinks by 2^(-2p/d) per
        bisection, so b = ceil((d/p) log2 ``ratio``), 1 <= b <= 2d (``ratio`` = eta over the
        threshold)."""
        amesh, opts = self.amesh, self.options
        d, p = amesh.dim, max(self.degree, 1)
        b = int(np.clip(math.ceil((d / p) * math.log2(max(ratio, 1.0))), 1, 2 * d))
        points, cells, levels = amesh.points, amesh.cells, amesh.levels
        centres = points[cells[core]].mean(axis=1)
        target = levels[core] + b
        if opts.max_level is not None:
            target = np.minimum(target, opts.max_level)
        return centres, target

    def _refine_band(self, change: MeshChange) -> MeshChange:
        """Bisect the band cells still below their target generation (:meth:`_mark`), a few
        rounds, composed into one change with one mesh id."""
        centres, target = self._band
        opts, amesh = self.options, self.amesh
        mesh_id = change.new_mesh_id
        for _ in range(4 * amesh.dim):
            _, behind = band_marking(
                amesh.points, amesh.cells, amesh.levels, centres, target, self.refine_band
            )
            if not behind.any():
                break
            more = amesh.adapt(
                refine=behind,
                max_dofs=opts.max_dofs,
                degree=self.degree,
                components=self.components,
                max_level=opts.max_level,
            )
            if not more.changed:
                break
            change = _compose(change, more)
        amesh.mesh_id = mesh_id
        change.new_mesh_id = mesh_id
        return change

    # -- checkpoint protocol ----------------------------------------------------------------
    def checkpoint_state(self) -> dict:
        """The adaptive mesh's whole hierarchy and the vertex history (:mod:`.hysteresis`) as
        arrays, for a checkpoint."""
        return {"amesh": self.amesh.checkpoint_state(), "history": self.history.checkpoint_state()}

    def restore_state(self, data: dict) -> None:
        """Restore the adaptive mesh and the vertex history from :meth:`checkpoint_state`."""
        self.amesh = AdaptiveMesh.restore_state(data["amesh"])
        if data.get("history") is not None:
            self.history = VertexHistory.restore_state(data["history"])
        else:  # a checkpoint without it: the vertices of the mesh count as initial
            self.history = VertexHistory(self.amesh.n_vertices)


_LIBC = None  # glibc, once looked up (False: not there)
#: glibc's mallopt parameter of the mmap threshold
_M_MMAP_THRESHOLD = -3
#: during a rebuild (:func:`mesh_arrays_mapped`) arrays from this size on get a mapping of
#: their own; above the assembly's 4 MB chunk temporaries (rothe.fem.elasticity.CHUNK_ENTRIES)
MAPPED_FROM = 5 << 20
#: the threshold outside a rebuild: glibc's largest dynamic one on 64-bit systems (what the
#: dynamic threshold rises to once an array of that size was freed)
HEAP_UP_TO = 32 << 20


def _libc():
    """glibc (ctypes), or False where there is none."""
    global _LIBC
    if _LIBC is None:
        try:
            _LIBC = ctypes.CDLL("libc.so.6")
            _LIBC.malloc_trim  # noqa: B018 - present in glibc only
            _LIBC.mallopt  # noqa: B018
        except (OSError, AttributeError):
            _LIBC = False
    return _LIBC


def return_free_memory() -> None:
    """Hand the free pages of the heap back to the system (glibc's ``malloc_trim(0)``; nothing
    where there is no glibc). A family's rebuild calls it before it builds the new mesh's
    matrices: the arrays of the previous meshes, freed in pieces of many sizes, stay resident
    as free heap and the new mesh's arrays come on top of them (the adaptive 3D pulse:
    peak -20 MB at the same CPU time; a fixed mmap threshold instead: -38 MB but +30 % CPU)."""
    libc = _libc()
    if libc:
        libc.malloc_trim(0)


@contextmanager
def mesh_arrays_mapped():
    """While a family's rebuild builds the new mesh's matrices, every array of at least
    :data:`MAPPED_FROM` bytes gets a mapping of its own (glibc's mmap threshold; nothing where
    there is no glibc); after it the threshold is :data:`HEAP_UP_TO`. Why: glibc's dynamic
    threshold puts the mesh's long-lived matrices (K, M, the step matrix and its scaled copy:
    5-10 MB each at 15k P2 dofs in 3D) on the heap among the steps' small arrays; released
    with the mesh (:meth:`rothe.eld.system.ELDSystem.release`) they left holes that the heap
    kept resident and the later meshes' arrays came on top: the adaptive 3D pulse's peak
    167-172 -> 153-154 MB at the same CPU time (+1 %; the same threshold for the whole run:
    -17 MB but +8-20 % CPU, every large temporary mapped and faulted in again,
    docs/adaptivity.md). Side effect on the process: the dynamic threshold is off from the
    first rebuild on, fixed at its own maximum."""
    libc = _libc()
    if not libc:
        yield
        return
    libc.mallopt(_M_MMAP_THRESHOLD, MAPPED_FROM)
    try:
        yield
    finally:
        libc.mallopt(_M_MMAP_THRESHOLD, HEAP_UP_TO)


def finite_or_fail(name: str, values) -> np.ndarray:
    """``values`` as a float array, or FloatingPointError naming ``name`` (a transfer check)."""
    arr = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise FloatingPointError(f"the transferred {name} has NaN or inf entries")
    return arr


def energy_or_fail(energy: float) -> float:
    """``energy`` if finite, else FloatingPointError (a transfer check)."""
    if not math.isfinite(energy):
        raise FloatingPointError("the energy of the transferred state is not finite")
    return float(energy)
