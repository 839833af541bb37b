"""Analytic references: bar and beam frequencies with attachments, the rigid limit, the decay
rate of the first mode under feedback (known values from the classical tables)."""

import numpy as np
import pytest
from scipy.optimize import brentq

from rothe.eld.components import MassSpringDamper, TunedMassDamper
from rothe.eld.frequencies import (
    Attachment,
    bar_frequencies,
    beam_frequencies,
    beam_tip_mass_equation,
    controlled_bar_roots,
    first_mode_decay_rate,
    rigid_limit_frequency,
    sliced_bar_frequencies,
    tip_mass_roots,
)
from rothe.errors import RotheInputError


def test_tip_mass_roots_are_the_table_values():
    """beta L tan(beta L) = rho A L / m (Meirovitch's table: ratio 1 -> 0.8603, 3.4256, 6.4373;
    ratio 0.1 -> 0.3111; ratio 10 -> 1.4289)."""
    assert np.allclose(tip_mass_roots(1.0), [0.8603, 3.4256, 6.4373], atol=5e-5)
    assert tip_mass_roots(0.1, 1)[0] == pytest.approx(0.3111, abs=5e-5)
    assert tip_mass_roots(10.0, 1)[0] == pytest.approx(1.4289, abs=5e-5)


def test_bar_frequencies_clamped_free_and_with_a_tip_mass():
    L, E, rho, A = 2.0, 100.0, 1.0, 0.25
    c = np.sqrt(E / rho)
    assert np.allclose(
        bar_frequencies(L, E, rho) * L / c, [np.pi / 2, 3 * np.pi / 2, 5 * np.pi / 2], rtol=1e-12
    )
    m = 0.5
    w = bar_frequencies(L, E, rho, area=A, right=Attachment.point_mass(m))
    assert np.allclose(w * L / c, tip_mass_roots(rho * A * L / m), rtol=1e-11)
    # the same mass given as a component, and the mass-spring limits: a very stiff spring is
    # the rigid tip mass, a very soft one the free tip (plus the mass's own slow mode)
    assert np.allclose(
        bar_frequencies(
            L, E, rho, area=A, right=Attachment.of(MassSpringDamper(m, 0.0, dim=2), at=0), count=3
        ),
        w,
        rtol=1e-11,
    )
    stiff = bar_frequencies(L, E, rho, area=A, right=Attachment.suspended(1e-9, m, 1e9))
    assert np.allclose(stiff, w, rtol=1e-6)
    soft = bar_frequencies(L, E, rho, area=A, right=Attachment.suspended(1e-9, m, 1e-2), count=2)
    assert soft[0] == pytest.approx(np.sqrt(1e-2 / m), rel=1e-3)
    assert soft[1] * L / c == pytest.approx(np.pi / 2, rel=1e-3)
    tmd = Attachment.of(TunedMassDamper(1e-9, m, 1e9, dim=1 + 1), at=0)
    assert np.allclose(bar_frequencies(L, E, rho, area=A, right=tmd, count=3)[:3], w, rtol=1e-6)


def test_beam_frequencies_clamped_free_and_with_a_tip_mass():
    lam = np.sqrt(beam_frequencies(1.0, 1.0, 1.0))  # beta L with EI = rho A = L = 1
    assert np.allclose(lam, [1.875104, 4.694091, 7.854757], atol=2e-6)
    for ratio, first in ((1.0, 1.24792), (0.2, 1.61640)):
        root = brentq(beam_tip_mass_equation, 0.5, 1.875, args=(ratio,))
        assert root == pytest.approx(first, abs=2e-5)
        w = beam_frequencies(2.0, 3.0, 0.5, right=Attachment.point_mass(ratio * 0.5 * 2.0), count=1)
        assert (0.5 * w[0] ** 2 / 3.0) ** 0.25 * 2.0 == pytest.approx(root, rel=1e-10)


def test_rigid_limit_of_a_bar_on_a_mass_spring():
    """k - m w^2 = E A beta tan(beta L): w -> (k/(m + rho A L))^{1/2} as E -> infinity,
    with an error O(1/E)."""
    k, m = 50.0, 2.0
    w_rigid = rigid_limit_frequency(k, m, 1.0)
    errors = [
        abs(
            bar_frequencies(1.0, E, 1.0, left=Attachment.mass_spring(m, k), right="free", count=1)[
                0
            ]
            / w_rigid
            - 1
        )
        for E in (1e3, 1e4, 1e5)
    ]
    assert errors[0] < 1e-3 and errors[2] < 1e-5
    assert errors[0] / errors[1] == pytest.approx(10.0, rel=0.02)


def test_first_mode_decay_rate_under_velocity_feedback():
    """The exact root's decay rate tends to the modal formula as the gain goes to 0 (the error
    is of second order in the gain); the second mode, whose base and tip move in antiphase,
    is destabilized (spillover), the uncontrolled modes are undamped."""
    setup = dict(base_mass=1.0, base_stiffness=50.0)
    free = controlled_bar_roots(1.0, 100.0, 1.0, count=2, **setup)
    assert np.abs(free.real).max() < 1e-10 * np.abs(free).max()
    ratios = []
    for kv in (0.2, 0.05):
        H = lambda s, kv=kv: kv * s  # noqa: E731
        roots = controlled_bar_roots(1.0, 100.0, 1.0, H=H, count=2, **setup)
        ratios.append(-roots[0].real / first_mode_decay_rate(1.0, 100.0, 1.0, H=H, **setup))
        assert roots[0].real < 0 < roots[1].real
    assert abs(ratios[1] - 1) < 1e-5 and abs(ratios[0] - 1) / abs(ratios[1] - 1) > 8
    # PD with a filtered derivative: the derivative part adds inertia, not damping, to first
    # order; the decay comes from kp
    H = lambda s: s * (0.05 + 0.01 * s / (1 + 1e-3 * s))  # noqa: E731
    alpha = first_mode_decay_rate(1.0, 100.0, 1.0, H=H, **setup)
    roots = controlled_bar_roots(1.0, 100.0, 1.0, H=H, count=1, **setup)
    assert -roots[0].real == pytest.approx(alpha, rel=0.05)


