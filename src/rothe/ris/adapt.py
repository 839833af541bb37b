"""Space adaptivity of RIS runs: the RIS side of the adapt cycle (:mod:`rothe.fem.adapt.cycle`).

Andreia & Meyer (2022), Alg. 3.2 with Example 1.4 discretized by P1 elements: every step (3.1)
is a stationary problem on whatever mesh the step uses. After the accepted step k on mesh M_k
(from z_{k-1} at t_{k-1}, multiplier lambda_k; only if the run goes on),
:meth:`RISAdaptivity.adapt` runs the shared cycle with

1. **estimate**: cell indicators of the step on M_k (:func:`rothe.ris.indicator.
   ris_indicators_for`: the residual of (3.1) by Lemma 4.1 with z_{k-1}, z_k, lambda_k and the
   load at t_{k-1}, plus the jumps of c grad z_k . n);
2. **mark, refine/coarsen**: Doerfler refinement, coarsening of cells the front has left,
   ``max_dofs``, and the hysteresis of :mod:`rothe.fem.adapt.hysteresis` (RIS defaults
   :data:`HYSTERESIS`: cells of vertices created in the last 4 adaptations do not coarsen, a
   vertex removed twice stays);
3. **rebuild**: the same problem on the new mesh (:meth:`FERISProblem.on_mesh`: A, F, R, the
   lumped metric and the load rebuilt from the same data);
4. **transfer**: z_k (and the increment z_k - z_{k-1}, the next step's warm start) by nodal
   interpolation on the free nodes (:func:`rothe.fem.adapt.free_transfer`);
5. **relax** (below): the transferred state made stationary again on M_{k+1}, at fixed time.

Mesh changes must not drive the evolution
-----------------------------------------
A transfer changes the energy (interpolation of the non-convex g, the lumped quadrature of F on
new nodes) and leaves a state that does not satisfy the step's equations on the new mesh. Taken
as it is for the start of step k + 1, the scheme itself relaxes that defect, by steps on the
sphere with t_k - t_{k-1} = 0: viscous steps of the path that are artefacts of the mesh.
Measured before this remedy (Example 7.2, 16 x 16, regime, tol 1e-5, ``space_tol`` 1): the
viscous jump at t = 0.17196 never ended (395 of the first 400 steps with t' = 0, 139 mesh
changes, vertices created and removed up to 15 times, transfer energy +0.60 against a
dissipation of 26), every step after a mesh change had t' = 0. Adapting only after interior
steps (lambda_k = 0) ended the jump, but each of the 12 mesh changes after it still started a
relaxation of 7-18 steps with t' = 0, counted as 10 viscous jumps instead of one; and on a fast
front most steps are on the sphere (75 % on the unique front), so adaptation would wait most of
the time. The remedy here: **the accepted step k is re-solved on the new mesh at its own
multiplier, at fixed time, outside the path**. By Lemma 4.1, z_k on M_k is a stationary point of

    J_k(z) = I(t_{k-1}, z) + R(z - z_{k-1}) + lambda_k/2 ||z - z_{k-1}||_V^2     ((4.4) with
                                                                               lambda_k fixed)

(on the sphere, lambda_k > 0, in a viscous jump or a catch-up step; or inside the ball,
lambda_k = 0, in slip or sticking: then z_k is locally stable at t_{k-1}). On M_{k+1} the
relaxed state z* is the stationary point of the same functional with z_{k-1} replaced by its
transfer T z_{k-1}, found by the step's own solver (:class:`~rothe.ris.inner.BallStepSolver`
on J_k, a convex quadratic added to F) **started at T z_k** and descending from there, so it
is the stationary point next to the transferred state, not another branch. z* satisfies on
M_{k+1} what z_k satisfied on M_k (the step's equation with the same t_{k-1}, z_{k-1} and
lambda_k), so step k + 1 continues the evolution as on a fixed mesh: a jump under way goes on,
a stable state stays stable. Nothing advances: s and t stay, the relaxation is not a step of the
path (not in the trajectory's steps, never counted as a viscous step) and is booked on its own,
per step, as ``relax_energy`` = I(t_k, z*) - I(t_k, T z_k) and ``relax_dissipation`` =
R(z* - T z_k). A ball keeps it local: ||z - T z_{k-1}||_V <= ||T z_k - T z_{k-1}||_V +
:data:`RELAX_SCALE` (||T z_k||_V + tau_k). If the solver does not converge, or ends on that
sphere (no stationary point near the transferred state), the adaptation is refused: the mesh
hierarchy is rolled back, the run continues on M_k, and ``relax_refused`` counts it.

The step k + 1 then starts from z* on M_{k+1}: it is KKT-exact there (Lemma 4.1 on M_{k+1}),
its descent condition (3.2) compares I(t_k, z_{k+1}) + R(z_{k+1} - z*) with I(t_k, z*), and
I_1, I_2 (3.3), (3.4) use the affine interpolant between z* and z_{k+1}, all on M_{k+1}: nothing
of a step mixes two meshes.

Why nodal interpolation: on refinement it is exact (P1 on M_k is a subspace of P1 on M_{k+1}),
so a refinement changes neither z_k nor 1/2 <A z, z> nor int z (the lumped quadrature of F sees
the new nodes). On coarsening it is an injection (the coarse nodes are nodes of the fine mesh):
it keeps z = 0 on the Dirichlet nodes, is local, costs no solve, and leaves the unchanged part
of the mesh bit for bit alone; an L2 projection would smear the phase front across a coarse
cell and produce values outside the wells. The energy change I(t_k, T z_k) - I(t_k, z_k) is
recorded per step as ``transfer_energy``. Under the vertex rule of F it is, on a refinement,
sum_{v new} m_v (h_v - (T h)_v) with h = g(z) - l z (the lumped integrand at the new midpoints:
48 m_v on the barrier of a double-well interface), and no choice of the new values removes it
where the interface is not resolved (docs/ris_fem.md, *An energy-neutral transfer*); with the
cell rule (``quadrature="consistent"`` of the problem, the commands' default with
``--adapt-space``) F = int g(z_h) exactly, a refinement changes nothing but the load rule's
quadrature error, and a coarsening I by O(surplus) (bounded by :meth:`keep_cells`).

An adaptation that fails (an exception, a non-finite value, a mesh the problem cannot live on)
is never used either: the cycle rolls the mesh hierarchy back, the run continues on M_k, and
``transfer_failures`` counts it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..errors import described, fail
from ..fem.adapt import SpaceAdaptivity, free_transfer
from ..fem.adapt.cycle import AdaptationFailed, MeshAdaptation, energy_or_fail, finite_or_fail
from ..fem.simplex import SimplexEvaluator
from ..io.mesh_series import MeshSeries
from .indicator import ris_indicators_for
from .inner import BallStepSolver

#: RIS defaults of the hysteresis options left None in the SpaceAdaptivity
#: (:mod:`rothe.fem.adapt.hysteresis`)
HYSTERESIS = {"coarsen_delay": 4, "max_recoarsen": 2}

#: a vertex whose removal would change z by more than this share of its range is kept
#: (:meth:`RISAdaptivity.keep_cells`)
KEEP_SURPLUS = 1e-3

#: the relaxation's ball: ||T z_k - T z_{k-1}||_V + RELAX_SCALE (||T z_k||_V + tau_k)
RELAX_SCALE = 0.1


class RelaxationRefused(AdaptationFailed):
    """The transferred state has no stable state within the relaxation's ball (or the solve
    failed): the adaptation is not used."""


@dataclass
class RISAdaptStep:
    """What the adapt step after one accepted step did (for the trajectory).

    ``state`` is the state to go on from (on the new mesh when ``changed``: the relaxed
    transferred state), ``increment`` the accepted increment z_k - z_{k-1} on that mesh,
    ``transfer_energy`` I(t_k, T z_k) - I(t_k, z_k), ``relax_energy`` I(t_k, z*) - I(t_k, T z_k)
    and ``relax_dissipation`` R(z* - T z_k) (all 0 when nothing changed)."""

    changed: bool
    problem: object
    z: np.ndarray
    increment: np.ndarray | None
    transfer_energy: float = 0.0
    relax_energy: float = 0.0
    relax_dissipation: float = 0.0


@dataclass
class _Moving:
    """The state the cycle moves to the new mesh, and what the relaxation adds to it."""

    z: np.ndarray
    increment: np.ndarray | None
    z_prev: np.ndarray  # z_{k-1}
    lam: float  # lambda_k
    t_prev: float  # t_{k-1}: the time of step k (and of its relaxation)
    t: float  # t_k
    tau: float
    energy: float  # I(t_k, z_k) on the old mesh
    transfer_energy: float = 0.0
    relax_energy: float = 0.0
    relax_dissipation: float = 0.0


class _FixedMultiplier:
    """A view of the problem with F + lam/2 ||z - anchor||_V^2 for F (the step's functional at a
    fixed multiplier, module docstring); everything else is the problem's."""

    def __init__(self, problem, anchor, lam):
        self._p = problem
        self._anchor = anchor
        self._lm = float(lam) * problem.m

    def __getattr__(self, name):
        return getattr(self._p, name)

    def F(self, z):
        dz = z - self._anchor
        return self._p.F(z) + 0.5 * float(self._lm @ (dz * dz))

    def dF(self, z):
        return self._p.dF(z) + self._lm * (z - self._anchor)

    def d2F(self, z):
        h = self._p.d2F(z)
        if sp.issparse(h):  # the consistent quadrature's F'' (a matrix with A's sparsity)
            return (h + sp.diags(self._lm)).tocsr()
        return h + self._lm


