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
