"""Marking for space adaptivity: bulk (Doerfler) refinement, coarsening, the dof cap, options.

Given cell indicators eta_K >= 0 with the global estimate eta = (sum_K eta_K^2)^(1/2):

* **Refinement** (Doerfler 1996, bulk criterion), only while eta > ``space_tol``: the smallest
  set R of cells with the largest indicators such that

      sum_{K in R} eta_K^2 >= refine_fraction * eta^2.

  Cells whose indicator equals the smallest one taken are all taken (ties are not broken by
  cell number), so meshes with a symmetry keep it.
* **Coarsening**: with E^2 = max(eta, space_tol)^2, the largest set C of cells with the
  smallest indicators such that

      sum_{K in C} eta_K^2 <= coarsen_fraction * E^2,

  cells of R excluded. Relative to E (not eta): when the estimate is far below the tolerance,
  the cells that carry only a ``coarsen_fraction`` share of the *tolerance* may coarsen (a
  region the front has left, eta_K ~ 0, coarsens completely), and when refining (eta >
  space_tol) the two sets are disjoint as long as refine_fraction + coarsen_fraction <= 1. A
  marked cell merges with its sibling only if the whole patch of the bisection to undo is
  marked (:mod:`rothe.fem.adapt.bisection`). Coarsening a cell typically multiplies its
  squared indicator by 2^(2p/d) (P1: 2 in 2D); the next adaptation refines again if that
  matters.
* **space_tol** therefore controls when to refine (eta > space_tol) and how much error the
  coarsened cells may carry (coarsen_fraction * max(eta, space_tol)^2).
* **max_dofs** caps the dofs of the space after the adaptation (P``degree`` with
  ``components`` components, counted with Euler's formula, no space built). Coarsening is
  applied first and frees room; if refining all of R would exceed the cap, only the cells of R
  with the largest indicators are refined: the largest k such that the top-k cells plus their
  conformity closure stay within the cap (found by bisection on k). If the cap binds already
  the mesh is only coarsened.
* **adapt_every** = k: the stepper adapts after every k-th accepted step (the counter is the
  stepper's; :meth:`SpaceAdaptivity.due` says whether step number n is one).
* **refine_band** = r (a length): the cells within r of the Doerfler set D (barycentre to
  barycentre, D computed whatever the estimate) are kept from coarsening, and when refining,
  they are refined, in the same adaptation, until they reach the generation D is refined to
  (:func:`band_marking`; a few bisection rounds, one mesh change). A moving feature then finds
  a refined band where it goes next: with r = the distance it travels in ``adapt_every``
  steps, the mesh keeps up with one adaptation every ``adapt_every`` steps instead of one per
  step, and a fine band reaches ahead of it at once instead of one generation per step.
* **coarsen_batch** = b: an adaptation that would only coarsen happens when at least a share b
  of the cells is marked (a mesh change costs a rebuild, a transfer and a new factorization;
  merging a handful of cells does not pay that back). Coarsening together with a refinement
  always happens.
* **Hysteresis** (:mod:`.hysteresis`): ``coarsen_delay`` = k keeps the cells of vertices created
  in the last k adaptations from coarsening, ``max_recoarsen`` = m keeps a vertex that has been
  removed m times for good; so no cell is refined and coarsened again more than m times. None
  (the default) leaves the choice to the family (:class:`~rothe.fem.adapt.cycle.MeshAdaptation`
  ``hysteresis=``: RIS 4 and 2, ELD none).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ...errors import RotheInputError, check_choice, check_int, check_real, described, fail

#: the norms an indicator may estimate (SpaceAdaptivity.norm)
NORMS = ("energy", "l2")


def doerfler_marking(eta: np.ndarray, fraction: float) -> np.ndarray:
    """Boolean mask of the smallest set with sum eta_K^2 >= fraction * sum eta^2 (ties kept).

    Vectorized: one sort, one cumulative sum, one search.
    """
    eta = np.asarray(eta, dtype=float)
    e2 = eta * eta
    total = float(e2.sum())
    if total == 0.0 or fraction <= 0.0:
        return np.zeros(eta.shape, dtype=bool)
    order = np.argsort(-e2, kind="stable")
    csum = np.cumsum(e2[order])
    k = int(np.searchsorted(csum, fraction * total * (1.0 - 1e-14)))
    k = min(k, len(order) - 1)
    threshold = e2[order[k]]
    return e2 >= threshold


def coarsen_marking(
    eta: np.ndarray, budget: float, exclude: np.ndarray | None = None
) -> np.ndarray:
    """Boolean mask of the largest set of smallest indicators with sum eta_K^2 <= budget."""
    eta = np.asarray(eta, dtype=float)
    e2 = eta * eta
    allowed = np.ones(eta.shape, dtype=bool) if exclude is None else ~np.asarray(exclude)
    idx = np.flatnonzero(allowed)
    if idx.size == 0 or budget < 0:
        return np.zeros(eta.shape, dtype=bool)
    order = idx[np.argsort(e2[idx], kind="stable")]
    csum = np.cumsum(e2[order])
    k = int(np.searchsorted(csum, budget, side="right"))
    mask = np.zeros(eta.shape, dtype=bool)
    if k == 0:
        return mask
    # keep ties together: the last indicator taken decides for all cells equal to it
    last = e2[order[k - 1]]
    if k < len(order) and e2[order[k]] == last:
        take = e2[order] < last
        mask[order[take]] = True
        return mask
    mask[order[:k]] = True
    return mask


def band_marking(
    points: np.ndarray,
    cells: np.ndarray,
    levels: np.ndarray,
    core_centres: np.ndarray,
    core_target: np.ndarray,
    radius: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The band of width ``radius`` around core cells: (near, behind).

    ``core_centres`` (k, d) are the barycentres of the core cells (the Doerfler set), and
    ``core_target`` (k,) the generation each is refined to. ``near``: the cells of the mesh
    (``points``, ``cells``, ``levels``) whose barycentre is within ``radius`` of a core
    barycentre; ``behind``: those of them below the target of that nearest core cell (to be
    refined). One k-d tree query (scipy), no loop over cells.
    """
    near = np.zeros(len(cells), dtype=bool)
    if radius <= 0.0 or len(core_centres) == 0:
        return near, near.copy()
    centres = np.asarray(points)[np.asarray(cells)].mean(axis=1)
    dist, j = cKDTree(core_centres).query(centres, distance_upper_bound=radius)
    near = np.isfinite(dist)
    behind = np.zeros(len(cells), dtype=bool)
    behind[near] = levels[near] < core_target[j[near]]
    return near, behind


