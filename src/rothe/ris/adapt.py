"""Space adaptivity of RIS runs: a new P1 mesh after every ``adapt_every``-th accepted step.

Andreia & Meyer (2022), Alg. 3.2 with Example 1.4 discretized by P1 elements: every step (3.1)
is a stationary problem on whatever mesh the step uses. After the accepted step k on mesh M_k
(and only if the run goes on):

1. cell indicators of the step on M_k (:func:`rothe.ris.indicator.ris_indicators_for`:
   the residual of (3.1) by Lemma 4.1 with z_{k-1}, z_k, lambda_k and the load at t_{k-1}, plus
   the jumps of c grad z_k . n);
2. marking and adaptation (:func:`rothe.fem.adapt.adapt_mesh`: Doerfler refinement, coarsening
   of cells the front has left, ``max_dofs``);
3. if the mesh changed: the same problem on the new mesh (:meth:`FERISProblem.on_mesh`: A, F,
   R, the lumped metric and the load rebuilt from the same data) and z_k transferred by nodal
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

A transfer that fails (an exception, a non-finite value, a mesh the problem cannot live on) is
never used: the mesh hierarchy is rolled back to its state before the adaptation (from its own
``checkpoint_state``), the run continues on M_k, and ``transfer_failures`` counts it.
"""

from __future__ import annotations

import numpy as np

from ..errors import RotheInputError
from .indicator import ris_indicators_for
from ..fem.adapt import AdaptiveMesh, SpaceAdaptivity, adapt_mesh, free_transfer


def _mesh_series():
    from ..io.mesh_series import MeshSeries

    return MeshSeries()


class RISSpaceAdaptivity:
    """The adaptive mesh of one RIS run, its mesh series, and the adaptation after a step.

    ``problem`` is the run's initial :class:`~rothe.ris.fem_problem.FERISProblem`; it is kept
    (not rebuilt) until the first change, so a run in which nothing is ever marked is the
    fixed-mesh run bit for bit.
    """

    def __init__(self, problem, options: SpaceAdaptivity, *, reaction: str = "lambda"):
        if not isinstance(options, SpaceAdaptivity):
            raise RotheInputError(
                f"space: got a {type(options).__name__}, must be a "
                "rothe.fem.adapt.SpaceAdaptivity (or None for a fixed mesh)"
            )
        if not hasattr(problem, "on_mesh"):
            raise RotheInputError(
                f"space: got a {type(problem).__name__} problem, space "
                "adaptivity needs a finite-element RIS (FERISProblem)"
            )
        problem.check_movable("space" if options.naming == "api" else "--adapt-space")
        self.options = options
        self.initial = problem
        self.reaction = reaction
        self.amesh = AdaptiveMesh(problem.mesh)
        options.check_mesh(self.amesh, degree=1)
        self.series = _mesh_series()
        self.series.add(0, problem.mesh.p.T, problem.mesh.t.T)
        self.adaptations = 0  # adaptations that changed the mesh
        self.transfer_failures = 0
        self.last_change: dict | None = None
        self.last_failure: str | None = None

    @property
    def mesh_id(self) -> int:
        return int(self.amesh.mesh_id)

    def problem_now(self):
        """The problem on the current mesh (the initial one while the mesh is the initial)."""
        if self.amesh.mesh_id == 0:
            return self.initial
        return self.initial.on_mesh(self.amesh.mesh)

    # -- after an accepted step ----------------------------------------------------------------
    def adapt(self, problem, t_prev: float, z_prev, z, lam: float, increment):
        """Adapt after a step from (t_prev, z_prev) to z (lambda = lam) on ``problem``'s mesh.

        Returns None (mesh unchanged, or the transfer failed and the hierarchy was rolled back)
        or (new_problem, z_new, increment_new) on the new mesh.
        """
        reaction = lam if self.reaction == "lambda" else 0.0
        ind = ris_indicators_for(
            problem, t_prev, z, z_prev, lam, coefficient=problem.coefficient, reaction=reaction
        )
        before = self.amesh.checkpoint_state()
        try:
            change = adapt_mesh(self.amesh, ind.eta, self.options, degree=1)
            if not change.changed:
                return None
            new_problem = self.initial.on_mesh(self.amesh.mesh)
            P = free_transfer(change.transfer(1), problem.free, new_problem.free)
            z_new = P @ z
            d_new = P @ increment if increment is not None else None
            if z_new.shape != (new_problem.n,) or not np.all(np.isfinite(z_new)):
                raise ValueError("the transferred state is not finite")
        except Exception as exc:  # noqa: BLE001 - any failure: keep the step's mesh and state
            self.amesh = AdaptiveMesh.restore_state(before)
            self.transfer_failures += 1
            self.last_failure = f"{type(exc).__name__}: {exc}"
            return None
        self.adaptations += 1
        self.series.add(self.amesh.mesh_id, self.amesh.points, self.amesh.cells)
        self.last_change = {
            "mesh_id": self.mesh_id,
            "estimate": float(ind.estimate),
            "bisections": int(change.bisections),
            "merges": int(change.merges),
            "dofs": int(new_problem.n),
        }
        return new_problem, z_new, d_new

    # -- checkpoint protocol -------------------------------------------------------------------
    def checkpoint_state(self) -> dict:
        return {
            "amesh": self.amesh.checkpoint_state(),
            "series": self.series.checkpoint_state(),
            "adaptations": int(self.adaptations),
            "transfer_failures": int(self.transfer_failures),
        }

    def restore_state(self, data: dict):
        """Rebuild the hierarchy and the series; returns the problem on the current mesh."""
        from ..io.mesh_series import MeshSeries

        self.amesh = AdaptiveMesh.restore_state(data["amesh"])
        self.series = MeshSeries.restore_state(data["series"])
        self.adaptations = int(data["adaptations"])
        self.transfer_failures = int(data["transfer_failures"])
        return self.problem_now()
