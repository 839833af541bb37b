"""Glued bodies stepped in time (rothe.eld.bodies): two bodies with matching meshes equal one
body on the union mesh (one material, two materials, three bodies), action = reaction, the
whole-system ledger, BDF2's order, mortar interfaces converge to the matching result, and
one-line refusals."""

import numpy as np
import pytest
from scipy.spatial import cKDTree
from skfem import MeshTri

from rothe.eld import (
    BDF2,
    Body,
    ELDProblem,
    GluedBodies,
    ImplicitEuler,
    Material,
    Original,
    PiecewiseMaterial,
    run_bodies,
    run_eld,
)
from rothe.errors import RotheInputError
from rothe.fem.mesh import tag_box_faces
from rothe.stepping.controllers import Adaptive, Uniform

H = 0.25
SOFT = Material.from_young(100.0, 0.3, rho=1.0, dim=2)
STIFF = Material.from_young(300.0, 0.2, rho=2.0, dim=2)


def strip(x0, x1, nx, ny):
    return tag_box_faces(
        MeshTri.init_tensor(np.linspace(x0, x1, nx + 1), np.linspace(0, H, ny + 1))
    )


def pull(t, x, n):
    """A smooth transverse traction on the free end: 0.5 sin^2(pi t) e_y."""
    out = np.zeros_like(x)
    out[1] = 0.5 * np.sin(np.pi * t) ** 2
    return out


def zero(t, x):
    return 0.0 * x


def two_bodies(mat1, mat2, *, n=4, ny=(2, 2), degree=1, method="auto", T=0.5):
    return GluedBodies(
        Body(strip(0, 0.5, n, ny[0]), mat1, degree=degree, clamped=("left",), name="one"),
        [
            (
                Body(
                    strip(0.5, 1.0, n, ny[1]),
                    mat2,
                    degree=degree,
                    traction={"right": pull},
                    name="two",
                ),
                "right",
                "left",
            )
        ],
        method=method,
        T=T,
    )


def union(mat1, mat2, *, n=4, degree=1, T=0.5, cuts=(0.5,)):
    """The single body on [0, 1] x [0, H] with mat1 left of the first cut, mat2 right."""
    xs = np.linspace(0, 1, 2 * n + 1)
    mesh = tag_box_faces(MeshTri.init_tensor(xs, np.linspace(0, H, 3)))
    cx = mesh.p[0, mesh.t].mean(axis=0)
    if mat1 is mat2:
        material = mat1
    else:
        mesh = mesh.with_subdomains(
            {"a": np.flatnonzero(cx < cuts[0]), "b": np.flatnonzero(cx > cuts[0])}
        )
        material = PiecewiseMaterial({"m1": mat1, "m2": mat2}, regions={"a": "m1", "b": "m2"})
    with pytest.warns(UserWarning):  # (zero data: G_dot by differences, error 0)
        return ELDProblem(
            mesh,
            material,
            degree=degree,
            dirichlet={"left": zero},
            traction={"right": pull},
            T=T,
        )


def at(space_from, u_from, points):
    """u_from (interleaved dofs of space_from) at the dof points ``points`` (d, k)."""
    k = cKDTree(space_from.doflocs.T).query(points.T)[1]
    return u_from.reshape(-1, 2)[k]


@pytest.mark.parametrize(
    "mat2,scheme,form,degree",
    [
        (SOFT, BDF2(), None, 1),
        (STIFF, BDF2(), None, 2),
        (STIFF, ImplicitEuler(), Original(), 1),
    ],
)
def test_two_glued_bodies_equal_the_union_mesh_run(mat2, scheme, form, degree):
    """Matching meshes: the glued run is the single-body run on the union mesh (per-cell
    materials for two materials) to solver tolerance: displacements at every node, energy."""
    glued = two_bodies(SOFT, mat2, degree=degree)
    opts = {"scheme": scheme, "control": Uniform(0.01)}
    if form is not None:
        opts["form"] = form
    res = run_bodies(glued, **opts)
    prob = union(SOFT, mat2, degree=degree)
    one = run_eld(prob, **opts)
    U = one.state.u
    scale = np.abs(U).max()
    assert scale > 1e-3  # the load bends the strip
    for u, (_, space) in zip(glued.fields(res.state.u, res.state.q), glued.bodies(), strict=True):
        ref = at(prob.space, U, space.doflocs)
        assert np.abs(u.reshape(-1, 2) - ref).max() < 1e-10 * scale
    E_glued = res.trajectory["energy"]
    E_one = np.asarray(one.trajectory["energy"])
    assert np.abs(E_glued - E_one).max() < 1e-10 * E_one.max()


