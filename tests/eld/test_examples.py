"""``rothe.eld.examples``: the coupled examples of issue 19 (eld-tmd's cantilever, eld-control's
bar) with several materials (a PiecewiseMaterial; refused before: "material: got a
PiecewiseMaterial, must be one Material"): what sizes them stays defined for any material, the
predictions of a uniform strip are NaN with the reason."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rothe.eld.examples import (
    BEAM_THEORY_2D,
    NOT_SLICES,
    SEVERAL_MATERIALS,
    _clamped_frequency,
    axial_modulus,
    axial_slices,
    control_problem,
    rectangle,
    tip_mass_problem,
    tmd_problem,
)
from rothe.eld.frequencies import Attachment, sliced_bar_frequencies
from rothe.eld.materials import Material, PiecewiseMaterial
from rothe.errors import RotheInputError
from rothe.fem.mesh import box

#: the strips' single materials (eld-tmd, eld-control)
TMD = Material.from_young(1e4, 0.0, 1.0, dim=2, plane="stress")
BAR = Material.from_young(100.0, 0.0, 1.0, dim=2, plane="stress")


def _halves(left: Material, right: Material, split: float) -> PiecewiseMaterial:
    """``left`` at cell centroids x < split, ``right`` elsewhere."""

    def core(x):
        return x[0] < split

    def shell(x):
        return x[0] >= split

    return PiecewiseMaterial({"a": left, "b": right}, regions={core: "a", shell: "b"})


def test_clamped_frequency_is_the_discrete_cantilever_near_euler_bernoulli():
    """w_c of the default eld-tmd strip (1 x 0.1, P2, 20 x 2): the first bending mode of the
    clamped strip, 0.6 % below the Euler-Bernoulli 1.8751^2 sqrt(E I/(rho A))/L^2 = 10.1499
    (shear and the 2D section lower it); the same value on every call (Lanczos from ones)."""
    mesh = rectangle(20, 2, 1.0, 0.1)
    w = _clamped_frequency(mesh, TMD, 2, "left")
    eb = 1.8751040687**2 * math.sqrt(1e4 * 0.1**3 / 12 / 0.1)
    assert eb == pytest.approx(10.1499, abs=1e-4)
    assert -0.01 < w / eb - 1 < -0.003
    assert _clamped_frequency(mesh, TMD, 2, "left") == w
    # several materials: a stiffer tip half raises it, a heavier one lowers it
    stiff = _clamped_frequency(mesh, _halves(TMD, Material(1.0, 0.0, 3e4, plane="stress"), 0.5), 2,
                               "left")  # fmt: skip
    heavy = _clamped_frequency(mesh, _halves(TMD, Material(2.0, 0.0, 5e3, plane="stress"), 0.5), 2,
                               "left")  # fmt: skip
    assert stiff > w > heavy


def test_tmd_with_one_material_in_two_regions_is_the_one_material_example():
    """A PiecewiseMaterial whose regions share the strip's material: the same support, plate,
    absorber (w_1, m_1, k, c, w_c to round-off), the beam formula NaN with the reason; with a
    heavier tip half the strip's mass (the support's and the plate's) is sum rho_c |c|."""
    one = tmd_problem(2, 2, material=TMD, T=0.1)
    two = tmd_problem(2, 2, material=_halves(TMD, TMD, 0.5), T=0.1)
    for key in ("frequency", "modal_mass", "stiffness", "damping", "forcing", "clamped_frequency"):
        assert getattr(two, key) == pytest.approx(getattr(one, key), rel=1e-10), key
    assert one.prediction is None and one.beam_frequency == pytest.approx(10.1499, abs=1e-4)
    assert two.prediction == SEVERAL_MATERIALS and math.isnan(two.beam_frequency)
    heavy = tmd_problem(2, 2, material=_halves(TMD, Material(3.0, 0.0, 5e3, plane="stress"), 0.5))
    base = heavy.with_tmd.components[0]
    assert base.mass[0, 0] == pytest.approx(0.2, rel=1e-12)  # 0.05 + 0.15
    assert heavy.frequency < one.frequency


