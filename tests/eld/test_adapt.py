"""Space-adaptive ELD runs (rothe.eld.adapt): constraint and lifting after every change, the
ledger closing with the transfer term, nothing marked = the fixed mesh bit for bit, coarsening
behind the pulse, the adapt step (a new state, the accepted one untouched; its phases timed),
bad input, checkpoint/resume bit for bit, also after a stop signal between the refinement
rounds of a step (issue 21)."""

from __future__ import annotations

import copy
import signal

import numpy as np
import pytest
import scipy.sparse as sp

from rothe.eld import BDF2, Differenced, ImplicitEuler, Regularized, prepare_eld_run, run_eld
from rothe.eld.examples import mms_problem, pulse_problem
from rothe.errors import RotheInputError, RunFailed, RunInterrupted
from rothe.fem.adapt import SpaceAdaptivity
from rothe.io.checkpoint import CheckpointOptions, load_checkpoint
from rothe.stepping.controllers import Adaptive, Uniform

PULSE = dict(form=Regularized(), control=Uniform(0.02), scheme=BDF2())


def pulse(T=0.4):
    return pulse_problem(2, T=T)


def adaptivity(**kw):
    opts = dict(
        space_tol=2e-3, refine_fraction=0.5, coarsen_fraction=0.05, max_dofs=6000, adapt_every=1
    )
    opts.update(kw)
    return SpaceAdaptivity(**opts)


@pytest.fixture(scope="module")
def pulse_run():
    """One coarse adaptive pulse run, with every transfer checked as it happens."""
    problem = pulse()
    run = prepare_eld_run(problem, adapt=adaptivity(), **PULSE)
    family = run.stepper.adaptivity
    checks = []
    original = family.transfer

    def checked(state, change, system, new_system):
        new = original(state, change, system, new_system)
        new_problem = new_system.problem
        c = new_problem.constraint
        t = new.t
        lift = new_system.lifting
        f = new.fields
        checks.append(
            {
                # B u = G(t_j) (and v, a: G_dot, G_ddot) on the new Dirichlet nodes, exactly
                "u": np.max(np.abs(c.restrict(f["u"]) - new_problem.G(t))),
                "v": np.max(np.abs(c.restrict(f["v"]) - new_problem.G_dot(t))),
                "a": np.max(np.abs(c.restrict(f["a"]) - new_problem.G_ddot(t))),
                # the regularized unknowns with the new lifting: u = x + B^- G, x = 0 on Gamma_D
                "x": np.max(np.abs(f["u"] - f["x"] - lift(new_problem.G(t)))),
                "y": np.max(np.abs(f["v"] - f["y"] - lift(new_problem.G_dot(t)))),
                "b": np.max(np.abs(f["a"] - f["b"] - lift(new_problem.G_ddot(t)))),
                "x_gamma": np.max(np.abs(c.restrict(f["x"]))),
                "sizes": {k: w.size == new_problem.space.ndofs for k, w in f.items()},
                "lam": new.boundary["lam"].size == c.m,
                "bound": new_problem.step_bound() == problem.step_bound(),
            }
        )
        return new

    family.transfer = checked
    result = run.evolve()
    return run, result, checks


def test_constraint_and_lifting_hold_after_every_change(pulse_run):
    run, result, checks = pulse_run
    assert len(checks) >= 5
    for c in checks:
        assert c["u"] == 0.0 and c["v"] == 0.0 and c["a"] == 0.0
        assert c["x"] <= 1e-15 and c["y"] <= 1e-13 and c["b"] <= 1e-10
        assert c["x_gamma"] == 0.0
        assert all(c["sizes"].values()) and c["lam"] and c["bound"]
    # every later step keeps the constraint on its own mesh
    traj = result.trajectory
    sp = result.meshes
    final = result.state
    p = result.problem
    assert np.array_equal(p.constraint.restrict(final.u), p.G(final.t))
    assert final.mesh_id == traj["mesh_id"][-1] and final.mesh_id in sp.series


def test_ledger_closes_with_the_transfer_term(pulse_run):
    _, result, _ = pulse_run
    traj = result.trajectory
    scale = np.max(np.abs(traj["energy"]))
    residual = np.max(np.abs(traj["balance_residual"]))
    assert residual <= 1e-12 * scale
    transfer = traj["transfer"][-1]
    # the transfer term is needed: without it the balance would be off by far more
    assert abs(transfer) > 1e6 * residual
    # booked exactly at the steps after a mesh change: an adaptation after the previous step
    # or a refinement of the step's own mesh
    increments = np.diff(traj["transfer"])
    adapted_after = {a["step"] for a in result.meshes.adaptations}
    changed = np.array([(j - 1) in adapted_after for j in range(1, len(increments) + 1)])
    changed |= traj["step_refinements"] > 0
    assert np.all(increments[~changed] == 0.0) and np.any(increments[changed] != 0.0)