def test_three_bodies_glued_to_a_base_equal_the_union_mesh_run():
    """Bodies on both sides of the base (a star: each interface joins the base): the left one
    clamped, the right one loaded; the union mesh with three materials."""
    base = Body(strip(1 / 3, 2 / 3, 3, 2), STIFF, name="middle")
    left = Body(strip(0, 1 / 3, 3, 2), SOFT, clamped=("left",), name="left")
    right = Body(strip(2 / 3, 1, 3, 2), SOFT, traction={"right": pull}, name="right")
    glued = GluedBodies(base, [(left, "left", "right"), (right, "right", "left")], T=0.3)
    res = run_bodies(glued, scheme=BDF2(), control=Uniform(0.01))
    mesh = tag_box_faces(MeshTri.init_tensor(np.linspace(0, 1, 10), np.linspace(0, H, 3)))
    cx = mesh.p[0, mesh.t].mean(axis=0)
    mesh = mesh.with_subdomains(
        {"mid": np.flatnonzero(abs(cx - 0.5) < 1 / 6), "out": np.flatnonzero(abs(cx - 0.5) > 1 / 6)}
    )
    material = PiecewiseMaterial({"s": STIFF, "o": SOFT}, regions={"mid": "s", "out": "o"})
    with pytest.warns(UserWarning):
        prob = ELDProblem(mesh, material, dirichlet={"left": zero}, traction={"right": pull}, T=0.3)
    one = run_eld(prob, scheme=BDF2(), control=Uniform(0.01))
    U = one.state.u
    for u, (_, space) in zip(glued.fields(res.state.u, res.state.q), glued.bodies(), strict=True):
        assert (
            np.abs(u.reshape(-1, 2) - at(prob.space, U, space.doflocs)).max() < 1e-10 * abs(U).max()
        )
    assert np.abs(res.trajectory["balance"]).max() < 1e-13 * res.trajectory["energy"].max()


def _star():
    """The bodies of :func:`_chain` with 3 cells across the tip, glued as a star around the
    middle body (both interfaces by multipliers, the tip's a mortar one)."""
    return GluedBodies(
        Body(strip(1 / 3, 2 / 3, 3, 2), STIFF, name="two"),
        [
            (Body(strip(0, 1 / 3, 3, 2), SOFT, clamped=("left",), name="one"), "left", "right"),
            (
                Body(strip(2 / 3, 1, 3, 3), SOFT, traction={"right": pull}, name="three"),
                "right",
                "left",
            ),
        ],
        T=0.3,
    )


def _chain(ny3=2, T=0.3):
    """base (clamped) - middle - tip (pulled): the tip glued to the middle body, not to the
    base (body 2 to body 1)."""
    base = Body(strip(0, 1 / 3, 3, 2), SOFT, clamped=("left",), name="one")
    middle = Body(strip(1 / 3, 2 / 3, 3, 2), STIFF, name="two")
    tip = Body(strip(2 / 3, 1, 3, ny3), SOFT, traction={"right": pull}, name="three")
    return GluedBodies(base, [(middle, "right", "left"), (tip, "right", "left", 1)], T=T)


