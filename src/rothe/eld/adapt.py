"""Space adaptivity of elastodynamics runs: the ELD side of the adapt cycle.

``run_eld(problem, ..., adapt=SpaceAdaptivity(...))`` adapts the mesh after every
``adapt_every``-th accepted step j that is not the last (SPEC Sec. 7, issue 8; the perturbation
view of Altmann 2015, Theorem 4.5 / Remark 4.2, with the transfer error as a perturbation of the
history). The stepper's adapt step (:meth:`rothe.eld.stepper.ELDStepper.adapt`) runs the shared
cycle :meth:`rothe.fem.adapt.cycle.MeshAdaptation.cycle` with an :class:`ELDAdaptivity` as the
family, whose "problem" is the :class:`~rothe.eld.system.ELDSystem` on the current mesh:

1. **estimate** (:meth:`ELDAdaptivity.indicators`): the residual indicators of the accepted step
   on its own mesh (:func:`rothe.eld.indicator.eld_indicators_for`: cell residual of the momentum
   equation with the scheme's acceleration a^j and velocity v^j, jumps of the normal stress
   sigma(u + b v) n across interior facets, traction mismatch on Neumann facets) with the
   reaction rho (alpha_0/tau_j)^2 of the step (alpha_0 = 1 Euler, 3/2 BDF2), plus the Dirichlet
   data term of the next step (:func:`dirichlet_data_indicator`);
2. **mark, refine/coarsen** (:class:`rothe.fem.adapt.SpaceAdaptivity`: Doerfler refinement
   while eta > space_tol, coarsening of the cells that carry a coarsen_fraction share,
   max_dofs); nothing changed -> nothing else happens (the run is the fixed-mesh run bit for
   bit);
3. **rebuild** (:meth:`ELDAdaptivity.rebuild`): the problem on the new mesh
   (:meth:`ELDProblem.on_mesh`) and a new system for it (:meth:`ELDSystem.rebuilt`: operators,
   constraint, lifting, solver with its counters continued, the first factorization);
4. **transfer** (:meth:`ELDAdaptivity.transfer`) of every history vector (u, v, a and the
   scheme's x, y, b with their t_{j-1} values, whatever BDF2 needs) by the nodal interpolation T
   of the adaptation layer (exact on refinement, an injection on coarsening), of the multiplier
   by the trace transfer. Regularized form: u_1 = u - B^- G with the new B^- (transferring u_1
   itself would carry the old mesh's lifting, docs/adaptivity.md); the current displacement,
   velocity and acceleration take the data on the new Dirichlet nodes, u^j|Gamma = G(t_j),
   v^j|Gamma = G_dot(t_j), a^j|Gamma = G_ddot(t_j) (exactly what the scheme has at the old
   nodes, so the constraint B u = G holds on the new boundary), the t_{j-1} history keeps its
   transferred trace. Original form: u^j|Gamma = G(t_j), the rest transferred. Then
   :meth:`ELDSystem.adopt`: the energy change E(T u) - E(u) is booked as ``transfer`` in the
   ledger, so the balance closes to round-off over the whole run.

Within a step (:meth:`rothe.eld.stepper.ELDStepper.step`): while the step's estimate on its own
mesh exceeds space_tol, the mesh is refined (the cycle with ``refine_only=True``: Doerfler, no
coarsening) and the step solved again from the previous state transferred to the refined mesh,
at most :data:`STEP_ROUNDS` times; a step rejected by the time controller goes back to its
previous state's mesh.

An adaptation after a step that fails (an exception, a non-finite estimate, field or energy) is
never accepted: the cycle rolls the mesh hierarchy back and the run stops with
:class:`~rothe.errors.RunFailed` (its result so far and a checkpoint on the last mesh remain).
A failed refinement within a step leaves the step as it was.

Bookkeeping (:class:`ELDMeshes`, the ``meshes`` of a run's result): every distinct mesh once in
``series`` (:class:`rothe.io.mesh_series.MeshSeries`); the kept fields u, v, a, lambda live on
different meshes and are kept in ``kept`` (lists, with ``kept_mesh_id`` in the trajectory),
written to ``trajectory.npz`` by :func:`rothe.eld.output.write_eld_result`; the log of
adaptations in ``adaptations``. The trajectory gets the point series ``mesh_id``, ``ndofs``,
``cells`` (the mesh each state was computed on) and the step series ``space_estimate`` (eta of
the step, NaN when not adapted after it), ``step_dofs`` (the dofs of every solve of the step
summed), ``step_refinements`` and ``step_bisections`` (the refinements inside the step and their
bisections). Checkpoints hold the mesh hierarchy, the series, the kept fields (with the cell
stresses and Gamma_D's dofs per mesh for the VTU series) and the log; a resumed run continues
bit for bit.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from ..errors import RunFailed, described, fail
from ..fem.adapt import SpaceAdaptivity, check_adaptable, free_transfer
from ..fem.adapt.cycle import (
    AdaptationFailed,
    MeshAdaptation,
    energy_or_fail,
    finite_or_fail,
    mesh_arrays_mapped,
    return_free_memory,
)
from ..fem.topology import cell_diameters
from ..io.mesh_series import MeshSeries
from .data import Points
from .indicator import eld_indicators_for
from .materials import pressure_wave_speed
from .stress import StressEvaluator

#: rebuilds reuse the element matrices of the cells an adaptation left unchanged
#: (:meth:`ELDAdaptivity.rebuild`)
INCREMENTAL = False
#: the kept fields (ragged across meshes); ``stress``: the cell-mean Cauchy stress, 9 per cell
KEPT = ("u", "v", "a", "lam", "stress")
#: refinements of a step's own mesh at most, each followed by solving the step again
STEP_ROUNDS = 6
#: a step (after the first) is refined and solved again only while its estimate exceeds
#: STEP_MARGIN * space_tol; between space_tol and that the adapt step after it refines the mesh
#: for the next steps (measured on the pulse, adapt_every 4, space_tol 2e-3: 1.3 makes 10
#: instead of 24 in-step refinements at the same error; 2 let the mesh lag the onset of the
#: pulse, the energy error grew 8-fold)
STEP_MARGIN = 1.3
#: the steps after a step whose estimate grew by more than this factor since the estimated step
#: before it are estimated (and refined) too, until it stops growing: a transient (the onset of
#: the pulse: adapt_every 4 left steps 2 and 3 on the initial mesh while the pulse grew, their
#: error stayed, 10 % in u(T) instead of 2.4 %)
STEP_GROWTH = 1.5


def dirichlet_data_indicator(problem, t: float) -> np.ndarray:
    """Squared data indicator per cell: sum over the Dirichlet facets F of the cell of
    h_F^{-1} ||G(t) - I_h G(t)||_{L2(F)}^2 (the energy of the lifted interpolation error of
    the data, a layer one cell wide: the perturbation of the data of Theorem 4.5 that the
    residual indicator does not see). Vectorized over the facets of each part;
    h_F = |F|^(1/(d-1))."""
    space = problem.space
    c = problem.constraint
    d = space.dim
    mesh = space.mesh
    out = np.zeros(mesh.t.shape[1])
    full = np.zeros((space.n_scalar, d))
    full[c.scalar_dofs] = problem.G(t).reshape(-1, d)
    for part, data in problem.dirichlet.items():
        facets = space.facets((part,), "dirichlet")
        if facets.size == 0:
            continue
        q = space.facet_quadrature((part,), intorder=2 * space.degree + 2, name="dirichlet")
        _, nf, nq = q.x.shape
        ih = np.stack([np.einsum("ifq,if->fq", q.values, full[q.dofs, k]) for k in range(d)])
        x = q.x.reshape(d, -1)
        g = np.asarray(data.G(float(t), x), dtype=float)
        g = np.broadcast_to(g.reshape(d, -1) if g.ndim > 1 else g[:, None], x.shape)
        err2 = np.sum((g.reshape(d, nf, nq) - ih) ** 2, axis=0)
        measure = q.dx.sum(axis=1)
        h = measure ** (1.0 / (d - 1)) if d > 2 else measure
        np.add.at(out, mesh.f2t[0, facets], (err2 * q.dx).sum(axis=1) / h)
    return out


def check_adapt(adapt, *, data, noise) -> SpaceAdaptivity:
    """``adapt`` must be a SpaceAdaptivity, the data :class:`~rothe.eld.data.Points` and no
    noise (one-line errors naming ``adapt``, ``data``, ``noise``)."""
    if not isinstance(adapt, SpaceAdaptivity):
        raise fail(
            "adapt",
            described(type(adapt).__name__),
            "must be a rothe.fem.adapt.SpaceAdaptivity (or None for a fixed mesh)",
        )
    if not isinstance(data, Points):
        raise fail(
            "data",
            data.name,
            "must be 'points' with space adaptivity (the data of t_j "
            "is re-evaluated on the new Dirichlet nodes after a mesh change)",
        )
    if noise is not None:
        raise fail(
            "noise",
            noise.describe() if hasattr(noise, "describe") else noise,
            "is not supported with space adaptivity (noise vectors live on one mesh)",
        )
    return adapt


@dataclass
class StepRounds:
    """What :meth:`ELDAdaptivity.refine_in_step` did in one step: the ``result`` of the last
    solve, the ``refinements`` of the step's own mesh (each followed by a solve), their
    ``bisections`` and the ``dofs`` of every solve summed."""

    result: object
    refinements: int = 0
    bisections: int = 0
    dofs: int = 0


class ELDMeshes:
    """The series of meshes of a space-adaptive run and what lives on them (module docstring).

    Attributes
    ----------
    series : MeshSeries
        Every distinct mesh once, by mesh id.
    kept : dict
        ``u``, ``v``, ``a``, ``lam``, ``stress``: lists of the kept states' fields, each on its
        own mesh (``kept_mesh_id`` of the trajectory; ``stress`` the cell-mean Cauchy stress,
        (n_cells, 3, 3) flattened).
    gamma_dofs : dict
        Mesh id -> the scalar dofs of Gamma_D on that mesh (lambda's rows).
    adaptations : list of dict
        Per adaptation after a step: step, t, from_mesh, to_mesh, estimate, rounds, bisections,
        merges, cells, ndofs, transfer_energy.
    degree, components : int
        The element (P``degree``, ``components`` fields).
    """

    def __init__(self, degree: int, components: int):
        self.degree = int(degree)
        self.components = int(components)
        self.series = MeshSeries()
        self.kept: dict[str, list] = {k: [] for k in KEPT}
        self.adaptations: list[dict] = []
        #: mesh id -> the scalar dofs of Gamma_D on it (the rows of the kept lambda)
        self.gamma_dofs: dict[int, np.ndarray] = {}

    def keep(self, traj, state, system=None) -> None:
        """Keep u, v, a, lambda of ``state`` (on its mesh) and record it in ``traj``; with the
        ``system`` of the state's mesh also its cell-mean Cauchy stresses (``stress``, 9 per
        cell, :class:`rothe.eld.stress.StressEvaluator`) and, once per mesh, the scalar dofs of
        Gamma_D (``gamma_dofs``, where lambda lives): what the VTU series writes."""
        traj.append(kept_step=state.j, kept_t=state.t, kept_mesh_id=state.mesh_id)
        for name, w in (
            ("u", state.u),
            ("v", state.v),
            ("a", state.fields["a"]),
            ("lam", state.lam),
        ):
            self.kept[name].append(np.array(w, dtype=float))
        if system is not None:
            problem = system.problem
            sigma = StressEvaluator(problem.space, problem.material).stress(state.u)
            self.kept["stress"].append(sigma.reshape(-1))
            mesh_id = int(state.mesh_id)
            if mesh_id not in self.gamma_dofs:
                self.gamma_dofs[mesh_id] = np.asarray(problem.constraint.scalar_dofs).copy()

    def npz_arrays(self, traj) -> dict:
        """The meshes (every distinct one once, ``MeshSeries.npz_arrays`` keyed by the kept
        states' mesh ids) and the kept fields as one concatenation per field with offsets:
        ``u[k] = kept_u[kept_u_offsets[k]:kept_u_offsets[k + 1]]`` on mesh ``kept_mesh_id[k]``
        (interleaved vector dofs of P``degree``; ``lam`` on that mesh's constrained dofs)."""
        ids = np.asarray(traj["kept_mesh_id"] if "kept_mesh_id" in traj else [], dtype=np.int64)
        out = self.series.npz_arrays(ids)
        for name in KEPT:
            parts = self.kept[name]
            sizes = np.array([w.size for w in parts], dtype=np.int64)
            out[f"kept_{name}"] = np.concatenate(parts) if parts else np.zeros(0)
            out[f"kept_{name}_offsets"] = np.concatenate([[0], np.cumsum(sizes)])
        out["degree"] = np.asarray(self.degree)
        out["dim"] = np.asarray(self.components)
        return out

    def checkpoint_state(self) -> dict:
        """The series, the kept fields and the log (arrays and plain values)."""
        return {
            "series": self.series.checkpoint_state(),
            "kept": {k: [w.copy() for w in v] for k, v in self.kept.items()},
            "adaptations": [dict(a) for a in self.adaptations],
            "gamma_dofs": {str(k): v.copy() for k, v in self.gamma_dofs.items()},
        }

    def restore_state(self, data: dict) -> None:
        """Put back what :meth:`checkpoint_state` returned."""
        self.series = MeshSeries.restore_state(data["series"])
        self.kept = {
            k: [np.asarray(w, dtype=float).copy() for w in data["kept"].get(k, [])] for k in KEPT
        }
        self.adaptations = [dict(a) for a in data["adaptations"]]
        self.gamma_dofs = {
            int(k): np.asarray(v, dtype=np.int64).copy()
            for k, v in (data.get("gamma_dofs") or {}).items()
        }


class ELDAdaptivity:
    """The adaptive mesh of one ELD run with its series of meshes, and the ELD side of the adapt
    cycle (module docstring): ``indicators``, ``rebuild``, ``transfer`` on
    :class:`~rothe.eld.system.ELDSystem` objects.

    Parameters
    ----------
    problem : ELDProblem
        The run's problem on its initial mesh (triangles or tetrahedra).
    options : SpaceAdaptivity
    scheme : Scheme
        Its alpha_0 for equal steps sets the reaction of the indicator.
    times : PhaseTimes
        Where the cycle's phases are timed (the stepper's).
    """

    def __init__(self, problem, options: SpaceAdaptivity, *, scheme, times):
        check_adaptable(problem.space.mesh, "adapt")
        # (a body of several materials adapts too: every cell's region is carried to its
        # children by the bisection forest, the indicator takes per-cell constants)
        self.options = options
        self.alpha0 = scheme.alpha0
        space = problem.space
        self.adaptation = MeshAdaptation(
            space.mesh, options, degree=space.degree, components=space.dim, times=times
        )
        self.meshes = ELDMeshes(space.degree, space.dim)
        self.meshes.series.add(0, space.mesh.p.T, space.mesh.t.T)
        #: c_p of the fastest material (the default band, :meth:`set_band`)
        self.wave_speed = pressure_wave_speed(problem.material)
        #: h_0 of the L2 weights h_K / h_0 (``options.norm == 'l2'``): the initial mesh's
        #: longest cell edge
        self.h0 = float(cell_diameters(np.asarray(space.mesh.p), np.asarray(space.mesh.t)).max())
        self._memo = None  # (key, weakref system, weakref state, eta) of the last indicators
        #: (eta of the last estimated step, eta of the estimated step before it): the final
        #: estimate of each step (0 before the first)
        self.estimates = (0.0, 0.0)
        self._estimated_step = None  # (j, t) of the state of the last estimate
        #: factorizations of systems built since the last record (the trajectory's statistics)
        self.pending_factorizations = 0
        #: rebuild incrementally (:meth:`rebuild`; False: every element matrix computed)
        self.incremental = INCREMENTAL

    @property
    def mesh_id(self) -> int:
        """The id of the current mesh."""
        return self.adaptation.mesh_id

    def register_mesh(self) -> None:
        """Add the current mesh to the series (once per id)."""
        amesh = self.adaptation.amesh
        self.meshes.series.add(amesh.mesh_id, amesh.points, amesh.cells)

    # -- the family's side of the cycle ----------------------------------------------------------
    def indicators(self, system, target) -> np.ndarray:
        """eta_K of the accepted step that ended at ``state`` on ``system``'s mesh, ``target``
        = (state, tau, times) (module docstring): the residual indicator with the reaction
        rho (alpha_0/tau)^2, plus the Dirichlet data term over the data times ``times`` (a
        float or a tuple: the step's own time and those of the steps until the next
        adaptation, :meth:`data_times`), eta_K^2 += max_{t in times} sum_{F in Gamma_D,
        F in K} h_F^{-1} ||G(t) - I_h G(t)||_F^2.

        The last result is remembered: the adapt step after a step whose own (in-step)
        estimate left the mesh as it was asks for the same indicators again and gets them
        without a second evaluation."""
        state, tau, times = target
        times = tuple(times) if isinstance(times, tuple | list) else (float(times),)
        key = (id(system), id(state), float(tau), times)
        memo = self._memo
        if memo is not None and memo[0] == key and memo[1]() is system and memo[2]() is state:
            return memo[3]
        problem = system.problem
        f = state.fields
        rho = problem.material.rho
        ind = eld_indicators_for(
            problem, state.t, f["u"], f["v"], f["a"], reaction=rho * (self.alpha0 / tau) ** 2
        )
        data = dirichlet_data_indicator(problem, times[0])
        for t in times[1:]:
            data = np.maximum(data, dirichlet_data_indicator(problem, t))
        eta = np.sqrt(np.asarray(ind.eta, dtype=float) ** 2 + data)
        if self.options.norm == "l2":
            # the L2 norm of u by duality: eta_K h_K / h_0 (SpaceAdaptivity.norm)
            mesh = problem.space.mesh
            eta = eta * (cell_diameters(np.asarray(mesh.p), np.asarray(mesh.t)) / self.h0)
        if not np.all(np.isfinite(eta)):  # the run stops naming it (ELDStepper.adapt)
            raise FloatingPointError("non-finite error indicators")
        # weak references: the memo must not keep the system of a mesh the run has left alive
        # (its matrices and solver are most of a mesh's memory: the old system stayed until
        # the next estimate, next to the new one, at the peak of an adaptive 3D run)
        self._memo = (key, weakref.ref(system), weakref.ref(state), eta)
        value = float(np.sqrt(np.sum(eta * eta)))
        step = (int(state.j), float(state.t))
        if step == self._estimated_step:  # the same step again (a round or the adapt step)
            self.estimates = (value, self.estimates[1])
        else:
            self.estimates = (value, self.estimates[0])
            self._estimated_step = step
        return eta

    def data_times(self, t: float, tau: float, T: float) -> tuple:
        """The times whose Dirichlet data the mesh adapted after the step ending at ``t`` must
        resolve: t_j = t and t_j + i tau for i = 1, ..., adapt_every (the steps until the next
        adaptation), clipped to T, each once."""
        out = [float(t)]
        for i in range(1, self.options.adapt_every + 1):
            ti = min(t + i * tau, T)
            if ti > out[-1]:
                out.append(ti)
        return tuple(out)

    def set_band(self, tau: float) -> None:
        """The refinement band of the next cycle: ``refine_band`` if the options give one,
        else the distance the fastest wave travels until the next adaptation,
        c_p tau adapt_every with c_p = sqrt((lam + 2 mu)/rho) (:func:`pressure_wave_speed`)."""
        band = self.options.refine_band
        if band is None:
            band = self.wave_speed * tau * self.options.adapt_every
        self.adaptation.refine_band = float(band)

    def after_step(
        self, current, state, result, T: float, *, finished: bool, where, ndofs, transfer
    ):
        """The adapt step after the accepted ``result`` (the one copy of
        :meth:`rothe.eld.stepper.ELDStepper.adapt` and
        :meth:`rothe.eld.coupled_run.CoupledStepper.adapt`): when due and the run goes on,
        the cycle on ``current`` (what lives on the state's mesh) with the data times and band
        of the step; on a change the new mesh registered and the adaptation logged, with
        ``ndofs(out)`` unknowns and ``transfer(new_state)`` the energy the transfer moved.
        Returns (the cycle's outcome or None, the estimate or NaN). A failed adaptation (the
        cycle rolled back) raises :class:`~rothe.errors.RunFailed` naming the step; ``where()``
        gives its place."""
        self.register_mesh()
        if not self.options.due(state.j) or finished:
            return None, np.nan
        old_id = int(state.mesh_id)
        times = self.data_times(state.t, result.tau, T)
        self.set_band(result.tau)
        try:
            out = self.adaptation.cycle(self, current, (state, result.tau, times), state)
        except AdaptationFailed as exc:
            raise RunFailed(
                f"space adaptivity: the transfer to the new mesh after step "
                f"{state.j} (t = {state.t:.6g}) failed ({exc}); the run stops "
                f"on mesh {old_id}",
                where=where(),
            ) from exc
        if out.changed:
            self.register_mesh()
            self.meshes.adaptations.append(
                {
                    "step": state.j,
                    "t": float(state.t),
                    "from_mesh": old_id,
                    "to_mesh": int(out.state.mesh_id),
                    "estimate": out.estimate,
                    "rounds": 1,
                    "bisections": out.bisections,
                    "merges": out.merges,
                    "cells": int(self.adaptation.amesh.n_cells),
                    "ndofs": int(ndofs(out)),
                    "transfer_energy": float(transfer(out.state)),
                }
            )
        return out, out.estimate

    def due_in_step(self, j: int) -> bool:
        """Whether the step from state number ``j`` is estimated on its own mesh (and refined
        and solved again while its estimate exceeds :meth:`refine_above`): the first step,
        whose data meet the initial mesh, every step after which an adaptation is due
        (:meth:`SpaceAdaptivity.due`), and every step while the last estimate was above
        STEP_MARGIN space_tol or grew by more than :data:`STEP_GROWTH` since the estimate
        before it (the mesh lags, or a transient: a boundary pulse building up a wave); the
        other steps run on the mesh as it is."""
        last, before = self.estimates
        return (
            j == 0
            or self.options.due(j + 1)
            or last > STEP_MARGIN * self.options.space_tol
            or last > STEP_GROWTH * before
        )

    def refine_in_step(
        self,
        current,
        state,
        result,
        tau: float,
        T: float,
        *,
        attempt,
        remember,
        adopt,
        failed,
        ndofs,
        check=None,
    ) -> StepRounds:
        """The refinement rounds inside one step (module docstring, *Within a step*), the one
        copy of :meth:`rothe.eld.stepper.ELDStepper.step`'s and
        :meth:`rothe.eld.coupled_run.CoupledStepper.step`'s: when the step from ``state``
        (number j) is estimated on its own mesh (:meth:`due_in_step`), while the estimate eta
        of its ``result`` exceeds :meth:`refine_above` (space_tol on the first step,
        :data:`STEP_MARGIN` space_tol after) the mesh is refined (the cycle on ``current``
        with ``refine_only``: Doerfler, no coarsening, the band of the step) and the step
        solved again from ``state`` transferred to the refined mesh, at most
        :data:`STEP_ROUNDS` times; a failed estimate or transfer leaves the step as it was.

        The stepper's side, as callables: ``attempt(state)`` solves the step from ``state``
        on the current mesh; ``remember()`` (before each cycle) what the stepper needs to go
        back to the step's start mesh if the step is rejected -- handed to ``adopt(out,
        remembered)`` after a change, which binds the stepper to ``out``'s mesh and returns
        what lives on it (the next cycle's ``current``); ``failed()`` after a failed cycle
        (the stepper stays on the mesh it solved the step on); ``ndofs(current)`` the
        unknowns of a solve; ``check()`` between the rounds
        (:func:`rothe.stepping.interrupt.check` where the stepper can abandon a step).

        Returns the last solve's result with the rounds' counts (:class:`StepRounds`)."""
        check = check or (lambda: None)
        adaptation = self.adaptation
        above = self.refine_above(state.j)
        rounds = STEP_ROUNDS if self.due_in_step(state.j) else 0
        if rounds:
            self.set_band(tau)
        done = StepRounds(result, dofs=int(ndofs(current)))
        for _ in range(rounds):
            if not result.converged or result.state is None:
                break
            check()
            remembered = remember()
            times = self.data_times(result.state.t, tau, T)
            try:
                out = adaptation.cycle(
                    self,
                    current,
                    (result.state, tau, times),
                    state,
                    refine_only=True,
                    refine_above=above,
                )
            except AdaptationFailed:  # no estimate or no transfer: the step stands
                failed()
                break
            if not out.changed:
                break
            current, state = adopt(out, remembered), out.state
            check()  # (an abandoning stepper goes back to the mesh of the original state)
            done.refinements += 1
            done.bisections += out.bisections
            result = done.result = attempt(state)
            done.dofs += int(ndofs(current))
        return done

    def refine_above(self, j: int) -> float:
        """The estimate above which the step from state ``j`` is refined and solved again:
        space_tol on the first step, :data:`STEP_MARGIN` times it after."""
        return self.options.space_tol * (1.0 if j == 0 else STEP_MARGIN)

    def rebuild(self, system, mesh):
        """The system of the same problem on ``mesh`` (counters continued; its first
        factorization is counted in :attr:`pending_factorizations`), factored by SuperLU in its
        symmetric mode (:class:`rothe.eld.solvers.ReferenceSolver`: 40 % less time per
        mesh; the initial mesh keeps the default mode, so a run whose mesh never changes is the
        fixed-mesh run bit for bit).

        ``system`` is released first (:meth:`ELDSystem.release`: its matrices and solver go,
        what the transfer and the record of its step need stays): one mesh's system lives at
        a time, and the rebuild of a large mesh no longer comes on top of the previous one's
        (the peak of an adaptive 3D run, docs/adaptivity.md). Going back to it (a stop
        signal, a failed transfer, a rejected step after in-step refinements) revives it."""
        system.release()
        return_free_memory()  # the peak of an adaptive 3D run is the rebuild's (docs)
        change = self.adaptation.change
        source = None
        if change is not None and self.incremental and len(change.unchanged) == mesh.t.shape[1]:
            # incremental: the element matrices of the cells that did not change are reused
            source = np.where(change.unchanged, change.old_start, -1)
        with mesh_arrays_mapped():  # released with the mesh, they leave no holes in the heap
            problem = system.problem.on_mesh(mesh, source, keep=self.incremental)
            new = system.rebuilt(problem, symmetric_lu=True, short_lived=True)
        new.owns_problem = True
        self.pending_factorizations += new.initial_factorizations
        return new

    def transfer(self, state, change, system, new_system):
        """``state`` on ``new_system``'s mesh (module docstring, step 4): every field through
        the transfer T, the boundary vectors through its trace part, the data of t_j on the new
        Dirichlet nodes, the regularized unknowns split by the new lifting, then adopted."""
        ms = self.meshes
        problem, new_problem = system.problem, new_system.problem
        T = change.transfer(ms.degree, ms.components)
        T_gamma = free_transfer(T, problem.constraint.dofs, new_problem.constraint.dofs)
        mapped = state.mapped(T, T_gamma)
        f = mapped.fields
        C = new_problem.constraint.dofs
        t = state.t
        lift = new_system.lifting
        if lift is not None:
            for name, g in (
                ("u", new_problem.G(t)),
                ("v", new_problem.G_dot(t)),
                ("a", new_problem.G_ddot(t)),
            ):
                f[name][C] = g
        else:
            f["u"][C] = new_problem.G(t)
            f["x"] = f["u"].copy()
        for name, w in list(f.items()) + list(mapped.boundary.items()):
            finite_or_fail(name, w)
        mapped.mesh_id = self.mesh_id
        if lift is not None:
            for full, name in (("u", "x"), ("v", "y"), ("a", "b"), ("u_1", "x_1"), ("v_1", "y_1")):
                if full in f:
                    g = f[full][C].copy()
                    w = f[full] - lift(g)
                    w[C] = 0.0
                    f[name] = w
                    f[full] = w + lift(g)
        new = new_system.adopt(mapped)
        energy_or_fail(new.ledger.energy)
        return new

    # -- checkpoints ----------------------------------------------------------------------------
    def checkpoint_state(self) -> dict:
        """The mesh hierarchy, the vertex history of the hysteresis (``coarsen_delay``,
        ``max_recoarsen``: it decides which cells may coarsen, so a resumed run needs it), the
        series, the kept fields and the log."""
        return {
            **self.adaptation.checkpoint_state(),
            **self.meshes.checkpoint_state(),
            # the last estimates decide which steps refine in their rounds (due_in_step)
            "step_estimates": [float(e) for e in self.estimates],
            "estimated_step": None if self._estimated_step is None else list(self._estimated_step),
        }

    def restore_state(self, data: dict) -> None:
        """Put back what :meth:`checkpoint_state` returned (a checkpoint without the vertex
        history counts the mesh's vertices as initial; one without the last estimates takes
        them as none)."""
        self.adaptation.restore_state(data)
        self.meshes.restore_state(data)
        last, before = data.get("step_estimates", (0.0, 0.0))
        self.estimates = (float(last), float(before))
        step = data.get("estimated_step")
        self._estimated_step = None if step is None else (int(step[0]), float(step[1]))
