"""Space adaptivity of RIS runs: the RIS side of the adapt cycle (:mod:`rothe.fem.adapt.cycle`).

Andreia & Meyer (2022), Alg. 3.2 with Example 1.4 discretized by P1 elements: every step (3.1)
is a stationary problem on whatever mesh the step uses. After the accepted step k on mesh M_k
(and only if the run goes on), :meth:`RISAdaptivity.adapt` runs the shared cycle with

1. **estimate**: cell indicators of the step on M_k (:func:`rothe.ris.indicator.
   ris_indicators_for`: the residual of (3.1) by Lemma 4.1 with z_{k-1}, z_k, lambda_k and the
   load at t_{k-1}, plus the jumps of c grad z_k . n);
2. **mark, refine/coarsen**: Doerfler refinement, coarsening of cells the front has left,
   ``max_dofs`` (:class:`rothe.fem.adapt.SpaceAdaptivity`);
3. **rebuild**: the same problem on the new mesh (:meth:`FERISProblem.on_mesh`: A, F, R, the
   lumped metric and the load rebuilt from the same data);
4. **transfer**: z_k (and the increment z_k - z_{k-1}, the next step's warm start) by nodal
   interpolation on the free nodes (:func:`rothe.fem.adapt.free_transfer`).

The next step k + 1 then starts from the transferred z_k on M_{k+1}: it is KKT-exact there
(Lemma 4.1 on M_{k+1}), its descent condition (3.2) compares I(t_k, z_{k+1}) + R(z_{k+1} - z_k)
with I(t_k, z_k) *after transfer*, and I_1, I_2 (3.3), (3.4) use the affine interpolant between
the transferred z_k and z_{k+1}, all on M_{k+1}: nothing of a step mixes two meshes.

Why nodal interpolation: on refinement it is exact (P1 on M_k is a subspace of P1 on M_{k+1}),
so a refinement changes neither z_k nor I(t_k, z_k) (up to the lumped quadrature of F, which
sees the new nodes). On coarsening it is an injection (the coarse nodes are nodes of the fine
mesh): it keeps z = 0 on the Dirichlet nodes, is local, costs no solve, and leaves the unchanged
part of the mesh bit for bit alone; an L2 projection would smear the phase front across a
coarse cell and produce values outside the wells. What interpolation does not keep is the
energy: the change I(t_k, T z_k) - I(t_k, z_k) is recorded per step as ``transfer_energy``.

An adaptation that fails (an exception, a non-finite value, a mesh the problem cannot live on)
is never used: the cycle rolls the mesh hierarchy back, the run continues on M_k, and
``transfer_failures`` counts it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import described, fail
from ..fem.adapt import SpaceAdaptivity, free_transfer
from ..fem.adapt.cycle import AdaptationFailed, MeshAdaptation, finite_or_fail
from ..io.mesh_series import MeshSeries
from .indicator import ris_indicators_for


@dataclass
class RISAdaptStep:
    """What the adapt step after one accepted step did (for the trajectory).

    ``state`` is the state to go on from (on the new mesh when ``changed``), ``increment`` the
    accepted increment z_k - z_{k-1} on that mesh, ``transfer_energy`` I(t_k, T z_k) -
    I(t_k, z_k) (0 when nothing changed)."""

    changed: bool
    problem: object
    z: np.ndarray
    increment: np.ndarray | None
    transfer_energy: float = 0.0


class RISAdaptivity:
    """The adaptive mesh of one RIS run, its mesh series, and the RIS side of the cycle.

    ``problem`` is the run's initial :class:`~rothe.ris.fem_problem.FERISProblem`; it is kept
    (not rebuilt) until the first change, so a run in which nothing is ever marked is the
    fixed-mesh run bit for bit.
    """

    def __init__(self, problem, options: SpaceAdaptivity, *, reaction: str = "lambda", times=None):
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
        self.options = options
        self.initial = problem
        self.reaction = reaction
        self.meshes = MeshAdaptation(problem.mesh, options, degree=1, times=times)
        self.series = MeshSeries()
        self.series.add(0, problem.mesh.p.T, problem.mesh.t.T)
        self.adaptations = 0  # adaptations that changed the mesh
        self.transfer_failures = 0
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
        ind = ris_indicators_for(
            problem, t_prev, z, z_prev, lam, coefficient=problem.coefficient, reaction=reaction
        )
        return ind.eta

    def rebuild(self, problem, mesh):
        """The run's problem on ``mesh`` (always from the initial problem's data)."""
        return self.initial.on_mesh(mesh)

    def transfer(self, state, change, problem, new_problem):
        """(z, increment) through the nodal interpolation on the free nodes."""
        z, increment = state
        P = free_transfer(change.transfer(1), problem.free, new_problem.free)
        z_new = finite_or_fail("state", P @ z)
        if z_new.shape != (new_problem.n,):
            raise ValueError("the transferred state has the wrong size")
        return z_new, (P @ increment if increment is not None else None)

    # -- after an accepted step ----------------------------------------------------------------
    def adapt(
        self, problem, t_prev: float, z_prev, z, lam: float, increment, t: float, energy: float
    ) -> RISAdaptStep:
        """The adapt step after a step from (t_prev, z_prev) to z (multiplier lam, energy
        I(t, z)) on ``problem``'s mesh: the same z when nothing changed or the adaptation
        failed (counted in ``transfer_failures``), else z and the increment on the new mesh."""
        unchanged = RISAdaptStep(False, problem, z, increment)
        try:
            out = self.meshes.cycle(self, problem, (t_prev, z_prev, z, lam), (z, increment))
        except AdaptationFailed as exc:
            self.transfer_failures += 1
            cause = exc.cause if exc.cause is not None else exc
            self.last_failure = f"{type(cause).__name__}: {cause}"
            return unchanged
        if not out.changed:
            return unchanged
        new_problem = out.problem
        z_new, d_new = out.state
        self.adaptations += 1
        self.series.add(self.meshes.mesh_id, self.meshes.amesh.points, self.meshes.amesh.cells)
        self.last_change = {
            "mesh_id": self.mesh_id,
            "estimate": float(out.estimate),
            "bisections": out.bisections,
            "merges": out.merges,
            "dofs": int(new_problem.n),
        }
        transfer_energy = new_problem.energy(t, z_new) - energy
        return RISAdaptStep(True, new_problem, z_new, d_new, float(transfer_energy))

    # -- checkpoint protocol -------------------------------------------------------------------
    def checkpoint_state(self) -> dict:
        """The mesh hierarchy, the series of meshes and the counters."""
        return {
            "amesh": self.meshes.amesh.checkpoint_state(),
            "series": self.series.checkpoint_state(),
            "adaptations": int(self.adaptations),
            "transfer_failures": int(self.transfer_failures),
        }

    def restore_state(self, data: dict):
        """Rebuild the hierarchy and the series; returns the problem on the current mesh."""
        self.meshes.restore_state({"amesh": data["amesh"]})
        self.series = MeshSeries.restore_state(data["series"])
        self.adaptations = int(data["adaptations"])
        self.transfer_failures = int(data["transfer_failures"])
        return self.problem_now()