def test_bad_frequency_input_is_one_line():
    for make, message in [
        (
            lambda: bar_frequencies(1.0, 1.0, 1.0, left="free"),
            r"^left: got 'free', and right both free: the bar is not held",
        ),
        (
            lambda: bar_frequencies(1.0, 1.0, 1.0, right="hinged"),
            r"^right: got 'hinged', must be 'clamped', 'free' or an Attachment$",
        ),
        (
            lambda: Attachment(np.eye(2), np.zeros((2, 2)), at=2),
            r"^at: got 2, must be a coordinate index 0\.\.1$",
        ),
        (lambda: tip_mass_roots(-1.0), r"^mass_ratio: got -1, must be > 0$"),
    ]:
        with pytest.raises(RotheInputError, match=message):
            make()


# -- a bar of slices of different materials (the transfer matrix, issue 19) ---------------------


def test_sliced_bar_of_one_material_is_the_bar():
    tip = Attachment.mass_spring(0.25, 0.0)
    bar = bar_frequencies(1.0, 100.0, 1.0, area=0.25, right=tip)
    for lengths in ([1.0], [0.3, 0.7], [0.25, 0.25, 0.5]):
        sliced = sliced_bar_frequencies(lengths, 100.0, 1.0, area=0.25, right=tip)
        assert np.allclose(sliced, bar, rtol=1e-12, atol=0), (lengths, sliced / bar - 1)
    # a mass-spring at x = 0, free at L; clamped-free: (2k - 1) pi c / (2 L)
    base = Attachment.mass_spring(1.0, 50.0)
    assert np.allclose(
        sliced_bar_frequencies([0.2, 0.8], 100.0, 1.0, left=base),
        bar_frequencies(1.0, 100.0, 1.0, left=base),
        rtol=1e-12,
    )
    assert np.allclose(
        sliced_bar_frequencies([0.5, 0.5], 100.0, 1.0), [5 * np.pi, 15 * np.pi, 25 * np.pi]
    )


def test_sliced_bar_against_the_fe_modal_analysis_of_a_strip_of_two_materials():
    """The tip-mass strip 1 x 0.25 (nu = 0, plane stress: an exact 1D bar axially) of E = 100,
    rho = 1 on x < 0.5 and E = 400, rho = 2 on x > 0.5 (a PiecewiseMaterial), tip mass 0.25:
    the semi-discrete axial frequencies (P2) converge to the transfer matrix's 9.0434, 48.480,
    72.214 like h^4 (relative errors 1.2e-6, 5.2e-4, 3.9e-3 on 4 x 1 cells, 9.0e-8, 4.1e-5,
    2.9e-4 on 8 x 2, 6.0e-9, 2.8e-6, 2.0e-5 on 16 x 4 measured)."""
    from rothe.eld.examples import tip_mass_problem
    from rothe.eld.materials import Material, PiecewiseMaterial

    def soft(x):
        return x[0] < 0.5

    def stiff(x):
        return x[0] >= 0.5

    material = PiecewiseMaterial(
        {
            "soft": Material.from_young(100.0, 0.0, 1.0, dim=2, plane="stress"),
            "stiff": Material.from_young(400.0, 0.0, 2.0, dim=2, plane="stress"),
        },
        regions={soft: "soft", stiff: "stiff"},
    )
    exact = sliced_bar_frequencies(
        [0.5, 0.5], [100.0, 400.0], [1.0, 2.0], area=0.25, right=Attachment.mass_spring(0.25, 0)
    )
    assert exact == pytest.approx([9.04337511, 48.4804926, 72.2144002], rel=1e-8)
    errors = [
        np.abs(tip_mass_problem(n, 2, material=material, T=0.5).discrete / exact - 1)
        for n in (1, 2)
    ]
    assert np.all(errors[0] < [2e-6, 1e-3, 5e-3]), errors[0]
    assert np.all(errors[1] < errors[0] / 10), errors  # h^4: 13.6, 12.7, 13.3 measured
    # the homogeneous bar's frequencies are not these (the check would pass for a wrong E)
    assert (
        abs(
            bar_frequencies(1.0, 100.0, 1.0, area=0.25, right=Attachment.mass_spring(0.25, 0))[0]
            / exact[0]
            - 1
        )
        > 0.04
    )


def test_sliced_bar_refusals():
    with pytest.raises(
        RotheInputError, match=r"^E: got \[1.0, 2.0\], must be one value or one per slice \(3\)"
    ):
        sliced_bar_frequencies([0.3, 0.3, 0.4], [1.0, 2.0], 1.0)
    with pytest.raises(RotheInputError, match=r"^lengths: got -0.3, must be > 0"):
        sliced_bar_frequencies([0.3, -0.3], 1.0, 1.0)
    with pytest.raises(RotheInputError, match=r"^rho: got 0, must be > 0"):
        sliced_bar_frequencies([0.5, 0.5], 1.0, [1.0, 0.0])
