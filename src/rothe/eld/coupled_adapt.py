"""Space adaptivity of coupled runs: ``run_coupled(..., adapt=SpaceAdaptivity(...))`` (issue 19).

The elastic body of a :class:`~rothe.eld.coupling.CoupledProblem` (the *base* of glued bodies)
adapts its mesh after every ``adapt_every``-th accepted step that is not the last, with the
explicit adapt step of :func:`~rothe.eld.run.run_eld` and its objects: the shared cycle
:meth:`rothe.fem.adapt.cycle.MeshAdaptation.cycle` with :class:`CoupledAdaptivity` -- an
:class:`~rothe.eld.adapt.ELDAdaptivity` (its indicators, band, data times, series of meshes,
log of adaptations) whose rebuild and transfer act on the coupled system:

1. **estimate**: the body's residual indicators of the accepted step with the reaction
   rho (alpha_0/tau)^2 and the Dirichlet data term of the prescribed parts
   (:meth:`ELDAdaptivity.indicators`; the coupled parts are Dirichlet facets of the body, their
   data G(t, q) affine in x for the ready-made couplings: interpolated exactly);
2. **mark, refine/coarsen**: :class:`~rothe.fem.adapt.SpaceAdaptivity` (the same options);
3. **rebuild** (:meth:`CoupledAdaptivity.rebuild`): what lives on the mesh -- the body's M, K,
   C and constraint (:meth:`CoupledProblem.on_mesh`), the couplings' Gamma (the glue of two
   bodies: its interface, :meth:`rothe.eld.bodies.Glue.on_mesh`), the controllers' sensor rows,
   and a new :class:`~rothe.eld.coupled_step.CoupledStepSystem` (lifting, Phi = L Gamma, its
   factorization cache: the first step on the new mesh factors);
4. **transfer** (:meth:`rothe.eld.coupled_run.CoupledStepper.transferred`): u, v, a and the
   t_{j-1} history of u, v by the nodal interpolation T of the adaptation layer (exact on
   refinement, an injection on coarsening), lambda by its trace part; q, p, pdot, z (the
   components' and controllers' states) do not live on the mesh and carry over unchanged. The
   trace of t_j is re-evaluated from the data and q: u^j|Gamma = g_k(t_j) + Gamma q^j,
   v^j|Gamma = g'_k + Gamma p^j, a^j|Gamma = g''_k + Gamma pdot^j, so B u = G(t, q) holds on
   the new boundary -- in the original form too, whose differenced boundary velocity thereby
   restarts from the data's derivative as at t = 0 (the quotient of the step before lags by
   tau_{j-1} G''/2 under implicit Euler, which the first, shorter step on the new mesh turned
   into an acceleration ~ tau_{j-1}/tau: an estimate no step size brought below tol); the
   scheme's x, y (and the traces g_k, g'_k of the history) are split off the transferred u, v
   by the new lifting. The body's energy change E(T u) - E(u) is booked as
   ``transfer`` in the whole-system ledger, which therefore closes to round-off over the run.

**Checkpoints** (``run_coupled(..., checkpoint=...)``): the mesh hierarchy, the series of
meshes, the log and the hysteresis' vertex history (:meth:`ELDAdaptivity.checkpoint_state`,
as for run_eld); the resumed stepper rebuilds the system
on the restored mesh (:meth:`CoupledAdaptivity.rebuild` from the initial system:
:meth:`CoupledProblem.on_mesh` assembles from the mesh alone, so it is the system the run had).

**Within a step** (:meth:`rothe.eld.coupled_run.CoupledStepper.step`): the refinement rounds
of run_eld, the one copy :meth:`ELDAdaptivity.refine_in_step` -- while the step's estimate on
its own mesh exceeds space_tol (1.3 space_tol after the first step) the body's mesh is refined
(Doerfler, no coarsening) and the step solved again from its start state transferred to the
refined mesh (steps 3-4: q, p, z unchanged, the body's energy change booked as ``transfer``
in the start state's ledger), at most 6 times; a step the controller rejects goes back to its
start state's mesh. The trajectory's ``step_refinements``, ``step_bisections``, ``step_dofs``
count them.

**Fields** (``fields=True``): every accepted state's u, v, a, lambda and cell stresses are
kept on the mesh it was computed on (:meth:`ELDMeshes.keep`, as run_eld keeps its states),
what the ParaView series of an adaptive body is written from
(:func:`rothe.eld.bodies_output.write_bodies_result`).

Not here (yet): ``watch`` rows recorded per state (they live on the mesh), noise (Theorem
4.5's study runs on a fixed mesh). A body of several materials adapts like one (its
regions are carried to the refined cells, the indicator takes per-cell constants).
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import described, fail
from .adapt import ELDAdaptivity
from .coupled_step import CoupledStepSystem


@dataclass
class CoupledMesh:
    """What lives on one mesh of a coupled run: the system on it and its step algebra.
    ``problem`` (the body) is what :meth:`ELDAdaptivity.indicators` estimates on."""

    system: object  # CoupledProblem
    kern: CoupledStepSystem

    @property
    def problem(self):
        return self.system.body


class CoupledAdaptivity(ELDAdaptivity):
    """The adaptive mesh of a coupled run's body (module docstring): the ELD family of the
    adapt cycle with the coupled system's rebuild and the stepper's transfer.

    Parameters
    ----------
    stepper : CoupledStepper
        The run's stepper: it owns the state layout and the mesh it is bound to.
    options : SpaceAdaptivity
    """

    def __init__(self, stepper, options):
        super().__init__(stepper.body, options, scheme=stepper.scheme, times=stepper.times)
        self.stepper = stepper

    def rebuild(self, current: CoupledMesh, mesh) -> CoupledMesh:
        """The coupled system on ``mesh`` and its step algebra (module docstring, step 3)."""
        system = current.system.on_mesh(mesh)
        return CoupledMesh(system, CoupledStepSystem(system, self.stepper.lifting))

    def transfer(self, state, change, current: CoupledMesh, new: CoupledMesh):
        """``state`` on the new mesh (module docstring, step 4); the stepper is bound to the new
        mesh on success and stays on the old one if the transfer fails."""
        ms = self.meshes
        T = change.transfer(ms.degree, ms.components)
        out = self.stepper.transferred(state, T, current, new)
        out.mesh_id = self.mesh_id
        return out


def check_coupled_adapt(adapt, *, watch, noise) -> None:
    """What a space-adaptive coupled run does not take yet (one line naming the keyword):
    ``watch`` rows and ``noise`` live on one mesh (``fields`` are kept on their meshes)."""
    for name, value, why in (
        ("watch", watch, "rows of u on one mesh"),
        ("noise", noise, "the perturbation study runs on a fixed mesh"),
    ):
        if adapt is not None and value is not None:
            raise fail(name, described("given"), f"is not supported with space adaptivity ({why})")