@dataclass
class SpaceAdaptivity:
    """Options of space adaptivity, validated where they enter (one-line errors).

    Parameters
    ----------
    space_tol : float > 0
        Tolerance for the global estimate eta (refine only while eta > space_tol; the
        coarsened cells may carry coarsen_fraction * max(eta, space_tol)^2).
    refine_fraction : float in (0, 1)
        Doerfler bulk fraction theta_r of eta^2 to refine.
    coarsen_fraction : float in (0, 1)
        Share theta_c of max(eta, space_tol)^2 that the coarsened cells may carry;
        refine_fraction + coarsen_fraction <= 1.
    max_dofs : int >= 1 or None
        Cap on the dofs after an adaptation; checked against the initial mesh by
        :meth:`check_mesh` (it must not be below the dofs the run starts with).
    adapt_every : int >= 1
        Adapt after every adapt_every-th accepted step.
    max_level : int >= 0 or None
        Marked cells of this bisection generation are not refined further.
    coarsen_rounds : int >= 1
        Generations of bisection that one adaptation may undo.
    coarsen_delay : int >= 0 or None
        Hysteresis: cells with a vertex created in the last ``coarsen_delay`` adaptations are
        not coarsened (None: the family's default).
    max_recoarsen : int >= 0 or None
        Hysteresis: a vertex removed this many times is never removed again, so no cell is
        refined and coarsened again more often (None: the family's default, which may be no
        bound).
    refine_band : float >= 0 or None
        Width of the band around the Doerfler set that is refined with it and kept from
        coarsening (a length; None: the family's default, 0 = none).
    coarsen_batch : float in [0, 1) or None
        Least share of the cells marked for an adaptation that only coarsens (None: the
        family's default, 0 = any).
    norm : 'energy' or 'l2'
        The norm the indicators estimate: ``'energy'``, the step's energy norm (the residual
        indicator eta_K as it is); ``'l2'``, the L2 norm of u by duality (Aubin-Nitsche: the
        local factor h of ||e||_L2 <~ (sum_K h_K^2 eta_K^2)^(1/2)), eta_K h_K / h_0 with h_0
        the longest cell edge of the initial mesh, so that both agree on the initial mesh
        and ``space_tol`` keeps its scale there. Only families whose indicator is an energy-
        norm residual estimator take ``'l2'`` (elastodynamics).
    """

    space_tol: float
    refine_fraction: float = 0.5
    coarsen_fraction: float = 0.05
    max_dofs: int | None = None
    adapt_every: int = 1
    max_level: int | None = None
    coarsen_rounds: int = 1
    coarsen_delay: int | None = None
    max_recoarsen: int | None = None
    refine_band: float | None = None
    coarsen_batch: float | None = None
    norm: str = "energy"

    def __post_init__(self):
        tol = check_real("space_tol", self.space_tol)
        if not tol > 0:
            raise fail("space_tol", self.space_tol, "must be > 0")
        self.space_tol = tol
        for key in ("refine_fraction", "coarsen_fraction"):
            v = check_real(key, getattr(self, key))
            if not 0.0 < v < 1.0:
                raise fail(key, getattr(self, key), "must be in (0, 1)")
            setattr(self, key, v)
        total = self.refine_fraction + self.coarsen_fraction
        if total > 1.0:
            raise RotheInputError(
                f"refine_fraction + coarsen_fraction: got "
                f"{self.refine_fraction:g} + {self.coarsen_fraction:g} = {total:g}, must be "
                "<= 1 (the refined and the coarsened cells must not overlap)",
                "refine_fraction",
                mentions=("coarsen_fraction",),
            )
        if self.max_dofs is not None:
            self.max_dofs = check_int("max_dofs", self.max_dofs, minimum=1)
        self.adapt_every = check_int("adapt_every", self.adapt_every, minimum=1)
        if self.max_level is not None:
            self.max_level = check_int("max_level", self.max_level, minimum=0)
        self.coarsen_rounds = check_int("coarsen_rounds", self.coarsen_rounds, minimum=1)
        for key in ("coarsen_delay", "max_recoarsen"):
            if getattr(self, key) is not None:
                setattr(self, key, check_int(key, getattr(self, key), minimum=0))
        if self.refine_band is not None:
            band = check_real("refine_band", self.refine_band)
            if not band >= 0.0:
                raise fail("refine_band", self.refine_band, "must be >= 0 (a length)")
            self.refine_band = band
        if self.coarsen_batch is not None:
            batch = check_real("coarsen_batch", self.coarsen_batch)
            if not 0.0 <= batch < 1.0:
                raise fail("coarsen_batch", self.coarsen_batch, "must be in [0, 1)")
            self.coarsen_batch = batch
        self.norm = check_choice("norm", self.norm, NORMS)

    def check_mesh(self, amesh, degree: int = 1, components: int = 1) -> int:
        """Check max_dofs against the dofs on ``amesh`` (an AdaptiveMesh); returns those dofs."""
        dofs = amesh.ndofs(degree, components)
        if self.max_dofs is not None and self.max_dofs < dofs:
            raise fail(
                "max_dofs",
                self.max_dofs,
                f"must be >= the {dofs} dofs of the initial mesh",
            )
        return dofs

    def due(self, accepted_steps: int) -> bool:
        """Whether to adapt after the accepted step with this (1-based) number."""
        return accepted_steps > 0 and accepted_steps % self.adapt_every == 0

    def mark(
        self, eta: np.ndarray, frozen: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(refine, coarsen) masks from the cell indicators (see the module docstring);
        ``frozen`` (a cell mask) is never marked for coarsening (hysteresis, the band)."""
        eta = np.asarray(eta, dtype=float)
        if eta.ndim != 1 or not np.all(np.isfinite(eta)) or np.any(eta < 0):
            raise fail(
                "indicators",
                described("an array that is not finite and >= 0 per cell"),
                "must be one finite value >= 0 per cell",
            )
        est = float(np.sqrt(np.sum(eta * eta)))
        refine = (
            doerfler_marking(eta, self.refine_fraction)
            if est > self.space_tol
            else np.zeros(eta.shape, dtype=bool)
        )
        budget = self.coarsen_fraction * max(est, self.space_tol) ** 2
        exclude = refine if frozen is None else (refine | np.asarray(frozen, dtype=bool))
        coarsen = coarsen_marking(eta, budget, exclude=exclude)
        return refine, coarsen

    def describe(self) -> dict:
        """The options as in a trajectory's meta data and a summary."""
        out = {
            "space_tol": self.space_tol,
            "refine_fraction": self.refine_fraction,
            "coarsen_fraction": self.coarsen_fraction,
            "max_dofs": self.max_dofs,
            "adapt_every": self.adapt_every,
            "max_level": self.max_level,
            "coarsen_rounds": self.coarsen_rounds,
        }
        # the hysteresis options only when set (the descriptions of runs without them, and
        # their checkpoints, stay as they were)
        for key in ("coarsen_delay", "max_recoarsen", "refine_band", "coarsen_batch"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        if self.norm != "energy":  # likewise: a run in the energy norm keeps its description
            out["norm"] = self.norm
        return out


def adapt_mesh(
    amesh, eta: np.ndarray, options: SpaceAdaptivity, *, degree: int = 1, components: int = 1
):
    """Mark by ``options`` and adapt ``amesh`` (coarsen, then refine under the dof cap).

    Returns the :class:`~rothe.fem.adapt.bisection.MeshChange` (``change.changed`` is False
    when nothing was marked or nothing could change; the transfer is then the identity).
    """
    if len(eta) != amesh.n_cells:
        raise fail(
            "indicators",
            described(f"{len(eta)} values"),
            f"must have one per cell ({amesh.n_cells})",
        )
    refine, coarsen = options.mark(eta)
    return amesh.adapt(
        refine=refine,
        coarsen=coarsen,
        coarsen_rounds=options.coarsen_rounds,
        max_dofs=options.max_dofs,
        degree=degree,
        components=components,
        priority=eta,
        max_level=options.max_level,
    )