def test_control_with_several_materials_has_nan_predictions_and_the_discrete_frequency():
    """eld-control's bar with one material in two regions: the same discrete w_1 and start
    mode, the uniform bar's roots and modal rate NaN with the reason (one material: finite)."""
    one = control_problem(2, 2, material=BAR, T=0.1)
    two = control_problem(2, 2, material=_halves(BAR, BAR, 0.5), T=0.1)
    assert two.frequency == pytest.approx(one.frequency, rel=1e-10)
    assert np.allclose(two.controlled.components[0].q0, one.controlled.components[0].q0, rtol=1e-8)
    assert one.prediction is None and np.isfinite(one.roots).all()
    assert two.prediction == SEVERAL_MATERIALS
    for value in (two.roots, two.roots_uncontrolled, two.roots_undamped, two.modal_rate):
        assert np.isnan(value).all()


# -- the tip-mass bar of several materials: slices along x (branch slice19) ------------------


def _bands(materials: dict, edges, axis: int = 0) -> PiecewiseMaterial:
    """materials[names[i]] on the cells with centroid coordinate ``axis`` in
    [edges[i], edges[i + 1]) -- ``names`` the keys in order, repeated names allowed."""
    names = list(materials)

    def band(lo, hi):
        def inside(x):
            return (x[axis] >= lo) & (x[axis] < hi)

        inside.__name__ = f"band_{lo:g}_{hi:g}"
        return inside

    bands = zip(edges[:-1], edges[1:], strict=True)
    regions = {band(lo, hi): names[i % len(names)] for i, (lo, hi) in enumerate(bands)}
    return PiecewiseMaterial(materials, regions=regions)


SOFT = BAR
STIFF = Material.from_young(400.0, 0.0, 2.0, dim=2, plane="stress")


def test_axial_slices_of_a_strip():
    """Slices are found per material from the cells' x-extents: A B A (one material in two
    slices) in order, a layer split across y refused (overlapping x-intervals), the bounds
    exact to round-off."""
    mesh = rectangle(8, 2, 1.0, 0.25)
    slices = axial_slices(mesh, _bands({"a": SOFT, "b": STIFF}, [0, 0.25, 0.75, 1.01]))
    assert [(s["material"], s["x"]) for s in slices] == [
        ("a", [0.0, 0.25]), ("b", [0.25, 0.75]), ("a", [0.75, 1.0]),
    ]  # fmt: skip
    assert [s["modulus"] for s in slices] == [100.0, 400.0, 100.0]
    layers = axial_slices(mesh, _bands({"a": SOFT, "b": STIFF}, [0, 0.125, 1], axis=1))
    assert layers == f"{NOT_SLICES}: their intervals of x overlap or leave gaps"
    # the tip on the left: the slices from the clamped end (x = 1) to the tip (x = 0)
    flipped = axial_slices(mesh, _bands({"a": SOFT, "b": STIFF}, [0, 0.5, 1.01]), tip="left")
    assert [(s["material"], s["x"]) for s in flipped] == [("b", [0.5, 1.0]), ("a", [0.0, 0.5])]


def test_axial_slices_take_each_slices_axial_modulus():
    """Plane strain: E/(1 - nu^2) per slice, as the one-material bar (plane stress and 3D: E)."""
    strain = {
        "a": Material.from_young(100.0, 0.3, 1.0, dim=2, plane="strain"),
        "b": Material.from_young(400.0, 0.2, 2.0, dim=2, plane="strain"),
    }
    slices = axial_slices(rectangle(8, 2, 1.0, 0.25), _bands(strain, [0, 0.5, 1.01]))
    assert [s["modulus"] for s in slices] == pytest.approx([100 / 0.91, 400 / 0.96], rel=1e-14)
    assert [axial_modulus(m, 2) for m in strain.values()] == [s["modulus"] for s in slices]
    assert axial_modulus(strain["a"], 3) == pytest.approx(100.0, rel=1e-14)