def test_a_chain_of_three_bodies_equals_the_union_mesh_run():
    """base - 1 - 2 (the tip glued to the middle body: its glue substituted into the middle
    body's component): the union mesh with the stiff middle third to solver tolerance at
    every node of every body and in the energy; the ledger closes; the chain's interface holds
    to round-off at every state, the base's too."""
    glued = _chain()
    assert len(glued.components) == 1 and len(glued.chains) == 1
    assert [name for name, _ in glued.bodies()] == ["one", "two", "three"]
    comp = glued.components[0]
    assert [name for name, _, _ in comp.maps] == ["two", "three"]
    res = run_bodies(glued, scheme=BDF2(), control=Uniform(0.01))
    mesh = tag_box_faces(MeshTri.init_tensor(np.linspace(0, 1, 10), np.linspace(0, H, 3)))
    cx = mesh.p[0, mesh.t].mean(axis=0)
    mesh = mesh.with_subdomains(
        {"mid": np.flatnonzero(abs(cx - 0.5) < 1 / 6), "out": np.flatnonzero(abs(cx - 0.5) > 1 / 6)}
    )
    material = PiecewiseMaterial({"s": STIFF, "o": SOFT}, regions={"mid": "s", "out": "o"})
    with pytest.warns(UserWarning):
        prob = ELDProblem(mesh, material, dirichlet={"left": zero}, traction={"right": pull}, T=0.3)
    one = run_eld(prob, scheme=BDF2(), control=Uniform(0.01))
    U = one.state.u
    assert np.abs(U).max() > 1e-3
    fields = glued.fields(res.state.u, res.state.q)
    for u, (_, space) in zip(fields, glued.bodies(), strict=True):
        assert (
            np.abs(u.reshape(-1, 2) - at(prob.space, U, space.doflocs)).max() < 1e-10 * abs(U).max()
        )
    E, E1 = res.trajectory["energy"], np.asarray(one.trajectory["energy"])
    assert np.abs(E - E1).max() < 1e-10 * E1.max()
    assert glued.describe()["chains"][0]["method"] == "matching"
    tr = res.trajectory
    assert np.abs(tr["balance"]).max() < 1e-13 * tr["energy"].max()
    assert tr["constraint"].max() < 1e-13
    u, q = np.asarray(tr["u"]), np.asarray(tr["q"])
    assert max(glued.interface_residual(u[i], q[i]) for i in range(len(u))) < 1e-14
    # the body loads of the chain reach the base through body 1: the clamp holds them all
    assert abs(tr["work_components"][-1]) > 0
    # (the chain's ParaView series and its interface traction: tests/eld/test_bodies_output.py)


def test_a_non_matching_chain_interface_is_glued_by_the_mortar_projection():
    """The tip with 3 cells across against the middle body's 2: the chain's glue is the mortar
    Pi, substituted. The same discrete problem as the star with the middle body as the base
    (the clamped body and the tip glued to it: the same interfaces, the middle body side 1 of
    the mortar one, the multiplier route instead of the substitution): equal to solver
    tolerance at every node, in the energy; the interfaces hold, the ledger closes."""
    glued = _chain(ny3=3)
    assert glued.chains[0].method == "mortar"
    res = run_bodies(glued, scheme=BDF2(), control=Uniform(0.01))
    tr = res.trajectory
    assert np.abs(tr["balance"]).max() < 1e-13 * tr["energy"].max()
    assert glued.interface_residual(res.state.u, res.state.q) < 1e-13
    star = _star()
    assert star.interfaces[1].method == "mortar"
    ref = run_bodies(star, scheme=BDF2(), control=Uniform(0.01))
    mine = {
        n: w
        for (n, _), w in zip(glued.bodies(), glued.fields(res.state.u, res.state.q), strict=True)
    }
    theirs = {
        n: w for (n, _), w in zip(star.bodies(), star.fields(ref.state.u, ref.state.q), strict=True)
    }
    scale = max(np.abs(w).max() for w in theirs.values())
    assert scale > 1e-3
    for name, w in theirs.items():
        assert np.abs(mine[name] - w).max() < 1e-10 * scale, name
    E, E1 = tr["energy"], np.asarray(ref.trajectory["energy"])
    assert np.abs(E - E1).max() < 1e-10 * E1.max()