def test_meshes_stored_once_and_ids_per_state(pulse_run):
    _, result, _ = pulse_run
    traj = result.trajectory
    sp = result.meshes
    ids = traj["mesh_id"]
    assert len(ids) == len(traj["t"]) and ids[0] == 0
    assert set(np.unique(ids)) <= set(sp.series.ids)
    # every mesh once: those the steps were computed on and those adapted to after a step
    assert len(sp.series.ids) == len(set(sp.series.ids))
    assert set(sp.series.ids) == set(ids.tolist()) | {a["to_mesh"] for a in sp.adaptations}
    for m, u in zip(traj["kept_mesh_id"], sp.kept["u"], strict=True):
        points, cells = sp.series.mesh(m)
        n_edges = len(
            {tuple(sorted(e)) for c in cells for e in ((c[0], c[1]), (c[1], c[2]), (c[0], c[2]))}
        )
        assert u.size == 2 * (len(points) + n_edges)  # P2 on that mesh
    arrays = sp.npz_arrays(traj)
    assert np.array_equal(arrays["state_mesh_id"], traj["kept_mesh_id"])
    off = arrays["kept_u_offsets"]
    assert np.array_equal(arrays["kept_u"][off[-2] : off[-1]], sp.kept["u"][-1])


def test_coarsening_returns_to_coarser_cells_after_the_pulse_passed(pulse_run):
    _, result, _ = pulse_run
    traj = result.trajectory
    sp = result.meshes
    assert sum(a["merges"] for a in sp.adaptations) > 0

    def cells_near_left(mesh_id):
        points, cells = sp.series.mesh(mesh_id)
        return int(np.sum(points[cells].mean(axis=1)[:, 0] < 0.25))

    ids = traj["mesh_id"]
    near = np.array([cells_near_left(m) for m in ids])
    peak = int(np.argmax(near))
    # refined while the pulse is emitted (t <= 0.1), coarsened once the front has left:
    # at T = 0.4 the pressure front is 0.6 away from the pushed side
    assert traj["t"][peak] <= 0.2 and near[peak] >= 10 * near[0]
    assert near[-1] <= 0.7 * near[peak]
    assert np.all(np.diff(near[peak:]) <= 0.05 * near[peak])  # no regrowth


def test_nothing_marked_equals_the_fixed_mesh_bit_for_bit():
    problem, _ = mms_problem(3, 2, T=0.2)
    opts = dict(control=Uniform(0.05), scheme=BDF2())
    fixed_run = run_eld(problem, **opts)
    adaptive_run = run_eld(problem, adapt=SpaceAdaptivity(space_tol=1e30, adapt_every=1), **opts)
    fixed, adaptive = fixed_run.trajectory, adaptive_run.trajectory
    assert adaptive_run.meshes.adaptations == []
    for key in fixed.keys():
        if key in ("u", "v", "a", "lam"):
            kept = adaptive_run.meshes.kept[key]
            assert all(np.array_equal(x, y) for x, y in zip(fixed[key], kept, strict=True))
        else:
            assert np.array_equal(fixed[key], adaptive[key]), key
    assert np.array_equal(fixed_run.state.u, adaptive_run.state.u)
    assert np.all(adaptive["mesh_id"] == 0)


def test_incremental_rebuild_is_the_full_rebuild_bit_for_bit(monkeypatch):
    """Rebuilds that reuse the element matrices of the cells an adaptation left unchanged
    (rothe.eld.adapt.INCREMENTAL) give the run of full rebuilds bit for bit: every mesh's K,
    every state, the ledger (the arithmetic is the same: the same chunks and scatter order)."""
    import rothe.eld.adapt as eld_adapt

    def run(incremental):
        monkeypatch.setattr(eld_adapt, "INCREMENTAL", incremental)
        prepared = prepare_eld_run(pulse(T=0.2), adapt=adaptivity(), **PULSE)
        family = prepared.stepper.adaptivity
        original = family.rebuild
        built = []

        def rebuild(system, mesh):
            cached = system.problem.space.element_stiffness is not None
            new = original(system, mesh)
            problem = new.problem
            change = family.adaptation.change
            reused = int(np.count_nonzero(change.unchanged)) if incremental and cached else 0
            built.append((problem.K.data.copy(), problem.M.data.copy(), reused))
            return new

        family.rebuild = rebuild
        return prepared.evolve(), built

    full, built_full = run(False)
    inc, built_inc = run(True)
    assert len(built_full) == len(built_inc) >= 3
    assert sum(r for _, _, r in built_inc[1:]) > 0  # cells were reused after the first rebuild
    for (K0, M0, _), (K1, M1, _) in zip(built_full, built_inc, strict=True):
        assert np.array_equal(K0, K1) and np.array_equal(M0, M1)
    a, b = full.trajectory, inc.trajectory
    for key in ("energy", "balance_residual", "transfer", "ndofs", "mesh_id"):
        assert np.array_equal(a[key], b[key]), key
    for key in ("u", "v", "lam"):
        for x, y in zip(full.meshes.kept[key], inc.meshes.kept[key], strict=True):
            assert np.array_equal(x, y), key
    assert np.array_equal(full.state.u, inc.state.u)


def test_adaptive_time_steps_with_space_adaptivity():
    result = run_eld(
        pulse(0.08),
        scheme=BDF2(),
        control=Adaptive(1e-2, tau=0.01),
        adapt=adaptivity(adapt_every=2, max_dofs=2000),
    )
    traj = result.trajectory
    assert result.meshes.adaptations
    assert all(a["step"] % 2 == 0 for a in result.meshes.adaptations)
    assert np.max(np.abs(traj["balance_residual"])) <= 1e-12 * np.max(traj["energy"])
    assert len(set(traj["tau"].tolist())) > 1