def test_tip_mass_clamped_on_the_right_orders_the_slices_from_the_clamp():
    """The strip clamped on 'right', the mass on 'left': the sliced bar from the stiff half
    (the clamped end) to the soft one -- 11.404, 41.622, 70.779, not the 9.0434, 48.480, 72.214
    of the other way round; the discrete frequencies agree to 3.1e-4 (P2, 8 x 2)."""
    material = _bands({"soft": SOFT, "stiff": STIFF}, [0, 0.5, 1.01])
    example = tip_mass_problem(2, 2, material=material, clamp=("right",), tip="left", T=0.5)
    assert example.prediction == "sliced bar"
    assert [s["material"] for s in example.slices] == ["stiff", "soft"]
    expected = sliced_bar_frequencies(
        [0.5, 0.5], [400.0, 100.0], [2.0, 1.0], area=0.25, right=Attachment.mass_spring(0.25, 0)
    )
    assert np.array_equal(example.analytic, expected)
    assert expected == pytest.approx([11.40411705, 41.62189237, 70.7786088], rel=1e-8)
    assert np.all(np.abs(example.discrete / example.analytic - 1) < [1e-6, 1e-4, 1e-3])


# -- the discrete closed loop's roots (closed_loop_roots): a prediction for any material ------


def test_control_discrete_roots_converge_to_the_uniform_bar_roots():
    """The eigenvalues of the semi-discrete closed loop (body on the constraint, base, the
    feedback's non-symmetric terms) near the first two axial modes tend to the roots of the
    uniform bar's characteristic equation as h -> 0: P1 on 8 x 2 and 16 x 4 cells, measured
    |ds|/|s| 6.1e-5 -> 1.6e-5 (s_1) and 1.9e-3 -> 3.9e-4 (s_2), i.e. h^2; the uncontrolled
    roots likewise."""
    errors = []
    for n in (2, 4):
        ex = control_problem(n, 1, T=0.1)
        assert ex.prediction is None
        rel = np.abs(ex.roots_discrete - ex.roots) / np.abs(ex.roots)
        free = np.abs(ex.roots_discrete_uncontrolled - ex.roots_uncontrolled)
        assert (rel < [1e-4, 3e-3]).all() and (free / np.abs(ex.roots_uncontrolled) < 3e-3).all()
        errors.append(rel)
    ratio = errors[0] / errors[1]
    assert (ratio > 3).all() and (ratio < 5.5).all(), ratio  # (h^2: 4)
    assert -ex.roots_discrete[0].real == pytest.approx(0.46322, rel=1e-4)


@pytest.mark.parametrize(
    "gain, b, rate",
    [(0.0, 0.0, 0.0), (0.0, 0.005, 0.0032968), (-1.0, 0.005, -0.45508), (1.0, 0.005, 0.46322)],
)
def test_control_discrete_rate_of_zero_negative_and_positive_gain(gain, b, rate):
    """No feedback and no damping: Re s = 0 to round-off (the loop is then the undamped
    symmetric system); no feedback: the material damping's rate, the controlled loop's root
    equal to the uncontrolled one; a negative gain: a negative rate (the mode grows), the
    uniform bar's root to 1e-4 as a positive one. P2, 4 x 1 cells."""
    ex = control_problem(1, 2, gain=gain, b=b, T=0.1)
    s = ex.roots_discrete
    if rate == 0.0:
        assert np.abs(s.real).max() < 1e-12 * np.abs(s).max()
    else:
        assert -s[0].real == pytest.approx(rate, rel=1e-4)
    assert -s[0].real == pytest.approx(-ex.roots[0].real, rel=1e-4, abs=1e-14)
    if gain == 0.0:
        assert np.allclose(s, ex.roots_discrete_uncontrolled, rtol=1e-10)


def test_control_discrete_roots_with_a_filter_state():
    """k_d > 0 adds the controller's state z (the filtered derivative, T_f = 0.02): the loop
    has 2N + 1 unknowns; its first root is the uniform bar's with H = s (k_p + k_d s/(1 + T_f s))
    (measured rate 0.45280 both)."""
    ex = control_problem(1, 2, kd=0.05, T=0.1)
    assert np.abs(ex.roots_discrete - ex.roots).max() < 1e-4 * np.abs(ex.roots).max()
    assert -ex.roots_discrete[0].real == pytest.approx(0.45280, rel=1e-4)


