"""The space indicator of a body of several materials (per-cell lam, mu, rho) and space-adaptive
runs of such bodies: equal per-cell constants give the one-material indicator, the exact
two-material bar has a zero indicator with its own constants (and not with one material), an
adaptive run keeps every cell's material through refinement and coarsening (the region carried
from the root cell), plain and coupled."""

from __future__ import annotations

import numpy as np
import pytest
from skfem import MeshTri

from rothe.eld import BDF2, ELDProblem, Material, PiecewiseMaterial, run_eld
from rothe.eld.components import MassSpringDamper
from rothe.eld.coupled_run import run_coupled
from rothe.eld.coupling import CoupledProblem, Translation
from rothe.eld.indicator import eld_indicators, eld_indicators_for
from rothe.errors import RotheInputError
from rothe.fem.adapt import SpaceAdaptivity
from rothe.fem.elasticity import VectorSpace
from rothe.fem.mesh import tag_box_faces
from rothe.stepping.controllers import Uniform

pytestmark = pytest.mark.filterwarnings("ignore:G_d")

H = 0.25
SOFT = Material.from_young(100.0, 0.0, rho=1.0, dim=2, plane="stress")
STIFF = Material.from_young(400.0, 0.0, rho=3.0, dim=2, plane="stress")


def _bar(nx=8, ny=2):
    """[0, 1] x [0, H], the cells left of x = 0.5 'soft', right of it 'stiff'."""
    mesh = tag_box_faces(MeshTri.init_tensor(np.linspace(0, 1, nx + 1), np.linspace(0, H, ny + 1)))
    cx = mesh.p[0, mesh.t].mean(axis=0)
    return mesh.with_subdomains(
        {"soft": np.flatnonzero(cx < 0.5), "stiff": np.flatnonzero(cx > 0.5)}
    )


def _zero(t, x):
    return 0 * x


MATERIALS = PiecewiseMaterial({"soft": SOFT, "stiff": STIFF})


@pytest.mark.parametrize("degree", [1, 2])
def test_equal_per_cell_constants_give_the_one_material_indicator(degree):
    mesh = _bar()
    space = VectorSpace(mesh, degree)
    rng = np.random.default_rng(3)
    u, a = rng.standard_normal((2, space.ndofs))
    nc = mesh.t.shape[1]
    common = dict(accel=a, traction={"right": lambda x, n: 0 * x}, dirichlet_parts=("left",))
    one = eld_indicators(mesh, degree, 1.5, 2.0, u, rho=3.0, reaction=50.0, **common)
    per = eld_indicators(
        mesh,
        degree,
        np.full(nc, 1.5),
        np.full(nc, 2.0),
        u,
        rho=np.full(nc, 3.0),
        reaction=np.full(nc, 50.0),
        **common,
    )
    np.testing.assert_allclose(per.eta, one.eta, rtol=1e-14, atol=0)
    assert one.eta.max() > 0
    with pytest.raises(RotheInputError, match=r"^mu: got an array of shape \(3,\), must be"):
        eld_indicators(mesh, degree, 1.5, np.ones(3), u)
    with pytest.raises(RotheInputError, match=r"^mu: got an array of shape .* positive values"):
        eld_indicators(mesh, degree, 1.5, np.zeros(nc), u)


def test_the_exact_two_material_bar_has_a_zero_indicator():
    """A bar pulled by g on its right end, clamped on the left: sigma_xx = g in both materials,
    u_x piecewise linear with its kink on x = 0.5 (a mesh line). P1 interpolates it exactly:
    with each cell's constants the indicator is round-off; with one material the interface
    jump and the end's traction mismatch are seen."""
    g = 0.3
    mesh = _bar()
    problem = ELDProblem(
        mesh,
        MATERIALS,
        dirichlet={"left": _zero},
        traction={"right": lambda t, x, n: np.stack([g + 0 * x[0], 0 * x[0]])},
    )
    E1, E2 = 100.0, 400.0  # (nu = 0, plane stress: sigma_xx = E eps_xx)
    x = problem.space.doflocs[0]
    ux = np.where(x < 0.5, g * x / E1, g * (0.5 / E1 + (x - 0.5) / E2))
    u = np.stack([ux, 0 * ux], axis=1).ravel()
    eta = eld_indicators_for(problem, 0.0, u).eta
    assert np.sqrt(np.sum(eta**2)) < 1e-12 * g
    one = eld_indicators(
        mesh,
        1,
        SOFT.lam_eff,
        SOFT.mu,
        u,
        traction={"right": lambda x, n: np.stack([g + 0 * x[0], 0 * x[0]])},
        dirichlet_parts=("left",),
    ).eta
    assert np.sqrt(np.sum(one**2)) > 1e-2 * g / np.sqrt(SOFT.mu)


def _adaptive(run, system, problem, ledger: str):
    """Run ``system`` (run_eld or run_coupled) with BDF2, tau = 0.01 and space_tol 3e-3: at
    least 3 meshes, the ledger ``ledger`` closed, every cell of the final mesh (``problem``
    of the result) of the material of its centroid's side of x = 0.5. Returns the result."""
    res = run(
        system,
        scheme=BDF2(),
        control=Uniform(0.01),
        adapt=SpaceAdaptivity(space_tol=3e-3, max_dofs=5000),
    )
    tr = res.trajectory
    assert len(set(np.asarray(tr["mesh_id"]).tolist())) >= 3
    assert np.abs(tr[ledger]).max() <= 1e-10 * np.abs(tr["energy"]).max()
    final = problem(res)
    mesh = final.space.mesh
    cx = mesh.p[0, mesh.t].mean(axis=0)
    names = list(MATERIALS.names)
    want = np.where(cx < 0.5, names.index("soft"), names.index("stiff"))
    np.testing.assert_array_equal(final.cell_material.names, want)
    return res


def test_an_adaptive_run_of_two_materials_keeps_every_cells_material():
    problem = ELDProblem(
        _bar(),
        MATERIALS,
        degree=1,
        dirichlet={"left": _zero},
        traction={"right": lambda t, x, n: np.stack([0 * x[0], np.sin(8 * t) ** 2 + 0 * x[0]])},
        T=0.3,
    )
    res = _adaptive(run_eld, problem, lambda r: r.stepper.system.problem, "balance_residual")
    final = res.stepper.system.problem
    assert final.space.mesh.t.shape[1] > problem.space.mesh.t.shape[1]


def test_a_coupled_run_of_two_materials_adapts():
    problem = ELDProblem(
        _bar(), MATERIALS, degree=1, dirichlet={"left": _zero}, traction=None, T=0.1
    )
    tip = MassSpringDamper(0.2, [30.0, 30.0], 0.0, name="tip", p0=[0.0, 0.5])
    system = CoupledProblem(problem, [tip], [Translation("right", tip)])
    res = _adaptive(run_coupled, system, lambda r: r.stepper.body, "balance")
    assert res.trajectory["constraint"].max() <= 1e-10