@pytest.mark.parametrize(
    "item, line",
    [
        (2, "attached[1][3]: got 2, must be the number of a body before it: 0 (the base) to 1"),
        (-1, "attached[1][3]: got -1, must be the number of a body before it"),
        ("1", "attached[1][3]: got '1', must be the number of a body before it"),
    ],
)
def test_a_chain_to_a_body_not_before_it_is_refused(item, line):
    base = Body(strip(0, 1 / 3, 1, 1), SOFT, clamped=("left",), name="one")
    middle = Body(strip(1 / 3, 2 / 3, 1, 1), STIFF, name="two")
    tip = Body(strip(2 / 3, 1, 1, 1), SOFT, name="three")
    with pytest.raises(RotheInputError) as info:
        GluedBodies(base, [(middle, "right", "left"), (tip, "right", "left", item)])
    assert str(info.value).startswith(line)
    with pytest.raises(RotheInputError, match=r"^attached\[1\]\.part_j: got 'left', is loaded, "):
        GluedBodies(base, [(middle, "right", "left"), (tip, "left", "left", 1)])
    with pytest.raises(RotheInputError, match=r"^attached\[1\]\.part_j: got 'middle', must be one"):
        GluedBodies(base, [(middle, "right", "left"), (tip, "middle", "left", 1)])


def test_action_equals_reaction_and_the_ledger_closes():
    """The multiplier's nodal forces on the two bodies have opposite resultants (to round-off),
    the base's equals the recorded reaction; the interface holds at every accepted state; the
    whole-system ledger closes and the glue does no work (no prescribed work)."""
    glued = two_bodies(SOFT, STIFF, ny=(2, 3))  # (mortar: Pi reproduces constants)
    assert glued.interfaces[0].method == "mortar"
    res = run_bodies(glued, scheme=BDF2(), control=Uniform(0.01))
    tr = res.trajectory
    lam = np.asarray(tr["lam"])
    assert lam.shape == (len(tr["t"]), glued.system.constraint.m)
    worst, biggest = 0.0, 0.0
    for k in range(1, lam.shape[0]):
        f1, f2 = glued.interface_forces(lam[k])
        s1, s2 = f1.reshape(-1, 2).sum(axis=0), f2.reshape(-1, 2).sum(axis=0)
        worst = max(worst, np.abs(s1 + s2).max())
        biggest = max(biggest, np.abs(s1).max())
        assert np.allclose(s1, tr["reaction_right"][k], rtol=0, atol=1e-14 * max(1, abs(s1).max()))
    assert biggest > 1e-3
    assert worst < 1e-13 * biggest
    assert glued.multiplier(lam[-1]).shape == (2 * glued.interfaces[0].dofs1.size,)
    assert np.abs(tr["constraint"]).max() < 1e-14
    E = tr["energy"]
    assert E[-1] > 1e-4
    assert np.abs(tr["balance"]).max() < 1e-12 * E.max()
    assert np.abs(tr["work_prescribed"]).max() < 1e-15
    # the energy is the loads' work up to the scheme's dissipation (BDF2: small, positive)
    assert 0 < tr["numerical_dissipation"][-1] < 0.05 * tr["work_components"][-1]


def test_bdf2_order_in_u_and_adaptive_steps():
    """BDF2 on the smooth pull: order >= 1.8 in u of both bodies at T; adaptive steps reach
    the uniform reference within the tolerance's size."""
    glued = two_bodies(SOFT, STIFF, T=0.5)

    def final(control):
        r = run_bodies(glued, scheme=BDF2(), control=control, fields=False)
        return np.concatenate(glued.fields(r.state.u, r.state.q)), r

    ref, _ = final(Uniform(0.5 / 160))
    errs = [np.abs(final(Uniform(tau))[0] - ref).max() for tau in (0.5 / 10, 0.5 / 20, 0.5 / 40)]
    orders = np.log2(np.array(errs[:-1]) / errs[1:])
    assert orders.min() >= 1.8, orders
    # adaptive: a tighter tolerance takes more steps and gets closer (1e-2: 51 steps, 1.0 %;
    # 1e-3: 115 steps, 0.22 % measured)
    out = {}
    for tol in (1e-2, 1e-3):
        u, r = final(Adaptive(tol, tau=0.01))
        out[tol] = (r.trajectory.stats.accepted_steps, np.abs(u - ref).max() / np.abs(ref).max())
        assert np.abs(r.trajectory["balance"]).max() < 1e-12 * r.trajectory["energy"].max()
    assert out[1e-2][0] < out[1e-3][0] < 200
    assert out[1e-3][1] < 0.5 * out[1e-2][1] < 0.01