def test_control_discrete_roots_with_several_materials_are_defined():
    """A stiffer, heavier tip half (E 3x, rho 2x): the uniform bar's roots NaN, the discrete
    loop's finite -- lower in frequency and damped more slowly than the uniform bar's (the
    tip half heavier) -- and with equal halves the one-material roots to round-off."""
    one = control_problem(1, 2, material=BAR, T=0.1)
    same = control_problem(1, 2, material=_halves(BAR, BAR, 0.5), T=0.1)
    assert np.allclose(same.roots_discrete, one.roots_discrete, rtol=1e-10)
    hard = Material.from_young(300.0, 0.0, 2.0, dim=2, plane="stress")
    two = control_problem(1, 2, material=_halves(BAR, hard, 0.5), T=0.1)
    assert np.isnan(two.roots).all() and np.isfinite(two.roots_discrete).all()
    s1 = two.roots_discrete[0]
    assert 5.7 < s1.imag < 5.9 and 0.40 < -s1.real < 0.43  # (measured 5.8125, 0.41750 on 8 x 2)
    assert s1.imag < one.roots_discrete[0].imag


# -- eld-tmd and eld-control on 3D bodies (refused before: "mesh: got a 3D mesh ..., must be
# 2D (this example's support and tip plate are plane)") ------------------------------------------


def test_tmd_on_a_3d_bar_tunes_to_either_transverse_axis_of_a_square_section():
    """The 3D bar 1 x 0.1 x 0.1 (8 cubes x 6 tetrahedra, P2) along x: its first bending modes
    in y and z are one eigenvalue (a square section), split in the solver's basis at will; the
    absorber along y or z is tuned to the same w_1 and m_1 (the combination with the largest
    a_direction, :func:`_bending_mode_3d`), and the plate carries a_x..theta_z and s. The
    Euler-Bernoulli comparison is NaN with its reason; w_c is the clamped body's."""
    mesh = box(8, 1, 1, 1.0, 0.1, 0.1)
    along_y = tmd_problem(mesh=mesh, T=0.1)
    along_z = tmd_problem(mesh=mesh, T=0.1, direction=2)
    assert along_y.frequency == pytest.approx(along_z.frequency, rel=1e-9)
    assert along_y.modal_mass == pytest.approx(along_z.modal_mass, rel=1e-9)
    # (measured: w_1 = 9.1411, w_c = 10.096 against the 2D strip's 10.085)
    assert 9.0 < along_y.frequency < along_y.clamped_frequency < 10.2
    # m_1 with a_y = 1: between the plate's mass and the bar's with its base (4 x 0.01)
    assert 0.05 * 0.01 < along_y.modal_mass < 0.04
    plate = along_y.with_tmd.components[1]
    assert plate.coordinates[-1] == "absorber_y" and plate.size == 7
    assert along_z.with_tmd.components[1].coordinates[-1] == "absorber_z"
    assert math.isnan(along_y.beam_frequency) and along_y.prediction == BEAM_THEORY_2D
    with pytest.raises(RotheInputError, match="direction: got 0, must be an axis 0..2 of the 3D"):
        tmd_problem(mesh=mesh, direction=0)


def test_control_on_a_3d_bar_has_the_bar_roots_of_its_section():
    """The 3D bar 1 x 0.25 x 0.25 (4 cubes, P2, nu = 0): the axial motion is the 1D bar's of
    area A = volume / L, so the uniform bar's roots hold and the discrete closed loop's agree
    with them (measured 2e-6 in the rate of the first mode)."""
    ex = control_problem(mesh=box(4, 1, 1, 1.0, 0.25, 0.25), T=0.1)
    assert ex.prediction is None and ex.height == pytest.approx(0.0625, rel=1e-12)
    assert ex.roots_discrete[0].real == pytest.approx(ex.roots[0].real, rel=1e-4)
    assert ex.roots_discrete[0].imag == pytest.approx(ex.roots[0].imag, rel=1e-4)
    assert ex.controlled.components[0].size == 3