def _fields_of(state):
    return {
        "t": state.t,
        "j": state.j,
        "mesh_id": state.mesh_id,
        "ledger": copy.deepcopy(state.ledger),
        **{f"f_{k}": w.copy() for k, w in state.fields.items()},
        **{f"b_{k}": w.copy() for k, w in state.boundary.items()},
        **{f"p_{k}": w.copy() for k, w in state.products.items()},
    }


def _same(a, b) -> bool:
    return a.keys() == b.keys() and all(
        np.array_equal(a[k], b[k]) if isinstance(a[k], np.ndarray) else a[k] == b[k] for k in a
    )


@pytest.mark.parametrize("scheme", [ImplicitEuler(), BDF2()], ids=["euler", "bdf2"])
def test_the_adapt_step_returns_a_new_state_and_never_changes_the_accepted_one(scheme):
    problem = pulse(0.2)
    run = prepare_eld_run(problem, adapt=adaptivity(), control=Uniform(0.02), scheme=scheme)
    stepper = run.stepper
    state, changed = run.state, 0
    for _ in range(6):
        result = stepper.step(state, 0.02)
        accepted = result.state
        before = _fields_of(accepted)
        arrays = {k: w for k, w in accepted.fields.items()}
        new = stepper.adapt(accepted, result)
        # the accepted state is what the step computed, bit for bit, and its arrays are its own
        assert _same(before, _fields_of(accepted))
        assert all(accepted.fields[k] is w for k, w in arrays.items())
        if new is accepted:  # nothing changed: the same object, on the step's mesh
            assert stepper.adaptivity.mesh_id == accepted.mesh_id
        else:
            changed += 1
            assert new.mesh_id == stepper.adaptivity.mesh_id != accepted.mesh_id
            assert all(new.fields[k] is not w for k, w in arrays.items())
            assert new.fields["u"].size == stepper.problem.space.ndofs
            # the step keeps its own mesh in the record; the new state goes on
            assert result.system.problem is not stepper.problem
            assert new.ledger.transfer != accepted.ledger.transfer
            assert (new.t, new.j, new.tau_prev) == (accepted.t, accepted.j, accepted.tau_prev)
        stepper.record(run.trajectory, result, new)
        state = new
    assert changed >= 2 and len(stepper.meshes.adaptations) == changed
    traj = run.trajectory
    assert len(traj["mesh_id"]) == len(traj["t"]) == 7
    assert len(traj["space_estimate"]) == 6 and np.all(np.isfinite(traj["space_estimate"]))


def test_the_seconds_of_every_phase_are_in_the_statistics(tmp_path):
    problem = pulse(0.1)
    result = run_eld(problem, adapt=adaptivity(), **PULSE)
    seconds = result.statistics.seconds
    for phase in (
        "estimate",
        "mark",
        "refine",
        "rebuild",
        "transfer",
        "factor",
        "solve",
        "step",
        "adapt",
        "record",
    ):
        assert seconds.get(phase, 0.0) > 0.0, phase
    # nested phases: the solves happen inside the steps
    assert seconds["step"] >= seconds["solve"]
    path = result.trajectory.save_npz(tmp_path / "t.npz")
    with np.load(path) as data:
        assert data["stats_seconds_rebuild"] > 0 and data["stats_seconds_factor"] > 0


def test_a_failed_transfer_is_never_accepted(monkeypatch):
    problem = pulse(0.2)
    run = prepare_eld_run(problem, adapt=adaptivity(), **PULSE)
    stepper = run.stepper

    def broken(state, change, system, new_system):
        raise FloatingPointError("the transferred u has NaN or inf entries")

    monkeypatch.setattr(stepper.adaptivity, "transfer", broken)
    with pytest.raises(
        RunFailed,
        match=r"space adaptivity: the transfer to the new mesh after "
        r"step 1 .* failed .*NaN.*; the run stops on mesh 0",
    ):
        run.evolve()
    # the hierarchy is rolled back: the last accepted state and the mesh agree
    assert stepper.adaptivity.mesh_id == 0 and stepper.problem is problem
    # step 1 is recorded on mesh 0 (it was computed and accepted there), nothing after it
    assert len(run.trajectory["t"]) == 2 and np.all(run.trajectory["mesh_id"] == 0)


def test_non_finite_indicators_stop_the_run_on_the_last_mesh(monkeypatch):
    import rothe.eld.adapt as adapt_module

    problem = pulse(0.2)
    run = prepare_eld_run(problem, adapt=adaptivity(), **PULSE)
    monkeypatch.setattr(
        adapt_module,
        "dirichlet_data_indicator",
        lambda problem, t: np.full(problem.space.mesh.t.shape[1], np.nan),
    )
    with pytest.raises(
        RunFailed,
        match=r"^space adaptivity: the transfer to the new mesh after "
        r"step 1 \(t = 0.02\) failed \(FloatingPointError: "
        r"non-finite error indicators\); the run stops on mesh 0$",
    ):
        run.evolve()
    traj = run.trajectory
    assert traj.stats.accepted_steps == 1 and np.all(traj["step_refinements"] == 0)
    assert "space_estimate" not in traj  # the adapt step of step 1 did not complete