class RISAdaptivity:
    """The adaptive mesh of one RIS run, its mesh series, and the RIS side of the cycle.

    ``problem`` is the run's initial :class:`~rothe.ris.fem_problem.FERISProblem`; it is kept
    (not rebuilt) until the first change, so a run in which nothing is ever marked is the
    fixed-mesh run bit for bit. ``inner``: the run's :class:`~rothe.ris.inner.InnerOptions`
    (the relaxation uses the step's solver).
    """

    def __init__(
        self, problem, options: SpaceAdaptivity, *, reaction: str = "lambda", times=None, inner=None
    ):
        if not isinstance(options, SpaceAdaptivity):
            raise fail(
                "adapt",
                described(f"a {type(options).__name__}"),
                "must be a rothe.fem.adapt.SpaceAdaptivity (or None for a fixed mesh)",
            )
        if not hasattr(problem, "on_mesh"):
            raise fail(
                "adapt",
                described(f"a {type(problem).__name__} problem"),
                "needs a finite-element RIS (FERISProblem) whose mesh can change",
            )
        problem.check_movable()
        if options.norm != "energy":
            # the RIS indicator is not a residual estimator of an energy norm of a linear
            # problem (its complementarity terms have no duality factor h)
            raise fail(
                "adapt.norm",
                options.norm,
                "must be 'energy' for a rate-independent system ('l2' is elastodynamics')",
            )
        self.options = options
        self.initial = problem
        self.reaction = reaction
        self.inner = inner
        self.meshes = MeshAdaptation(
            problem.mesh, options, degree=1, times=times, hysteresis=HYSTERESIS
        )
        self.series = MeshSeries()
        self.series.add(0, problem.mesh.p.T, problem.mesh.t.T)
        self.adaptations = 0  # adaptations that changed the mesh
        self.transfer_failures = 0
        self.relax_refused = 0
        self._evaluator = None  # (mesh, SimplexEvaluator) of the last estimate
        self.last_change: dict | None = None
        self.last_failure: str | None = None

    @property
    def mesh_id(self) -> int:
        """The id of the current mesh in the run's series (0: the problem's own mesh)."""
        return self.meshes.mesh_id

    def problem_now(self):
        """The problem on the current mesh (the initial one while the mesh is the initial)."""
        if self.meshes.mesh_id == 0:
            return self.initial
        return self.initial.on_mesh(self.meshes.mesh)

    # -- the family's side of the cycle ----------------------------------------------------------
    def indicators(self, problem, target) -> np.ndarray:
        """eta_K of the step from (t_prev, z_prev) to z with multiplier lam (module docstring)."""
        t_prev, z_prev, z, lam = target
        reaction = lam if self.reaction == "lambda" else 0.0
        if self._evaluator is None or self._evaluator[0] is not problem.mesh:
            # the geometry, topology and quadrature of a mesh serve every adaptation on it
            self._evaluator = (
                problem.mesh,
                SimplexEvaluator(problem.mesh, 1, cell_order=4, facet_order=1),
            )
        ind = ris_indicators_for(
            problem,
            t_prev,
            z,
            z_prev,
            lam,
            coefficient=problem.coefficient,
            reaction=reaction,
            evaluator=self._evaluator[1],
        )
        return ind.eta

    def keep_cells(self, problem, target, amesh) -> np.ndarray:
        """Cells that must not coarsen: those around a vertex whose removal would change z_k by
        more than :data:`KEEP_SURPLUS` times its range (the hierarchical surplus
        z_v - (z_a + z_b)/2 of the edge (a, b) that v bisects).

        Why: the residual indicator of a step is blind to where the state came from. Where it
        sticks, R_K only measures the violation of |l - g'(z)| <= kappa, and any change of z
        that keeps it stable stays: a rate-independent state does not relax back. Coarsened
        where it is not affine, the interpolant's error would stay in the state for good
        (measured on the unique front: adaptive meshes as fine as the uniform 128 x 128 along the
        front, yet an error of 0.019 against 0.0085 of the uniform 64 x 64, all of it in the
        band just behind the front that had been coarsened)."""
        _, _, z, _ = target
        full = problem.full_state(z)
        parents = amesh.vertex_parents()
        made = parents[:, 0] >= 0
        surplus = np.zeros(len(full))
        a, b = parents[made, 0], parents[made, 1]
        surplus[made] = np.abs(full[made] - 0.5 * (full[a] + full[b]))
        scale = float(full.max() - full.min()) if full.size else 0.0
        vertex = surplus > KEEP_SURPLUS * scale
        return np.any(vertex[amesh.cells], axis=1)

    def rebuild(self, problem, mesh):
        """The run's problem on ``mesh`` (always from the initial problem's data)."""
        return self.initial.on_mesh(mesh)

    def transfer(self, state: _Moving, change, problem, new_problem) -> _Moving:
        """z_k and the increment through the nodal interpolation on the free nodes; books
        I(t_k, T z_k) - I(t_k, z_k)."""
        P = free_transfer(change.transfer(1), problem.free, new_problem.free)
        z_new = finite_or_fail("state", P @ state.z)
        if z_new.shape != (new_problem.n,):
            raise ValueError("the transferred state has the wrong size")
        increment = P @ state.increment if state.increment is not None else None
        energy = energy_or_fail(new_problem.energy(state.t, z_new))
        return _Moving(
            z_new,
            increment,
            P @ state.z_prev,
            state.lam,
            state.t_prev,
            state.t,
            state.tau,
            state.energy,
            transfer_energy=energy - state.energy,
        )

    def relax(self, new_problem, state: _Moving) -> _Moving:
        """z* on the new mesh: the step re-solved at its own multiplier from T z_k (module
        docstring); raises :class:`RelaxationRefused` if the solver finds none nearby."""
        zt, anchor = state.z, state.z_prev
        rho = new_problem.norm_V(zt - anchor) + RELAX_SCALE * (new_problem.norm_V(zt) + state.tau)
        solver = BallStepSolver(_FixedMultiplier(new_problem, anchor, state.lam), self.inner)
        res = solver.solve(state.t_prev, anchor, rho, start=zt - anchor)
        if not res.converged:
            raise RelaxationRefused(
                f"the relaxation of the transferred state did not converge ({res.code})"
            )
        if res.lam > 0:
            raise RelaxationRefused(
                f"no stationary point within {rho:.3g} of the transferred state"
            )
        e_t = new_problem.energy(state.t, zt)
        e_relaxed = energy_or_fail(new_problem.energy(state.t, res.z))
        return _Moving(
            res.z,
            state.increment,
            state.z_prev,
            state.lam,
            state.t_prev,
            state.t,
            state.tau,
            state.energy,
            transfer_energy=state.transfer_energy,
            relax_energy=e_relaxed - e_t,
            relax_dissipation=float(new_problem.dissipation(res.z - zt)),
        )

    # -- after an accepted step ----------------------------------------------------------------
    def adapt(
        self,
        problem,
        t_prev: float,
        z_prev,
        z,
        lam: float,
        increment,
        t: float,
        energy: float,
        *,
        step: int,
        tau: float,
    ) -> RISAdaptStep:
        """The adapt step after the accepted step number ``step`` (1-based) from (t_prev,
        z_prev) to z (multiplier lam, radius tau, energy I(t, z)) on ``problem``'s mesh.

        Due every ``adapt_every`` steps. Returns the same z when nothing changed, the
        adaptation failed (``transfer_failures``) or its relaxation was refused
        (``relax_refused``); else the relaxed z and the increment on the new mesh."""
        unchanged = RISAdaptStep(False, problem, z, increment)
        if not self.options.due(step):
            return unchanged
        moving = _Moving(z, increment, z_prev, lam, t_prev, t, tau, energy)
        try:
            out = self.meshes.cycle(self, problem, (t_prev, z_prev, z, lam), moving)
        except RelaxationRefused as exc:
            self.relax_refused += 1
            self.last_failure = str(exc)
            return unchanged
        except AdaptationFailed as exc:
            self.transfer_failures += 1
            cause = exc.cause if exc.cause is not None else exc
            self.last_failure = f"{type(cause).__name__}: {cause}"
            return unchanged
        if not out.changed:
            return unchanged
        new_problem = out.problem
        moved: _Moving = out.state
        self.adaptations += 1
        self.series.add(self.meshes.mesh_id, self.meshes.amesh.points, self.meshes.amesh.cells)
        self.last_change = {
            "mesh_id": self.mesh_id,
            "estimate": float(out.estimate),
            "bisections": out.bisections,
            "merges": out.merges,
            "dofs": int(new_problem.n),
        }
        return RISAdaptStep(
            True,
            new_problem,
            moved.z,
            moved.increment,
            transfer_energy=float(moved.transfer_energy),
            relax_energy=float(moved.relax_energy),
            relax_dissipation=float(moved.relax_dissipation),
        )

    @staticmethod
    def ledger(adapted: RISAdaptStep | None, result) -> dict:
        """The energy series of one accepted step on changing meshes: ``transfer_energy``,
        ``relax_energy``, ``relax_dissipation`` of the adapt step after it (0 without a
        change) and ``dissipation`` R(z_k - z_{k-1}) of the step itself, so that the ledger
        compares them with the path's own dissipation."""
        changed = adapted is not None
        return {
            "transfer_energy": adapted.transfer_energy if changed else 0.0,
            "relax_energy": adapted.relax_energy if changed else 0.0,
            "relax_dissipation": adapted.relax_dissipation if changed else 0.0,
            "dissipation": float(result.problem.dissipation(result.increment)),
        }

    def meta(self) -> dict:
        """The counts of the run's adaptations, for ``trajectory.meta``, and the hysteresis in
        effect (the options' values or, where they are None, :data:`HYSTERESIS`'s: the
        options' own description leaves those out)."""
        m = self.meshes
        return {
            "space_adaptations": self.adaptations,
            "transfer_failures": self.transfer_failures,
            "final_mesh_id": self.mesh_id,
            "relax_refused": self.relax_refused,
            "max_recoarsened": self.max_recoarsened(),
            "hysteresis": {
                "coarsen_delay": m.coarsen_delay,
                "max_recoarsen": m.max_recoarsen,
                "refine_band": m.refine_band,
                "coarsen_batch": m.coarsen_batch,
            },
        }

    def max_recoarsened(self) -> int:
        """The most times any vertex has been removed (a cell coarsened after a refinement)."""
        return self.meshes.history.max_removals()

    # -- checkpoint protocol -------------------------------------------------------------------
    def checkpoint_state(self) -> dict:
        """The mesh hierarchy's data, the series and the adaptation counters, for a checkpoint."""
        data = self.meshes.checkpoint_state()
        data.update(
            {
                "series": self.series.checkpoint_state(),
                "adaptations": int(self.adaptations),
                "transfer_failures": int(self.transfer_failures),
                "relax_refused": int(self.relax_refused),
            }
        )
        return data

    def restore_state(self, data: dict):
        """Rebuild the hierarchy and the series; returns the problem on the current mesh."""
        self.meshes.restore_state(data)
        self.series = MeshSeries.restore_state(data["series"])
        self.adaptations = int(data["adaptations"])
        self.transfer_failures = int(data["transfer_failures"])
        self.relax_refused = int(data.get("relax_refused", 0))
        return self.problem_now()
