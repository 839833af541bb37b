"""ParaView series and trajectory.npz of glued bodies (rothe.eld.bodies_output): fixed meshes,
an adaptive base (one VTU per state on its own mesh) and chains (the traction on a chain
interface from the body's residual). Files are read back with meshio; the attached bodies'
tractions from their residuals are checked against the multiplier route."""

import numpy as np
import pytest

meshio = pytest.importorskip("meshio")

from rothe.eld import BDF2, run_bodies  # noqa: E402
from rothe.eld.bodies_output import write_bodies_result  # noqa: E402
from rothe.fem.adapt import SpaceAdaptivity  # noqa: E402
from rothe.io.mesh_series import MeshSeries  # noqa: E402
from rothe.stepping.controllers import Uniform  # noqa: E402

from .test_bodies import SOFT, STIFF, _chain, _star, two_bodies  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore:G_d")


def _read_xdmf(path):
    """(times, [(point_data, cell_data)]) of an XDMF time series."""
    with meshio.xdmf.TimeSeriesReader(str(path)) as reader:
        points, _ = reader.read_points_cells()
        frames = [reader.read_data(k) for k in range(reader.num_steps)]
    return points, [f[0] for f in frames], [(f[1], f[2]) for f in frames]


def _traction_by_multiplier(glued, lam, k):
    """Attached body k's traction on its constrained dofs by the multiplier route: its nodal
    force f_2 = (Pi S)^T M_G lambda (:meth:`GluedBodies.interface_forces`), lambda_2 =
    -M_G2^{-1} f_2 there (zero on its clamped parts)."""
    _, f2 = glued.interface_forces(lam, k)
    c = glued.components[k].problem.constraint
    return -c.multiplier_from_residual(f2[c.dofs])


def _vertex_rows(space, points):
    """Row of every vertex of ``space``'s mesh in the XDMF points (3D, z = 0)."""
    p = np.asarray(points)[:, :2]
    order = {tuple(np.round(x, 12)): i for i, x in enumerate(p)}
    return np.array([order[tuple(np.round(x, 12))] for x in space.mesh.p.T])


def test_two_bodies_on_fixed_meshes_every_body_its_series(tmp_path):
    """Mortar interface (P1, 2 : 3 cells across): the attached body's traction from its
    residual equals the multiplier's at every state to 1e-12 (measured 1.9e-14); both bodies' XDMF
    series read back with u, v, stresses and lambda of the right shapes; body 2's displacement
    and traction at a vertex equal the trajectory's."""
    glued = two_bodies(SOFT, STIFF, ny=(2, 3))
    res = run_bodies(glued, scheme=BDF2(), control=Uniform(0.02))
    tr = res.trajectory
    (lam2,) = glued.interface_tractions(tr["t"], tr["q"], tr["p"], tr["pdot"])
    ref = np.array([_traction_by_multiplier(glued, lam, 0) for lam in tr["lam"]])
    assert lam2.shape == ref.shape and np.abs(ref).max() > 1e-2
    assert np.abs(lam2 - ref).max() <= 1e-12 * np.abs(ref).max()
    paths = write_bodies_result(res, glued, tmp_path)
    names = sorted(p.name for p in paths["xdmf"])
    assert names == ["one.xdmf", "one_multiplier.xdmf", "two.xdmf", "two_multiplier.xdmf"]
    data = np.load(paths["npz"])
    n = len(tr["t"])
    u2 = glued.fields(tr["u"], tr["q"])[1]
    assert data["two_u"].shape == (n, 2 * glued.problems()[1].space.n_scalar)
    np.testing.assert_array_equal(data["two_u"], u2)
    np.testing.assert_array_equal(data["two_lambda"], lam2)
    space2 = glued.problems()[1].space
    points, times, frames = _read_xdmf(tmp_path / "two.xdmf")
    np.testing.assert_allclose(times, tr["t"])
    point, cell = frames[-1]
    nv = space2.mesh.p.shape[1]
    assert point["u"].shape == (nv, 3) and point["v"].shape == (nv, 3)
    assert point["stress_nodal"].shape == (nv, 9) and cell["stress"][0].shape[1] == 9
    rows = _vertex_rows(space2, points)
    vertex = int(np.argmax(np.abs(u2[-1].reshape(-1, 2)[:nv, 1])))  # the largest deflection
    np.testing.assert_allclose(point["u"][rows[vertex], :2], u2[-1].reshape(-1, 2)[vertex])
    # the multiplier series on body 2's constrained facets (its glued part 'left')
    points, _, frames = _read_xdmf(tmp_path / "two_multiplier.xdmf")
    c = glued.problems()[1].constraint
    lam_nodes = lam2[-1].reshape(-1, 2)
    k = int(np.argmax(np.abs(lam_nodes[:, 0])))
    where = space2.doflocs[:, c.scalar_dofs[k]]
    hit = np.flatnonzero(np.abs(np.asarray(points)[:, :2] - where).max(axis=1) < 1e-12)
    assert hit.size == 1
    np.testing.assert_allclose(frames[-1][0]["lambda"][hit[0], :2], lam_nodes[k])