def test_a_failed_transfer_after_the_release_stops_the_run_on_a_working_system(monkeypatch):
    """The rebuild releases the system of the mesh the run leaves (ELDSystem.release: one mesh's
    matrices and solver alive at a time); a transfer that fails after it stops the run on the
    last mesh with its system revived: its matrices and its stored factorization are those of
    the system before the release, bit for bit, and its counters continue unchanged."""
    from rothe.eld import ELDStepper
    from rothe.eld.adapt import ELDAdaptivity

    run = prepare_eld_run(pulse(0.2), adapt=adaptivity(), **PULSE)
    seen = {}
    transfer = ELDAdaptivity.transfer
    adapt = ELDStepper.adapt

    def failing(self, state, change, system, new_system):
        # in the adapt step after a few meshes (not the caller's problem)
        if "system" not in seen and seen.get("adapting") and state.j >= 3:
            assert system.released and system.problem.K is None and system.solver._prec is None
            seen["system"] = system
            raise FloatingPointError("injected")
        return transfer(self, state, change, system, new_system)

    def keeping(self, state, result):
        # before the adapt step: what the system of the state's mesh holds
        seen["before"] = (
            self.system,
            self.system.problem.K.toarray(),
            self.system.solver.stats.factorizations,
            self.system.reference,
        )
        seen["adapting"] = True
        try:
            return adapt(self, state, result)
        finally:
            seen["adapting"] = False

    monkeypatch.setattr(ELDAdaptivity, "transfer", failing)
    monkeypatch.setattr(ELDStepper, "adapt", keeping)
    with pytest.raises(RunFailed, match=r"FloatingPointError: injected\); the run stops on mesh"):
        run.evolve()
    system = run.stepper.system
    old, K, factorizations, reference = seen["before"]
    assert seen["system"] is old and old.released
    assert system is not old and not system.released and system.owns_problem
    assert np.array_equal(system.problem.K.toarray(), K)
    assert system.reference == reference and system.solver.stats.factorizations == factorizations
    rhs = np.linspace(0.0, 1.0, system.size)
    x = system.solve_linear(rhs, reference["tau_eff"])
    assert np.linalg.norm(system.apply_A(x, reference["tau_eff"]) - rhs) < 1e-8 * np.linalg.norm(
        rhs
    )


def test_bad_input_one_line():
    problem = pulse(0.2)
    with pytest.raises(
        RotheInputError,
        match=r"^max_dofs: got 10, must be >= the \d+ dofs of "
        r"the initial mesh$",
    ):
        run_eld(problem, adapt=adaptivity(max_dofs=10), **PULSE)
    with pytest.raises(
        RotheInputError,
        match=r"^data: got 'differenced', must be 'points' "
        r"with space adaptivity",
    ):
        run_eld(problem, data=Differenced(), adapt=adaptivity(), **PULSE)
    with pytest.raises(
        RotheInputError,
        match=r"^adapt: got dict, must be a "
        r"rothe.fem.adapt.SpaceAdaptivity",
    ):
        run_eld(problem, adapt={"space_tol": 1}, **PULSE)
    with pytest.raises(RotheInputError, match=r"^space_tol: got 0, must be > 0$"):
        SpaceAdaptivity(space_tol=0)


@pytest.mark.parametrize(
    "hysteresis",
    [
        {},
        {"coarsen_delay": 2, "max_recoarsen": 1},
        {"coarsen_delay": 3},
        {"max_recoarsen": 0},
        # between adaptations the last in-step estimates decide which steps refine in their
        # rounds: they come back from the checkpoint
        {"adapt_every": 2},
        {"adapt_every": 3},
    ],
)
def test_resumed_adaptive_run_equals_the_uninterrupted_run(tmp_path, monkeypatch, hysteresis):
    """Interrupted twice and resumed: bit for bit the uninterrupted run; with hysteresis the
    vertex history, which decides which cells may coarsen, comes back from the checkpoint."""
    import os

    from rothe.eld import ELDStepper

    problem = pulse(0.2)

    def make_run(**kw):
        return run_eld(problem, adapt=adaptivity(**hysteresis), **PULSE, **kw)

    full_run = make_run()
    full = full_run.trajectory
    ckpt = tmp_path / "c"
    original = ELDStepper.step
    resume = None
    # interrupted twice, each time after adaptations on a refined mesh; with adapt_every > 1
    # after the second step, where the restored in-step estimates decide the next step's rounds
    # (with the estimates zeroed on restore, the adapt_every 3 run differs from the
    # uninterrupted one in its kinetic energy from the third state on)
    points = (2, 2) if "adapt_every" in hysteresis else (4, 3)
    for k in points:
        calls = [0]

        def step(self, state, tau, s_end=None, k=k, calls=calls):
            calls[0] += 1
            if calls[0] == k:
                os.kill(os.getpid(), signal.SIGINT)
            return original(self, state, tau, s_end)

        monkeypatch.setattr(ELDStepper, "step", step)
        with pytest.raises(RunInterrupted):
            make_run(checkpoint=CheckpointOptions(ckpt, every_seconds=0.01), resume=resume)
        assert load_checkpoint(ckpt).status == "interrupted"
        resume = ckpt
    monkeypatch.setattr(ELDStepper, "step", original)
    resumed_run = make_run(resume=ckpt)
    resumed = resumed_run.trajectory
    assert set(full.keys()) == set(resumed.keys())
    for key in full.keys():  # space_estimate is NaN after the steps not adapted after
        assert np.array_equal(full[key], resumed[key], equal_nan=True), key
    a, b = full_run.meshes, resumed_run.meshes
    assert a.series.ids == b.series.ids and len(a.series.ids) > 2
    for i in a.series.ids:
        assert all(
            np.array_equal(x, y) for x, y in zip(a.series.mesh(i), b.series.mesh(i), strict=True)
        )
    for key in a.kept:
        assert all(np.array_equal(x, y) for x, y in zip(a.kept[key], b.kept[key], strict=True))
    assert a.adaptations == b.adaptations
    assert full.stats.untimed() == resumed.stats.untimed()