def test_mortar_interfaces_converge_to_the_matching_result():
    """Non-matching sides (2n against 3n cells across): the tip deflection approaches the
    matching meshes' one under refinement, the difference falls by more than 1.6 per
    halving."""

    def tip(glued):
        r = run_bodies(glued, scheme=BDF2(), control=Uniform(0.02), fields=False)
        u2 = glued.fields(r.state.u, r.state.q)[1].reshape(-1, 2)
        x = glued.components[0].problem.space.doflocs
        return u2[np.isclose(x[0], 1.0), 1].mean()

    diffs = []
    for n in (1, 2, 4):
        mortar = two_bodies(SOFT, STIFF, n=4 * n, ny=(2 * n, 3 * n))
        assert mortar.interfaces[0].method == "mortar"
        diffs.append(abs(tip(mortar) - tip(two_bodies(SOFT, STIFF, n=4 * n, ny=(2 * n, 2 * n)))))
    rates = np.array(diffs[:-1]) / diffs[1:]
    assert rates.min() > 1.6, (diffs, rates)


def test_bad_glued_bodies_are_one_line_each():
    m1, m2 = strip(0, 0.5, 2, 2), strip(0.5, 1, 2, 2)
    far = strip(0.7, 1.2, 2, 2)
    b1 = Body(m1, SOFT, clamped=("left",), name="one")
    cases = [
        (
            lambda: GluedBodies(b1, [(Body(far, SOFT, name="two"), "right", "left")]),
            r"^attached\[0\]\.interface: got parts 'right' \(body 1\) and 'left' \(body 2\) "
            r"that do not touch: 0 % of 'right' lies on 'left'",
        ),
        (
            lambda: GluedBodies(b1, [(Body(m2, SOFT, name="two"), "rigth", "left")]),
            r"^attached\[0\]\.base_part: got 'rigth', must be one of bottom, left, right, top$",
        ),
        (
            lambda: GluedBodies(b1, [(Body(m2, SOFT, name="two"), "right", "lft")]),
            r"^attached\[0\]\.body_part: got 'lft', must be one of bottom, left, right, top$",
        ),
        (
            lambda: GluedBodies(
                b1, [(Body(m2, SOFT, clamped=("left",), name="two"), "right", "left")]
            ),
            r"^attached\[0\]\.clamped: got 'left', must be a boundary part of the body other "
            r"than the glued one: bottom, right, top$",
        ),
        (
            lambda: GluedBodies(
                b1, [(Body(m2, SOFT, dirichlet={"right": zero}, name="two"), "right", "left")]
            ),
            r"^attached\[0\]\.dirichlet: got 'right', must be empty",
        ),
        (
            lambda: GluedBodies(b1, [(Body(m2, SOFT, name="one"), "right", "left")]),
            r"^attached\[0\]\.name: got 'one', must be unique among the bodies$",
        ),
        (
            lambda: GluedBodies(b1, []),
            r"^attached: got \[\], must glue at least one body to the base$",
        ),
        (
            lambda: GluedBodies(
                Body(m1, SOFT, clamped=("right",), name="one"),
                [(Body(m2, SOFT, name="two"), "right", "left")],
            ),
            r"^couplings\[0\]\.part: got 'right', also carries prescribed Dirichlet data",
        ),
    ]
    for build, pattern in cases:
        with pytest.raises(RotheInputError, match=pattern):
            build()


