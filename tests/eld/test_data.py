"""The data of a step (rothe.eld.data): the data-mode objects and the noise of Theorem 4.5."""

import numpy as np
import pytest

from rothe.eld import (
    BDF2,
    DataNoise,
    Differenced,
    ImplicitEuler,
    Means,
    Points,
    StepData,
    mms_problem,
    run_eld,
)
from rothe.errors import RotheInputError


@pytest.mark.parametrize("datum", ["G", "G_dot", "G_ddot", "F"])
def test_noise_in_one_datum_changes_only_that_datum(datum):
    problem, _ = mms_problem(2, 1)
    clean = StepData(problem, Points()).at(3, 0.2, 0.3)
    noisy = StepData(problem, Points(), DataNoise(1e-3, datum, seed=1)).at(3, 0.2, 0.3)
    for name in ("G", "G_dot", "G_ddot", "F"):
        diff = np.abs(getattr(noisy, name) - getattr(clean, name)).max()
        if name == datum:
            assert diff > 1e-5
        else:
            assert diff == 0.0, name
    with pytest.raises(
        RotheInputError,
        match=r"^noise target: got 'H', must be one of G, "
        "G_dot, G_ddot, F",
    ):
        DataNoise(1e-3, "H")
    with pytest.raises(RotheInputError, match=r"^seed: got -1, must be an integer >= 0"):
        DataNoise(1e-3, "G", seed=-1)


def test_noise_depends_only_on_seed_and_step():
    targets = ("G", "G_dot", "G_ddot")
    a, b = DataNoise(1e-3, targets, seed=4), DataNoise(1e-3, targets, seed=4)
    for j in (1, 7):
        for x, y in zip(a.constraint_noise(j, 10), b.constraint_noise(j, 10), strict=True):
            assert np.array_equal(x, y)
    theta, xi, vartheta = a.constraint_noise(3, 1000)
    assert np.abs(theta).max() <= 1e-3 and np.abs(theta).max() > 0.9e-3
    assert not np.allclose(theta, xi) and not np.allclose(xi, vartheta)


def test_the_modes_evaluate_points_means_and_the_schemes_quotients():
    problem, _ = mms_problem(2, 1)
    t0, t1 = 0.2, 0.3
    points = StepData(problem, Points()).at(3, t0, t1)
    assert np.array_equal(points.G_dot, problem.G_dot(t1))
    means = StepData(problem, Means()).at(3, t0, t1)
    assert np.allclose(means.G_dot, (problem.G(t1) - problem.G(t0)) / 0.1)
    assert np.array_equal(means.G, points.G)
    # differenced: the Euler quotients of the history kept in the state's boundary vectors
    history = Differenced().history(
        {"G": problem.G(t0), "G_dot": problem.G_dot(t0)}, (1.0, -1.0, 0.0)
    )
    diff = StepData(problem, Differenced()).at(3, t0, t1, (1.0, -1.0, 0.0), history)
    assert np.allclose(diff.G_dot, (problem.G(t1) - problem.G(t0)) / 0.1)
    assert np.allclose(diff.G_ddot, (diff.G_dot - problem.G_dot(t0)) / 0.1)
    assert Points().history({}, (1.0, -1.0, 0.0)) is None
    assert set(Differenced().next_history({"G": 1, "G_dot": 2}, diff)) == {
        "G",
        "G_1",
        "G_dot",
        "G_dot_1",
    }


def test_data_modes_refuse_bad_input_in_one_line_naming_the_parameter():
    problem, _ = mms_problem(2, 1)
    with pytest.raises(
        RotheInputError,
        match=r"^data: got 'mean', must be Points\(\), "
        r"Means\(\) or Differenced\(\)",
    ) as info:
        run_eld(problem, data="mean")
    assert info.value.parameter == "data" and len(str(info.value).splitlines()) == 1
    # step means are first-order data: refused with BDF2, accepted by Euler
    with pytest.raises(
        RotheInputError,
        match=r"^data: got 'means', with scheme bdf2 must be "
        r"points or differenced \(step means",
    ):
        run_eld(problem, scheme=BDF2(), data=Means())
    Means().check(ImplicitEuler())
    with pytest.raises(RotheInputError, match=r"^noise: got 'str', must be a rothe.eld.DataNoise"):
        StepData(problem, Points(), noise="G")
