"""Hysteresis of coarsening (rothe.fem.adapt.hysteresis): no cell is refined and coarsened again
more than ``max_recoarsen`` times, whatever the indicators do; freshly refined cells wait
``coarsen_delay`` adaptations; the history survives a checkpoint and a rolled-back cycle."""

from __future__ import annotations

import numpy as np
import pytest

from rothe.fem import mesh as meshes
from rothe.fem.adapt import SpaceAdaptivity
from rothe.fem.adapt.cycle import AdaptationFailed, MeshAdaptation
from rothe.fem.adapt.hysteresis import VertexHistory


class Blinking:
    """A family whose indicator is large on a disc in odd adaptations and tiny everywhere in
    even ones: without hysteresis the disc is refined and coarsened back again and again."""

    def __init__(self, fail_rebuild_at=None):
        self.calls = 0
        self.meshes = None
        self.fail_rebuild_at = fail_rebuild_at

    def indicators(self, problem, target):
        am = self.meshes.amesh
        x = am.points[am.cells].mean(axis=1)
        self.calls += 1
        h = np.sqrt(np.abs(np.linalg.det(am.points[am.cells[:, 1:]] - am.points[am.cells[:, :1]])))
        disc = np.sum((x - 0.4) ** 2, axis=1) < 0.05
        if self.calls % 2:
            return np.where(disc, h, 1e-6 * h)
        return 1e-6 * h

    def rebuild(self, problem, mesh):
        if self.fail_rebuild_at is not None and self.calls == self.fail_rebuild_at:
            raise RuntimeError("rebuild failed")
        return problem

    def transfer(self, state, change, problem, new_problem):
        return state


def count_cycles(options, hysteresis, rounds=24):
    """Run the blinking family; count per vertex (by its coordinates, independently of the
    module under test) how often it was created and removed."""
    family = Blinking()
    ma = MeshAdaptation(meshes.unit_square(4), options, hysteresis=hysteresis)
    family.meshes = ma
    created, removed = {}, {}
    for _ in range(rounds):
        before = {tuple(p) for p in ma.amesh.points}
        out = ma.cycle(family, None, None, None)
        if out.changed:
            after = {tuple(p) for p in ma.amesh.points}
            for v in after - before:
                created[v] = created.get(v, 0) + 1
            for v in before - after:
                removed[v] = removed.get(v, 0) + 1
    return created, removed, ma


def opts(**kw):
    return SpaceAdaptivity(space_tol=1e-3, refine_fraction=0.9, coarsen_fraction=0.05, **kw)


def test_without_hysteresis_the_blinking_indicator_cycles():
    """The scenario the bound is for: the same vertices come and go every other adaptation."""
    created, removed, _ = count_cycles(opts(), None)
    assert max(removed.values()) >= 8 and max(created.values()) >= 9


@pytest.mark.parametrize("bound", [0, 1, 2])
def test_no_vertex_is_removed_more_than_max_recoarsen_times(bound):
    created, removed, ma = count_cycles(opts(max_recoarsen=bound), None)
    assert max(created.values()) <= bound + 1
    assert max(removed.values(), default=0) <= bound
    assert ma.history.max_removals() == max(removed.values(), default=0)
    if bound:
        assert max(removed.values()) == bound  # the bound is reached, not just unused


def test_the_family_default_applies_where_the_options_leave_it_open():
    created, removed, ma = count_cycles(opts(), {"max_recoarsen": 1, "coarsen_delay": 0})
    assert (ma.max_recoarsen, ma.coarsen_delay) == (1, 0)
    assert max(removed.values()) == 1 and max(created.values()) == 2
    # an explicit option wins over the family's default
    _, removed, ma = count_cycles(opts(max_recoarsen=2), {"max_recoarsen": 1})
    assert ma.max_recoarsen == 2 and max(removed.values()) == 2


def test_coarsen_delay_holds_fresh_cells():
    """With a delay of 3 adaptations, a refined disc can only go in the 4th adaptation after
    the one that made it: the blinking family then coarsens it at most every 4th round."""
    family = Blinking()
    ma = MeshAdaptation(meshes.unit_square(4), opts(coarsen_delay=3), hysteresis=None)
    family.meshes = ma
    born = {}
    for k in range(16):
        before = {tuple(p) for p in ma.amesh.points}
        out = ma.cycle(family, None, None, None)
        after = {tuple(p) for p in ma.amesh.points}
        for v in after - before:
            born[v] = k
        for v in before - after:
            assert k - born[v] > 3, "a vertex went before its delay was over"
        assert out.changed or k % 2 == 1


def test_history_survives_checkpoint_and_rollback():
    created, removed, ma = count_cycles(opts(max_recoarsen=1), None, rounds=9)
    data = ma.checkpoint_state()
    clone = MeshAdaptation(meshes.unit_square(4), opts(max_recoarsen=1))
    clone.restore_state(data)
    assert np.array_equal(clone.history.birth, ma.history.birth)
    assert np.array_equal(
        clone.history.removals(ma.amesh.points), ma.history.removals(ma.amesh.points)
    )
    assert clone.history.cycles == ma.history.cycles
    restored = VertexHistory.restore_state(ma.history.checkpoint_state())
    assert restored.max_removals() == ma.history.max_removals() == 1
    # a cycle that fails after changing the mesh leaves mesh and history as they were
    family = Blinking(fail_rebuild_at=ma.history.cycles + 1)
    family.calls = ma.history.cycles
    family.meshes = ma
    points, birth = ma.amesh.points.copy(), ma.history.birth.copy()
    with pytest.raises(AdaptationFailed):
        ma.cycle(family, None, None, None)
    assert np.array_equal(ma.amesh.points, points) and np.array_equal(ma.history.birth, birth)