def test_a_chain_writes_every_body_and_its_chain_traction_is_the_stars_multiplier(tmp_path):
    """base - middle - tip with a mortar chain interface (the tip 3 cells across): the tip's
    traction on its glued part from its residual (no multiplier on a chain interface) equals
    the multiplier's in the same bodies glued as a star around the middle body (the tip glued
    to the base there) to solver tolerance; all three bodies' series are written."""
    glued = _chain(ny3=3)
    res = run_bodies(glued, scheme=BDF2(), control=Uniform(0.01))
    tr = res.trajectory
    star = _star()
    ref = run_bodies(star, scheme=BDF2(), control=Uniform(0.01)).trajectory
    _, tip = glued.interface_tractions(tr["t"], tr["q"], tr["p"], tr["pdot"])
    theirs = np.array([_traction_by_multiplier(star, lam, 1) for lam in ref["lam"]])
    assert np.abs(theirs).max() > 1e-2
    assert np.abs(tip - theirs).max() <= 1e-12 * np.abs(theirs).max()
    paths = write_bodies_result(res, glued, tmp_path)
    assert sorted(p.name for p in paths["xdmf"]) == [
        f"{b}{s}.xdmf" for b in ("one", "three", "two") for s in ("", "_multiplier")
    ]
    data = np.load(paths["npz"])
    np.testing.assert_array_equal(data["three_lambda"], tip)
    _, times, frames = _read_xdmf(tmp_path / "three_multiplier.xdmf")
    assert len(times) == len(tr["t"]) and frames[-1][0]["lambda"].shape[1] == 3
    assert np.abs(frames[-1][0]["lambda"]).max() == pytest.approx(np.abs(tip[-1]).max(), rel=1e-12)


def test_an_adaptive_base_writes_one_vtu_per_state_on_its_mesh(tmp_path):
    """The base adapts (fields kept on the mesh each state was computed on): one VTU per
    state with that mesh's vertices and the fields of the fixed-mesh series; the last one's u
    is the final state's; body 2 (fixed mesh) has its XDMF series, its traction from its
    residual equals the multiplier's on the last mesh (the last glue, mortar)."""
    glued = two_bodies(SOFT, STIFF, n=2, ny=(1, 1))
    res = run_bodies(
        glued,
        scheme=BDF2(),
        control=Uniform(0.01),
        adapt=SpaceAdaptivity(space_tol=2e-3, adapt_every=2, max_dofs=4000),
    )
    tr, meshes = res.trajectory, res.meshes
    assert "u" not in tr and len(meshes.kept["u"]) == len(tr["t"]) == len(tr["kept_t"])
    kept_ids = np.asarray(tr["kept_mesh_id"])
    assert np.unique(kept_ids).size >= 3
    assert np.array_equal(res.state.u, meshes.kept["u"][-1])
    paths = write_bodies_result(res, glued, tmp_path)
    assert paths["pvd"].name == "one.pvd"
    assert sorted(p.name for p in paths["xdmf"]) == ["two.xdmf", "two_multiplier.xdmf"]
    vtus = sorted(tmp_path.glob("one_*.vtu"))
    assert len(vtus) == len(tr["t"])
    for k in (0, len(vtus) // 2, len(vtus) - 1):
        m = meshio.read(vtus[k])
        points, cells = meshes.series.mesh(int(kept_ids[k]))
        assert m.points.shape[0] == len(points) and m.cells[0].data.shape == cells.shape
        for name, width in (("u", 3), ("v", 3), ("stress_nodal", 9), ("lambda", 3)):
            assert m.point_data[name].shape == (len(points), width), name
        assert m.cell_data["stress"][0].shape == (len(cells), 9)
    last = meshio.read(vtus[-1])
    u = res.state.u.reshape(-1, 2)[: len(last.points)]
    np.testing.assert_allclose(last.point_data["u"][:, :2], u)
    # the npz: every state's mesh, the kept fields with offsets
    data = np.load(paths["npz"])
    series, state_ids = MeshSeries.from_npz(data)
    np.testing.assert_array_equal(state_ids, tr["mesh_id"])
    off = data["kept_u_offsets"]
    np.testing.assert_array_equal(data["kept_u"][off[-2] : off[-1]], res.state.u)
    # body 2's traction on the last mesh: residual route = multiplier route (the last glue)
    st, s = res.stepper, res.state
    (lam2,) = glued.interface_tractions(tr["t"][-1:], tr["q"][-1:], tr["p"][-1:], tr["pdot"][-1:])
    comp = glued.components[0]
    f2 = np.zeros(comp.problem.space.ndofs)
    f2[comp.free] = st.system.generalized_reaction(s.lam)  # (E: the free dofs' selection)
    c2 = comp.problem.constraint
    ref = -c2.multiplier_from_residual(f2[c2.dofs])
    assert np.abs(ref).max() > 1e-3
    assert np.abs(lam2[0] - ref).max() <= 1e-12 * np.abs(ref).max()
    np.testing.assert_array_equal(data["two_lambda"][-1], lam2[0])