def test_a_signal_between_the_refinement_rounds_of_a_step_abandons_it(
    tmp_path, signal_at_call, monkeypatch
):
    """Issue 21: a step re-solved on meshes refined within the step (up to STEP_ROUNDS) is
    abandoned by a stop signal between its rounds; abandon goes back to the mesh and system of
    the last accepted state, and the resumed run is the uninterrupted one, bit for bit."""
    from rothe.eld import ELDStepper

    problem = pulse(0.2)

    def make_run(**kw):
        return run_eld(problem, adapt=adaptivity(), **PULSE, **kw)

    # the uninterrupted run, with the step index j of the state every attempt starts from:
    # uniform steps are never rejected, so an attempt from the same j as the one before is a
    # re-solve on a mesh refined within the step
    starts = []
    original = ELDStepper._attempt

    def recording(self, state, tau):
        starts.append(int(state.j))
        return original(self, state, tau)

    monkeypatch.setattr(ELDStepper, "_attempt", recording)
    full_run = make_run()
    monkeypatch.setattr(ELDStepper, "_attempt", original)
    full = full_run.trajectory
    resolves = [i for i in range(2, len(starts) + 1) if starts[i - 1] == starts[i - 2]]
    assert np.sum(full["step_refinements"]) == len(resolves) >= 2
    # session 1 stops at the first re-solve; session 2 (from the checkpoint: its calls count
    # from the first attempt of the abandoned step) at the first re-solve of a later step
    first = resolves[0]
    later = next(i for i in resolves if starts[i - 1] > starts[first - 1])
    restart = starts.index(starts[first - 1]) + 1
    ckpt, resume = tmp_path / "c", None
    for k, accepted in ((first, starts[first - 1]), (later - restart + 1, starts[later - 1])):
        signal_at_call(ELDStepper, "_attempt", k)
        with pytest.raises(RunInterrupted) as info:
            make_run(checkpoint=CheckpointOptions(ckpt, every_seconds=0.01), resume=resume)
        exc = info.value
        assert exc.where["abandoned_step"] is True and exc.where["accepted_steps"] == accepted
        saved = load_checkpoint(ckpt)
        assert saved.status == "interrupted" and saved.state["stepper"]["j"] == accepted
        # the mesh of the last accepted state, not the one refined for the abandoned step
        assert (
            saved.state["stepper"]["adapt"]["amesh"]["mesh_id"]
            == (saved.state["stepper"]["mesh_id"])
        )
        resume = ckpt
    signal_at_call(ELDStepper, "_attempt", 10**9)
    resumed_run = make_run(resume=ckpt)
    resumed = resumed_run.trajectory
    for key in full.keys():  # space_estimate is NaN after the steps not adapted after
        assert np.array_equal(full[key], resumed[key], equal_nan=True), key
    assert full.stats.untimed() == resumed.stats.untimed()
    assert full_run.meshes.series.ids == resumed_run.meshes.series.ids
    ls = resumed.meta["linear_solver"]
    assert full.meta["linear_solver"] == ls | {
        "setup_seconds": full.meta["linear_solver"]["setup_seconds"]
    }


def test_a_signal_in_the_adapt_step_abandons_the_accepted_step(
    tmp_path, signal_at_call, monkeypatch
):
    """Issue 21: a stop signal during the adapt step after an accepted step (here during the
    factorization of the new mesh's system, which runs abandonable: interrupt.call) abandons the
    whole attempt -- the accepted step, the decision, the new mesh and the rounds' refinements --
    and the resumed run is the uninterrupted one, bit for bit."""
    from rothe.eld import ELDStepper

    problem = pulse(0.2)

    def make_run(**kw):
        return run_eld(problem, adapt=adaptivity(), **PULSE, **kw)

    # the uninterrupted run, with the step j after which each adapt step changed the mesh (only
    # those factor a new system: the abandonable part of an adapt step)
    changed = []
    original = ELDStepper.adapt

    def recording(self, state, result):
        new = original(self, state, result)
        if new.mesh_id != state.mesh_id:
            changed.append(int(state.j))
        return new

    monkeypatch.setattr(ELDStepper, "adapt", recording)
    full = make_run().trajectory
    monkeypatch.setattr(ELDStepper, "adapt", original)
    # an adapt step follows every accepted step: the k-th call of a session that starts after
    # step j0 is the one after step j0 + k; abandoned, the run has j0 + k - 1 accepted steps
    # (the first interruption after step 2 at the earliest, so that a step is left to keep)
    first = next(j for j in changed if j >= 2)
    later = next(j for j in changed if j > first)
    # the rebuild released the system of the mesh it left before the abandoned factorization:
    # abandon revives it (built again, its factorization's key refactored)
    from rothe.eld.system import ELDSystem

    revived = []
    revive = ELDSystem.revived

    def counting(self):
        new = revive(self)
        if new is not self:
            revived.append(new)
        return new

    monkeypatch.setattr(ELDSystem, "revived", counting)
    ckpt, resume = tmp_path / "c", None
    for k, accepted in ((first, first - 1), (later - first + 1, later - 1)):
        signal_at_call(ELDStepper, "adapt", k)
        revived.clear()
        with pytest.raises(RunInterrupted) as info:
            make_run(checkpoint=CheckpointOptions(ckpt, every_seconds=0.01), resume=resume)
        assert len(revived) >= 1 and all(r is revived[0] for r in revived)  # built once
        exc = info.value
        assert exc.where["abandoned_step"] is True and exc.where["accepted_steps"] == accepted
        assert len(exc.trajectory["tau"]) == accepted  # the step whose adapt step it was: gone
        saved = load_checkpoint(ckpt)
        assert saved.state["stepper"]["j"] == accepted
        stepper = saved.state["stepper"]
        assert stepper["adapt"]["amesh"]["mesh_id"] == stepper["mesh_id"]
        resume = ckpt
    signal_at_call(ELDStepper, "adapt", 10**9)
    resumed = make_run(resume=ckpt).trajectory
    for key in full.keys():
        assert np.array_equal(full[key], resumed[key], equal_nan=True), key
    assert full.stats.untimed() == resumed.stats.untimed()
    ls = resumed.meta["linear_solver"]
    assert full.meta["linear_solver"] == ls | {
        "setup_seconds": full.meta["linear_solver"]["setup_seconds"]
    }