def test_glued_step_is_one_sparse_factorization_and_agrees_with_the_schur_path(monkeypatch):
    """P2 bodies (body 2: 90 coordinates): the bordered step factored as one sparse matrix --
    one factorization per step size (the consistent acceleration's and the step's), one
    back-substitution per step, no dense border -- and the same numbers as the Schur
    complement path (forced by raising the threshold) to solver round-off."""
    from rothe.eld import coupled_run, coupled_step

    opts = {"scheme": BDF2(), "control": Uniform(0.02), "T": 0.2}
    mono = run_bodies(two_bodies(SOFT, STIFF, degree=2), **opts)
    kern = mono.stepper.kern
    assert kern.monolithic and kern.r == 90
    assert kern.X is None  # no r back-substitutions, no dense r x r Schur complement
    assert kern.stats["factorizations"] == 2
    assert kern.stats["back_substitutions"] == mono.state.j + 1
    monkeypatch.setattr(coupled_step, "SPARSE_COORDINATES", 10**6)
    monkeypatch.setattr(coupled_run, "SPARSE_COORDINATES", 10**6)
    schur = run_bodies(two_bodies(SOFT, STIFF, degree=2), **opts)
    assert not schur.stepper.kern.monolithic
    # the border's non-zero columns (body 2's 5 interface nodes x 2) per factorization
    assert schur.stepper.kern.stats["back_substitutions"] == 2 * 10 + schur.state.j + 1
    scale = np.abs(schur.state.u).max()
    assert scale > 1e-4
    assert np.abs(mono.state.u - schur.state.u).max() < 1e-10 * scale
    assert np.abs(mono.state.q - schur.state.q).max() < 1e-10 * np.abs(schur.state.q).max()
    assert np.abs(mono.state.lam - schur.state.lam).max() < 1e-9 * np.abs(schur.state.lam).max()
    assert (
        np.abs(mono.trajectory["balance"]).max() < 1e-12 * np.abs(mono.trajectory["energy"]).max()
    )


def test_the_glue_and_its_border_are_sparse_in_the_attached_bodys_unknowns():
    """Body 2 of 16770 unknowns (P2, 32 cells across: above the command's former cap of
    6000): the glue's Jacobian Pi S E (d k1 x m = 130 x 16770, 17 MB dense), Gamma and the
    border Phi hold one entry per interface dof (matching: Pi a permutation), and building them
    allocates less than a tenth of the dense Jacobian (it would fail if a d k1 x m or n x r
    array were built)."""
    import tracemalloc

    import scipy.sparse as sp

    from rothe.eld.bodies import Glue
    from rothe.eld.constraint import HarmonicLifting, NodalLifting

    glued = GluedBodies(
        Body(strip(0, 0.5, 64, 32), SOFT, degree=2, clamped=("left",), name="one"),
        [(Body(strip(0.5, 1.0, 64, 32), STIFF, degree=2, name="two"), "right", "left")],
        T=0.1,
    )
    system, itf, comp = glued.system, glued.interfaces[0], glued.components[0]
    k1, m = itf.dofs1.size, comp.size
    assert (k1, m) == (65, 16770)
    dense = 2 * k1 * m * 8
    tracemalloc.start()
    try:
        glue = Glue(itf, comp)
        system._gamma_cache = None
        Gamma = system.gamma()
        Phi = system.lifted_modes(NodalLifting(system.constraint))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < dense / 10, (peak, dense)
    assert sp.issparse(glue.J) and glue.J.shape == (2 * k1, m) and glue.J.nnz == 2 * k1
    assert sp.issparse(Gamma) and Gamma.nnz == 2 * k1
    assert sp.issparse(Phi) and Phi.shape == (system.body.space.ndofs, m) and Phi.nnz == 2 * k1
    # the same map as the interface's: G(q) = Pi S_Q u_2 at the side-1 points
    q = np.random.default_rng(1).standard_normal(m)
    u2 = comp.field(q).reshape(-1, 2)
    assert np.allclose(glue.values(0.0, q, glue._x1).T, itf.Pi @ u2[itf.dofs2])
    # harmonic lifting: only Gamma's 130 non-zero columns are lifted (dense in the base's dofs)
    PhiH = system.lifted_modes(HarmonicLifting(system.constraint, system.body.K))
    assert sp.issparse(PhiH) and np.unique(PhiH.tocoo().col).size == 2 * k1
