"""Space adaptivity of elastodynamics runs: a new mesh after every k-th accepted step.

``run_eld(problem, ..., space=SpaceAdaptivity(...))`` drives a :class:`SpaceAdaptiveStepper`
on the shared evolve loop. It wraps the :class:`~rothe.eld.schemes.ELDStepper` of the current
mesh (which does the steps) and, after every ``adapt_every``-th accepted step j that is not
the last, adapts the mesh (SPEC Sec. 7, issue 8; the perturbation view of Altmann 2015,
Theorem 4.5 / Remark 4.2, with the transfer error as a perturbation of the history):

1. **indicators** of the accepted step on its own mesh (:func:`rothe.eld.indicator.
   eld_indicators_for`, the residual estimator: cell residual of the momentum equation with the
   scheme's acceleration a^j and velocity v^j, jumps of the normal stress sigma(u + b v) n across
   interior facets, traction mismatch on Neumann facets), with the reaction rho (alpha_0/tau_j)^2
   of the step (alpha_0 = 1 Euler, 3/2 BDF2);
2. **marking and adaptation** (:func:`rothe.fem.adapt.adapt_mesh`: Doerfler refinement while
   eta > space_tol, coarsening of the cells that carry a coarsen_fraction share, max_dofs);
   nothing changed -> nothing else happens (the run is the fixed-mesh run bit for bit);
3. **transfer** of every history vector (u, v, a and the scheme's x, y, b with their t_{j-1}
   values, whatever BDF2 needs) by the nodal interpolation T of the adaptation layer (exact on
   refinement, an injection on coarsening), of the multiplier by the trace transfer;
4. a **new problem and stepper** on the new mesh (:meth:`ELDProblem.on_mesh`; the stepper's
   constructor re-checks the step bound tau < rho/d0 of Lemma 3.2). Regularized form: the
   lifting is rebuilt, u_1 = u - B^- G with the new B^- (transferring u_1 itself would carry the
   old mesh's lifting, docs/adaptivity.md); the current displacement, velocity and acceleration
   take the data on the new Dirichlet nodes, u^j|Gamma = G(t_j), v^j|Gamma = G_dot(t_j),
   a^j|Gamma = G_ddot(t_j) (exactly what the scheme has at the old nodes, so the constraint
   B u = G holds on the new boundary), the t_{j-1} history keeps its transferred trace.
   Original form: u^j|Gamma = G(t_j), the rest transferred;
5. :meth:`ELDStepper.adopt`: the energy change E(T u) - E(u) is booked as ``transfer`` in the
   ledger, so the balance closes to round-off over the whole run.

Within a step (:meth:`SpaceAdaptiveStepper.step`): while the step's estimate on its own mesh
exceeds space_tol, the mesh is refined (Doerfler, no coarsening) and the step solved again from
the previous state transferred to the refined mesh, at most :data:`STEP_ROUNDS` times; a step
rejected by the time controller goes back to its previous state's mesh.

A transfer that fails (an exception, a non-finite field or energy) is never accepted: the mesh
hierarchy is rolled back and the run stops with :class:`~rothe.errors.RunFailed` (its result
so far and a checkpoint on the last mesh remain).

Because the evolve loop has no hook after acceptance, the adaptation runs in :meth:`record`
(called once per accepted step) and replaces the accepted state's contents in place (the loop
holds that object); a step is always computed, estimated and recorded on the mesh it was
computed on, and the transfer's energy appears in the ledger of the next step.

Bookkeeping: point series ``mesh_id``, ``ndofs``, ``cells`` (the mesh each state was computed
on), step series ``space_estimate`` (eta of the step, NaN when not adapted after it), ``step_dofs``
(the dofs of every solve of the step summed), ``step_refinements``; every
distinct mesh once in :attr:`series` (:class:`rothe.io.mesh_series.MeshSeries`); the kept
fields u, v, a, lambda live on different meshes and are kept in :attr:`kept` (lists, with
``kept_mesh_id`` in the trajectory), written to ``trajectory.npz`` by
:func:`rothe.eld.output.write_eld_result`. Checkpoints hold the inner stepper's state, the
mesh hierarchy, the mesh series and the kept fields; a resumed run continues bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import fields as dataclass_fields
from dataclasses import replace

import numpy as np

from ..errors import RotheInputError, RunFailed, described, fail
from ..fem.adapt import (
    AdaptiveMesh,
    SpaceAdaptivity,
    adapt_mesh,
    check_adaptable,
    doerfler_marking,
    free_transfer,
)
from ..io.mesh_series import MeshSeries
from .schemes import ELDState, ELDStepper

#: the kept fields (ragged across meshes)
KEPT = ("u", "v", "a", "lam")
#: adaptation rounds after a step at most: the first refines and coarsens, the others refine
#: while the estimate on the new mesh is above space_tol
REFINE_ROUNDS = 1
#: refinements of a step's own mesh at most, each followed by solving the step again
STEP_ROUNDS = 3


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


def check_space_options(space, *, data: str, noise, form: str) -> SpaceAdaptivity:
    """``space`` must be a SpaceAdaptivity; data 'points' and no noise (one-line errors)."""
    if not isinstance(space, SpaceAdaptivity):
        raise fail(
            "space",
            described(type(space).__name__),
            "must be a rothe.fem.adapt.SpaceAdaptivity (or None for a fixed mesh)",
        )
    if data != "points":
        raise fail(
            "data",
            data,
            "must be 'points' with space adaptivity (the data of t_j is "
            "re-evaluated on the new Dirichlet nodes after a mesh change)",
        )
    if noise is not None:
        raise fail(
            "noise",
            noise.describe() if hasattr(noise, "describe") else noise,
            "is not supported with space adaptivity (noise vectors live on one mesh)",
        )
    return space


class SpaceAdaptiveStepper:
    """An :class:`ELDStepper` on a mesh that changes between steps (module docstring).

    Parameters
    ----------
    problem : ELDProblem on a triangle or tetrahedron mesh (the initial mesh)
    options : SpaceAdaptivity
    stepper_kwargs : the arguments of ELDStepper after ``problem`` (form, tau, scheme, ...)
    """

    def __init__(self, problem, options: SpaceAdaptivity, stepper_kwargs: dict):
        check_adaptable(problem.space.mesh, "--adapt-space" if options.naming == "cli" else "space")
        self.options = options
        kwargs = dict(stepper_kwargs)
        self.store_fields = bool(kwargs.pop("store_fields", True))
        self.keep_every = int(kwargs.get("keep_every", 1))
        self.observer = kwargs.pop("observer", None)
        self.kwargs = kwargs
        self.problem = problem
        self.inner = ELDStepper(problem, store_fields=False, **kwargs)
        self.keep_every = self.inner.keep_every
        self.amesh = AdaptiveMesh(problem.space.mesh)
        self.degree, self.components = problem.space.degree, problem.space.dim
        options.check_mesh(self.amesh, self.degree, self.components)
        self.series = MeshSeries()
        mesh = problem.space.mesh
        self.series.add(0, mesh.p.T, mesh.t.T)
        self.kept: dict[str, list] = {k: [] for k in KEPT}
        self.adaptations: list[dict] = []
        self._pending_factorizations = 0
        self._base = None  # (state, mesh hierarchy, problem, stepper) before in-step refinement
        self._step_refinements = 0

    # -- delegation to the stepper of the current mesh --------------------------------------------
    def __getattr__(self, name):
        # only reached for attributes not defined here: scheme, form, order, max_ratio, tau,
        # n_steps, steps, kind, solver, error_scale, bound, T, ...
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)

    def max_step(self, tau_prev):
        return self.inner.max_step(tau_prev)

    def finished(self, state) -> bool:
        return self.inner.finished(state)

    def limit(self, state, tau):
        return self.inner.limit(state, tau)

    def overshoot(self, state, attempts):
        return self.inner.overshoot(state, attempts)

    def pick_landing(self, state, attempts):
        return self.inner.pick_landing(state, attempts)

    def where(self, state, result=None) -> dict:
        info = self.inner.where(state, result)
        info["mesh_id"] = int(state.mesh_id)
        return info

    def progress_fields(self, state) -> dict:
        out = self.inner.progress_fields(state)
        out["dofs"] = self.problem.space.ndofs
        return out

    def step(self, state, tau, s_end=None):
        """One step; while its estimate on its mesh exceeds space_tol, the mesh is refined
        (Doerfler, no coarsening) and the step is solved again from the previous state
        transferred to the refined mesh, at most :data:`STEP_ROUNDS` times (the
        solve-estimate-mark-refine loop of the step: a wave that enters a coarse region, or
        the data of a boundary pulse, is resolved in the step that creates it). The result is
        that of the last solve; ``result.counters['dofs']`` sums the dofs of every solve."""
        self._restore_base(state)
        original = state
        result = self.inner.step(state, tau, s_end)
        dofs = self.problem.space.ndofs
        opts = self.options
        for _ in range(STEP_ROUNDS):
            if not result.converged or result.state is None:
                break
            try:
                eta = self.indicators(self.problem, result.state, tau, result.state.t)
            except Exception:  # noqa: BLE001 - no estimate, no refinement: the step stands
                break
            if not np.all(np.isfinite(eta)) or np.sqrt(np.sum(eta * eta)) <= opts.space_tol:
                break
            base = self._base
            if base is None or base[0] is not original:
                base = (original, self.amesh.checkpoint_state(), self.problem, self.inner)
            before = self.amesh.checkpoint_state() if self._step_refinements else base[1]
            try:
                change = self.amesh.adapt(
                    refine=doerfler_marking(eta, opts.refine_fraction),
                    max_dofs=opts.max_dofs,
                    degree=self.degree,
                    components=self.components,
                    priority=eta,
                    max_level=opts.max_level,
                )
                if not change.changed:
                    break
                problem = self.problem.on_mesh(self.amesh.mesh)
                mapped = self._map(state, change, self.problem, problem)
                inner, moved = self._new_stepper(problem, mapped)
            except Exception:  # noqa: BLE001 - a failed transfer is not used: the step stands
                self.amesh = AdaptiveMesh.restore_state(before)
                break
            self._base = base
            self.problem, self.inner, state = problem, inner, moved
            self._step_refinements += 1
            result = self.inner.step(state, tau, s_end)
            dofs += problem.space.ndofs
        result.counters["dofs"] = dofs
        return result

    def _restore_base(self, state) -> None:
        """A step retried (rejected by the time controller) from a state whose mesh was refined
        during the rejected attempt: back to that state's mesh and stepper."""
        base = self._base
        if base is not None and base[0] is state and state.mesh_id != self.amesh.mesh_id:
            self.amesh = AdaptiveMesh.restore_state(base[1])
            self.problem, self.inner = base[2], base[3]
            self._step_refinements = 0  # counted for the attempt that is accepted

    def initial_state(self) -> ELDState:
        return self.inner.initial_state()

    # -- recording and adaptation ---------------------------------------------------------------
    def _mesh_record(self, state) -> dict:
        return {
            "mesh_id": int(state.mesh_id),
            "ndofs": int(self.problem.space.ndofs),
            "cells": int(self.problem.space.mesh.t.shape[1]),
        }

    def _keep(self, traj, state) -> None:
        traj.append(kept_step=state.j, kept_t=state.t, kept_mesh_id=state.mesh_id)
        for name, w in (
            ("u", state.u),
            ("v", state.v),
            ("a", state.fields["a"]),
            ("lam", state.lam),
        ):
            self.kept[name].append(np.array(w, dtype=float))

    def record_initial(self, traj, state) -> None:
        self.inner.record_initial(traj, state)
        traj.append(**self._mesh_record(state))
        if self.store_fields:
            self._keep(traj, state)

    def adapt(self, state, result):
        """The evolve loop's adapt step; the adaptation itself still runs in :meth:`record`."""
        return state

    def record(self, traj, result, state=None) -> None:
        st = result.state
        self._base = None  # accepted: the state's mesh is the current one
        self.series.add(st.mesh_id, self.amesh.points, self.amesh.cells)
        self.inner.record(traj, result)
        traj.append(**self._mesh_record(st))
        traj.append(
            step_dofs=int(result.counters.get("dofs", self.problem.space.ndofs)),
            step_refinements=self._step_refinements,
        )
        self._step_refinements = 0
        if self.store_fields and (st.j % self.keep_every == 0 or self.inner.finished(st)):
            self._keep(traj, st)
        if self.observer is not None:
            self.observer(st, result)
        estimate = math.nan
        if self.options.due(st.j) and not self.inner.finished(st):
            estimate = self._adapt(st, result.tau)
        traj.append(space_estimate=estimate)
        if self._pending_factorizations:
            traj.stats.linear_factorizations += self._pending_factorizations
            self._pending_factorizations = 0

    def indicators(self, problem, state, tau: float, t_next: float) -> np.ndarray:
        """eta_K of the accepted step that ended at ``state`` on ``problem``'s mesh (module
        docstring): the residual indicator with the reaction rho (alpha_0/tau)^2, plus the
        Dirichlet data term of the next step, eta_K^2 += sum_{F in Gamma_D, F in K}
        h_F^{-1} ||G(t_next) - I_h G(t_next)||_F^2 (:func:`dirichlet_data_indicator`)."""
        from .indicator import eld_indicators_for

        f = state.fields
        a0 = 1.0 if self.inner.scheme == "euler" else 1.5
        rho = problem.material.rho
        ind = eld_indicators_for(
            problem, state.t, f["u"], f["v"], f["a"], reaction=rho * (a0 / tau) ** 2
        )
        eta2 = np.asarray(ind.eta, dtype=float) ** 2 + dirichlet_data_indicator(problem, t_next)
        return np.sqrt(eta2)

    def _adapt(self, state: ELDState, tau: float) -> float:
        """Adapt after the accepted ``state``; replaces its contents in place when the mesh
        changed. Returns the estimate eta of the step on its own mesh.

        Round 1 marks by :meth:`SpaceAdaptivity.mark` (refine and coarsen); while the estimate
        of the transferred state on the new mesh is still above space_tol, up to
        :data:`REFINE_ROUNDS` - 1 more rounds refine only (a front that moved by more than a
        cell per step is caught up at once instead of one bisection per step)."""
        j = state.j
        t_next = min(state.t + tau, self.inner.T)
        opts = self.options
        snapshot = self.amesh.checkpoint_state()
        old_id = int(state.mesh_id)
        estimate = math.nan
        try:
            problem, work, changes = self.problem, state, []
            for r in range(REFINE_ROUNDS):
                eta = self.indicators(problem, work, tau, t_next)
                if not np.all(np.isfinite(eta)):
                    raise FloatingPointError("non-finite error indicators")
                est = float(np.sqrt(np.sum(eta * eta)))
                if r == 0:
                    estimate = est
                    change = adapt_mesh(
                        self.amesh, eta, opts, degree=self.degree, components=self.components
                    )
                else:
                    if est <= opts.space_tol:
                        break
                    change = self.amesh.adapt(
                        refine=doerfler_marking(eta, opts.refine_fraction),
                        max_dofs=opts.max_dofs,
                        degree=self.degree,
                        components=self.components,
                        priority=eta,
                        max_level=opts.max_level,
                    )
                if not change.changed:
                    break
                new_problem = problem.on_mesh(self.amesh.mesh)
                work = self._map(work, change, problem, new_problem)
                problem = new_problem
                changes.append(change)
            if not changes:
                return estimate
            inner, new_state = self._new_stepper(problem, work)
        except Exception as exc:  # noqa: BLE001 - a failed transfer is never accepted
            self.amesh = AdaptiveMesh.restore_state(snapshot)
            if isinstance(exc, RotheInputError) and not isinstance(exc, RunFailed):
                detail = str(exc)
            else:
                detail = f"{type(exc).__name__}: {exc}"
            raise RunFailed(
                f"space adaptivity: the transfer to the new mesh after step {j} "
                f"(t = {state.t:.6g}) failed ({detail}); the run stops on mesh "
                f"{old_id}",
                where=self.where(state),
            ) from exc
        old_energy = state.ledger.energy
        # the accepted step stays what it was; the loop holds `state`: take over the new contents
        for fld in dataclass_fields(ELDState):
            setattr(state, fld.name, getattr(new_state, fld.name))
        self.series.add(self.amesh.mesh_id, self.amesh.points, self.amesh.cells)
        self.problem, self.inner = problem, inner
        self.adaptations.append(
            {
                "step": j,
                "t": float(state.t),
                "from_mesh": old_id,
                "to_mesh": int(state.mesh_id),
                "estimate": estimate,
                "rounds": len(changes),
                "bisections": int(sum(c.bisections for c in changes)),
                "merges": int(sum(c.merges for c in changes)),
                "cells": int(self.amesh.n_cells),
                "ndofs": int(problem.space.ndofs),
                "transfer_energy": float(state.ledger.energy - old_energy),
            }
        )
        return estimate

    def _map(self, state: ELDState, change, p_old, problem) -> ELDState:
        """Every field through the transfer T, the boundary vectors through its trace part;
        u, v, a at t_j take G, G_dot, G_ddot(t_j) on the new Dirichlet nodes (module
        docstring, step 3)."""
        T = change.transfer(self.degree, self.components)
        T_gamma = free_transfer(T, p_old.constraint.dofs, problem.constraint.dofs)
        mapped = state.mapped(T, T_gamma)
        f = mapped.fields
        C = problem.constraint.dofs
        t = state.t
        if self.inner.form == "regularized":
            for name, g in (("u", problem.G(t)), ("v", problem.G_dot(t)), ("a", problem.G_ddot(t))):
                f[name][C] = g
        else:
            f["u"][C] = problem.G(t)
            f["x"] = f["u"].copy()
        for name, w in list(f.items()) + list(mapped.boundary.items()):
            if not np.all(np.isfinite(w)):
                raise FloatingPointError(f"the transferred {name} has NaN or inf entries")
        return replace(mapped, mesh_id=int(self.amesh.mesh_id))

    def _new_stepper(self, problem, mapped: ELDState):
        """The stepper on the new mesh (its constructor re-checks tau < rho/d0) and the state
        it adopts: regularized form, x, y, b and the t_{j-1} history rebuilt with the new
        lifting (module docstring, steps 4-5)."""
        kwargs = dict(self.kwargs)
        kwargs["error_scale"] = self.inner.error_scale
        inner = ELDStepper(problem, store_fields=False, **kwargs)
        # the solver's counters continue; the new stepper's first factorization is counted
        inner.solver.stats = replace(self.inner.solver.stats)
        inner.solver.stats.factorizations += inner.initial_factorizations
        self._pending_factorizations += inner.initial_factorizations
        inner._last_newton = self.inner._last_newton
        f = mapped.fields
        C = problem.constraint.dofs
        if inner.form == "regularized":
            lift = inner.lifting
            for full, name in (("u", "x"), ("v", "y"), ("a", "b"), ("u_1", "x_1"), ("v_1", "y_1")):
                if full in f:
                    g = f[full][C].copy()
                    w = f[full] - lift(g)
                    w[C] = 0.0
                    f[name] = w
                    f[full] = w + lift(g)
        new = inner.adopt(mapped)
        if not math.isfinite(new.ledger.energy):
            raise FloatingPointError("the energy of the transferred state is not finite")
        return inner, new

    # -- checkpoints ----------------------------------------------------------------------------
    def checkpoint_state(self, state) -> dict:
        """The inner stepper's state, the mesh hierarchy, the mesh series, the kept fields and
        the log of adaptations (arrays and plain values)."""
        self._restore_base(state)  # e.g. interrupted after a rejected, refined attempt
        return {
            "format": "rothe-eld-space-1",
            "inner": self.inner.checkpoint_state(state),
            "amesh": self.amesh.checkpoint_state(),
            "adapted": bool(self.adaptations),
            "series": self.series.checkpoint_state(),
            "kept": {k: [w.copy() for w in v] for k, v in self.kept.items()},
            "adaptations": [dict(a) for a in self.adaptations],
        }

    def restore_state(self, data: dict) -> ELDState:
        if data.get("format") != "rothe-eld-space-1":
            raise RotheInputError(
                f"checkpoint: got format {data.get('format')!r}, must be "
                "'rothe-eld-space-1' (a space-adaptive ELD run)"
            )
        self.amesh = AdaptiveMesh.restore_state(data["amesh"])
        self.series = MeshSeries.restore_state(data["series"])
        self.kept = {k: [np.asarray(w, dtype=float).copy() for w in data["kept"][k]] for k in KEPT}
        self.adaptations = [dict(a) for a in data["adaptations"]]
        if int(data["inner"].get("mesh_id", 0)) != 0:
            self.problem = self.problem.on_mesh(self.amesh.mesh)
            kwargs = dict(self.kwargs)
            kwargs["error_scale"] = data["inner"].get("error_scale")
            self.inner = ELDStepper(self.problem, store_fields=False, **kwargs)
        return self.inner.restore_state(data["inner"])

    # -- outputs --------------------------------------------------------------------------------
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