# -- command line --------------------------------------------------------------------------------


def test_cli_eld_pulse_writes_meshes_vtu_series_and_figures(tmp_path, capsys):
    import json

    import meshio

    from rothe.cli.main import main
    from rothe.io.mesh_series import MeshSeries

    out = tmp_path / "pulse"
    code = main(
        [
            "run",
            "eld-pulse",
            "--n",
            "2",
            "--T",
            "0.06",
            "--tau",
            "0.02",
            "--keep-every",
            "1",
            "--max-dofs",
            "3000",
            "--adapt-every",
            "1",  # three steps: the default (6) would adapt inside the first step only
            "--out",
            str(out),
        ]
    )
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["adaptations"] >= 1 and s["meshes"] >= s["adaptations"] + 1
    assert s["ndofs"] > s["ndofs_initial"] and s["balance_residual_max"] < 1e-12
    # every bisection counts, those of refinements inside a step too: the cells grew by them
    data0 = np.load(out / "trajectory.npz")
    cells = data0["cells"]
    assert s["bisections"] >= cells.max() - cells[0]
    assert s["refinements_in_steps"] == int(np.sum(data0["step_refinements"]))
    data = np.load(out / "trajectory.npz")
    series, ids = MeshSeries.from_npz(data)
    assert np.array_equal(ids, data["kept_mesh_id"]) and len(series.ids) == s["meshes"]
    off = data["kept_u_offsets"]
    for k, m in enumerate(ids):
        points, cells = series.mesh(m)
        vtu = meshio.read(out / f"pulse_{k:06d}.vtu")
        assert len(vtu.points) == len(points) and len(vtu.cells[0].data) == len(cells)
        u = data["kept_u"][off[k] : off[k + 1]].reshape(-1, 2)[: len(points)]
        assert np.array_equal(vtu.point_data["u"][:, :2], u)
        # the fields of the fixed-mesh XDMF: stresses (cells and vertices) and the multiplier
        sigma = vtu.cell_data["stress"][0]
        assert sigma.shape == (len(cells), 9) and np.all(np.isfinite(sigma))
        vm = vtu.cell_data["von_mises"][0]
        assert vm.shape == (len(cells),) and np.all(vm >= 0)
        assert vtu.point_data["stress_nodal"].shape == (len(points), 9)
        assert vtu.point_data["von_mises_nodal"].shape == (len(points),)
        lam = vtu.point_data["lambda"]
        assert np.array_equal(vtu.point_data["reaction_density"], -lam)
        left = points[:, 0] == 0.0  # Gamma_D of the pulse: the left side
        assert not np.any(lam[~left]) and np.all(np.isfinite(lam))
        if data["kept_t"][k] > 0:
            assert np.any(lam[left])
    assert (out / "pulse.pvd").is_file()
    for fig in ("fig_dofs.png", "fig_mesh.png", "fig_energy.png"):
        assert (out / fig).is_file(), fig


@pytest.mark.parametrize(
    "args, message",
    [
        (["run", "eld-pulse", "--space-tol", "0"], r"--space-tol: got 0, must be > 0"),
        (["run", "eld-pulse", "--refine-fraction", "1"], r"--refine-fraction: got 1, must be in"),
        (
            ["run", "eld-pulse", "--refine-fraction", "0.8", "--coarsen-fraction", "0.3"],
            r"--refine-fraction \+ --coarsen-fraction: got 0.8 \+ 0.3 = 1.1, must be <= 1",
        ),
        (["run", "eld-pulse", "--max-dofs", "10"], r"--max-dofs: got 10, must be >= the 306 dofs"),
        (["run", "eld-pulse", "--adapt-every", "0"], r"--adapt-every: got 0, must be an integer"),
        (["run", "eld-pulse", "--adapt-every", "-3"], r"--adapt-every: got -3, must be an integer"),
        (
            ["run", "eld-pulse", "--refine-band", "-1"],
            r"--refine-band: got -1, must be >= 0 \(a length\)",
        ),
        (["run", "eld-pulse", "--refine-band", "nan"], r"--refine-band: got .nan., must be finite"),
        (["run", "eld-pulse", "--coarsen-batch", "1"], r"--coarsen-batch: got 1, must be in"),
        (
            ["run", "eld-mms", "--refine-band", "0.1"],
            r"--refine-band: got 0.1, is used by --adapt-space only",
        ),
        (
            ["run", "eld-pulse", "--no-adapt-space", "--max-dofs", "1000"],
            r"--max-dofs: got 1000, is used by --adapt-space only",
        ),
        (["run", "eld-mms", "--adapt-space"], r"--space-tol: got None, must be given"),
        (
            ["run", "eld-pulse", "--space-norm", "h1"],
            r"^rothe: error: --space-norm: got 'h1', must be one of energy, l2$",
        ),
        (
            ["run", "eld-pulse", "--no-adapt-space", "--space-norm", "l2"],
            r"--space-norm: got 'l2', is used by --adapt-space only",
        ),
        (
            ["run", "eld-mms", "--adapt-space", "--space-tol", "1", "--data", "means"],
            r"--data: got 'means', must be points with --adapt-space",
        ),
    ],
)
def test_cli_bad_space_options_one_line_exit_2(tmp_path, capsys, args, message):
    import re

    from rothe.cli.main import main

    code = main(args + ["--T", "0.02", "--tau", "0.01", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert re.search(message, err), err


def test_a_quadrilateral_mesh_is_refused_naming_the_parameter():
    # the library names its parameter (``mesh`` by default, the caller's otherwise); the command
    # line passes its option (tests/cli/test_cli_ris_fem.py: ``--adapt-space: got a mesh of ...``)
    from skfem import MeshQuad

    from rothe.fem.adapt import check_adaptable

    with pytest.raises(
        RotheInputError,
        match=r"^mesh: got a mesh of quadrilaterals, "
        r"needs triangles \(2D\) or tetrahedra \(3D\)",
    ):
        check_adaptable(MeshQuad())
    with pytest.raises(RotheInputError, match=r"^adapt: got a mesh of quadrilaterals"):
        check_adaptable(MeshQuad(), "adapt")


def test_3d_tetrahedra_adapt_with_the_ledger_closing():
    from rothe.eld.examples import beam_problem

    problem = beam_problem(1, length=2.0, T=0.03, degree=1)
    result = run_eld(
        problem, control=Uniform(0.01), adapt=adaptivity(space_tol=1e-5, max_dofs=1500)
    )
    traj = result.trajectory
    assert result.meshes.adaptations or np.any(traj["step_refinements"] > 0)
    assert traj["ndofs"].max() > traj["ndofs"][0] and traj["ndofs"].max() <= 1500
    assert np.max(np.abs(traj["balance_residual"])) <= 1e-12 * np.max(traj["energy"])
    final, p = result.state, result.problem
    assert np.array_equal(p.constraint.restrict(final.u), p.G(final.t))


def test_cli_default_cap_on_the_adapted_mesh():
    # without a cap a --space-tol below what the time step allows refines until memory runs out
    import argparse

    from rothe.cli.adapt_options import fit_default_cap, space_adaptivity
    from rothe.cli.eld_options import ELD_MAX_DOFS

    def args(**given):
        base = dict(
            adapt_space=True,
            space_tol=1e-3,
            refine_fraction=None,
            coarsen_fraction=None,
            max_dofs=None,
            adapt_every=None,
        )
        return argparse.Namespace(**{**base, **given})

    a = args()
    space = space_adaptivity(a, default_max_dofs=ELD_MAX_DOFS["2d"])
    assert space.max_dofs == 200_000
    fit_default_cap(a, space, 150_000)  # an initial mesh finer than half the cap
    assert space.max_dofs == 300_000
    a = args(max_dofs=5_000)
    space = space_adaptivity(a, default_max_dofs=ELD_MAX_DOFS["3d"])
    fit_default_cap(a, space, 150_000)  # the user's cap is the user's (run_eld checks it)
    assert space.max_dofs == 5_000


# -- the factorization is the current mesh's ------------------------------------------------------


def _factor_residual(system) -> float:
    """|A(te) x - b| / |b| with x from the stored factorization of ``system`` and A(te) the
    current mesh's step matrix of the factorization's key (inf if the sizes differ)."""
    ref = system.reference
    A = system._system_matrix(ref["tau_eff"], None)
    b = np.random.default_rng(1).standard_normal(A.shape[0])
    try:
        x = system.solver._prec(b)
    except (ValueError, RuntimeError):
        return float("inf")
    if x.shape != b.shape:
        return float("inf")
    return float(np.linalg.norm(A @ x - b) / np.linalg.norm(b))


@pytest.mark.parametrize("adapt_every", [1, 3])
def test_reused_factorization_is_the_current_meshs(adapt_every):
    """After every accepted step the stored factorization, which the next steps reuse, solves
    the step matrix of the mesh the run goes on with (a factor of an earlier mesh would not:
    other size, or other entries after a refinement that keeps the size)."""
    run = prepare_eld_run(pulse(T=0.3), adapt=adaptivity(adapt_every=adapt_every), **PULSE)
    seen = {}
    original = run.stepper.adapt

    def adapt(state, result):
        new = original(state, result)
        system = run.stepper.system
        seen[int(new.mesh_id)] = max(seen.get(int(new.mesh_id), 0.0), _factor_residual(system))
        return new

    run.stepper.adapt = adapt
    run.evolve()
    assert len(seen) >= 3, seen  # the mesh changed (in steps and after them)
    assert max(seen.values()) < 1e-10, seen


def test_factor_check_catches_a_stale_factorization():
    """The check above fails for a system that kept the factorization of its previous mesh."""
    run = prepare_eld_run(pulse(T=0.3), adapt=adaptivity(), **PULSE)
    run.evolve()
    system = run.stepper.system
    assert _factor_residual(system) < 1e-10
    problem0 = pulse(T=0.3)
    stale = system.rebuilt(problem0)  # the initial mesh's system ...
    stale.solver = system.solver  # ... with the factorization of the last mesh
    assert _factor_residual(stale) > 1e-3


def _amg_mismatch(system) -> float:
    """max |A_0 - D^{-1/2} A D^{-1/2}| / max |A_0| between the finest level A_0 of the stored
    AMG hierarchy of ``system`` and the scaled step matrix A of its current mesh at the
    hierarchy's key (inf if the sizes differ)."""
    from rothe.eld.solvers import jacobi_scaled

    solver = system.solver
    A = system._system_matrix(system.reference["tau_eff"], None)
    A0 = solver._ml.levels[0].A
    if A0.shape != A.shape:
        return float("inf")
    scaled = jacobi_scaled(A)[0]
    diff = abs(sp.csr_matrix(A0) - sp.csr_matrix(scaled)).max()
    return float(diff / abs(sp.csr_matrix(scaled)).max())


def test_reused_amg_hierarchy_is_the_current_meshs():
    """With AMG (solver='amg'), after every accepted step the stored hierarchy, which the next
    steps' solves reuse, is built from the step matrix of the mesh the run goes on with; a
    system given the previous mesh's solver fails the same check."""
    run = prepare_eld_run(pulse(T=0.3), adapt=adaptivity(), solver="amg", **PULSE)
    seen = {}
    previous = {}
    original = run.stepper.adapt

    def adapt(state, result):
        before = run.stepper.system
        # the previous mesh's hierarchy, held here: the rebuild releases the system it leaves
        stored = before.solver.snapshot()
        new = original(state, result)
        system = run.stepper.system
        assert system.kind == "amg"
        seen[int(new.mesh_id)] = max(seen.get(int(new.mesh_id), 0.0), _amg_mismatch(system))
        if system is not before:
            assert before.released and before.solver._ml is None
            previous[int(new.mesh_id)] = (system, before.solver, stored)
        return new

    run.stepper.adapt = adapt
    run.evolve()
    assert len(seen) >= 3, seen
    assert max(seen.values()) < 1e-12, seen
    system, old_solver, stored = next(iter(previous.values()))
    # the run left that mesh: its system was released, revived it is the system it was
    assert system.released
    stale = system.revived()
    assert stale is not system and not stale.released
    assert _amg_mismatch(stale) < 1e-12
    assert stale.reference == system.reference
    old_solver.rollback(stored)
    stale.solver, stale._ref = old_solver, system._ref
    assert _amg_mismatch(stale) > 1e-3


def test_l2_norm_indicators_are_the_energy_ones_weighted_by_h_over_h0():
    """SpaceAdaptivity(norm='l2'): eta_K h_K / h_0 (the duality factor of the L2 norm of u),
    h_0 the initial mesh's longest edge: equal on the initial mesh's largest cells, smaller on
    refined ones; and the L2 run refines less where the energy run refines most (a coarser
    final mesh for the same tolerance)."""
    from rothe.fem.topology import cell_diameters

    runs = {}
    for norm in ("energy", "l2"):
        run = prepare_eld_run(pulse(T=0.12), adapt=adaptivity(norm=norm), **PULSE)
        result = run.evolve()
        runs[norm] = (run, result)
    run_e, res_e = runs["energy"]
    run_l, _ = runs["l2"]
    # the same state and mesh through both families' indicators
    system = run_e.stepper.system
    state = res_e.state
    target = (state, 0.02, (state.t,))
    eta_e = run_e.stepper.adaptivity.indicators(system, target)
    eta_l = run_l.stepper.adaptivity.indicators(system, target)
    mesh = system.problem.space.mesh
    h = cell_diameters(np.asarray(mesh.p), np.asarray(mesh.t))
    h0 = run_l.stepper.adaptivity.h0
    first = pulse().space.mesh
    assert h0 == cell_diameters(np.asarray(first.p), np.asarray(first.t)).max()
    assert np.allclose(eta_l, eta_e * h / h0, rtol=1e-13, atol=0)
    assert h.min() < h0  # the energy run refined: there the weights are < 1
    assert np.all(eta_l <= eta_e * (1 + 1e-13))


def test_ris_refuses_the_l2_norm():
    from rothe.ris.adapt import RISAdaptivity
    from rothe.ris.examples import example_front

    with pytest.raises(RotheInputError, match=r"^adapt.norm: got 'l2', must be 'energy' for a "):
        RISAdaptivity(example_front(n=4), adaptivity(norm="l2"))
