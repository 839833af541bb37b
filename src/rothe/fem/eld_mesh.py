"""Meshes for the elastodynamics examples: unit square, box (beam), and meshio files.

All meshes are scikit-fem ``MeshTri`` / ``MeshTet`` with named boundary parts in
``mesh.boundaries`` (facet index arrays): ``left``/``right`` (x = min/max), ``bottom``/``top``
(y), and in 3D ``front``/``back`` (z), as in scikit-fem's ``with_defaults``. The box tags its
faces by the facet midpoints directly (scikit-fem's ``with_defaults`` takes 7 s at two million
tetrahedra, this takes the 2 s of computing the facets).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import check_int, check_positive, fail

_AXIS_NAMES = (("left", "right"), ("bottom", "top"), ("front", "back"))


def build_entities(t: np.ndarray, indices, n: int):
    """scikit-fem's ``Mesh.build_entities(t, indices)`` (facets or edges with the cells' map to
    them), the same arrays, by a stable sort of one int64 key per entity instead of
    ``np.unique(axis=1)`` over rows (5 s -> about 1 s for the facets of two million
    tetrahedra). Returns None if the keys would not fit in 63 bits (then use scikit-fem's).
    """
    if indices is None:
        return None, None
    k = len(indices[0])
    if k > 3 or float(n) ** k >= 2.0**63:
        return None
    ne = t.shape[1]
    m = len(indices)
    key = np.empty(m * ne, dtype=np.int64)
    for r, ix in enumerate(indices):
        rows = [t[i].astype(np.int64) for i in ix]
        lo = np.minimum.reduce(rows)
        hi = np.maximum.reduce(rows)
        part = key[r * ne:(r + 1) * ne]
        if k == 2:
            np.multiply(lo, n, out=part)
            part += hi
        else:
            mid = rows[0] + rows[1] + rows[2] - lo - hi
            np.multiply(lo, n, out=part)
            part += mid
            part *= n
            part += hi
    perm = np.argsort(key, kind="stable")
    skey = key[perm]
    del key
    first = np.empty(skey.size, dtype=bool)
    first[:1] = True
    np.not_equal(skey[1:], skey[:-1], out=first[1:])
    ukey = skey[first]
    del skey
    ids = np.cumsum(first, dtype=np.intp)
    ids -= 1
    del first
    mapping = np.empty(ids.size, dtype=np.intp)
    mapping[perm] = ids
    del perm, ids
    unique = np.empty((k, ukey.size), dtype=t.dtype)
    for r in range(k - 1, -1, -1):
        unique[r] = ukey % n
        ukey //= n
    return unique, mapping.reshape(m, ne)


def with_fast_facets(mesh):
    """Fill scikit-fem's cached facets of ``mesh`` (``mesh.facets``, ``mesh.t2f``) by
    :func:`build_entities` unless they exist; returns the mesh."""
    if not hasattr(mesh, "_facets"):
        t = np.asarray(mesh.t)
        built = build_entities(t, mesh.elem.refdom.facets, int(mesh.p.shape[1]))
        if built is not None:
            mesh._facets, mesh._t2f = built
    return mesh


def with_fast_edges(mesh):
    """Fill scikit-fem's cached edges of a tetrahedral ``mesh`` (``mesh.edges``, ``mesh.t2e``,
    used by P2 dof numbering) by :func:`build_entities` unless they exist; returns the mesh."""
    refdom = mesh.elem.refdom
    if getattr(refdom, "edges", None) is not None and not hasattr(mesh, "_edges"):
        built = build_entities(np.asarray(mesh.t), refdom.edges, int(mesh.p.shape[1]))
        if built is not None:
            mesh._edges, mesh._t2e = built
    return mesh


def tag_box_faces(mesh):
    """The mesh with boundary parts named after the faces of its bounding box."""
    with_fast_facets(mesh)
    # boundary facets: those of one cell only (scikit-fem's boundary_facets() would first
    # build the facet-to-cell map, two more sorts)
    facets = np.flatnonzero(np.bincount(np.asarray(mesh.t2f).ravel(),
                                        minlength=mesh.facets.shape[1]) == 1)
    mid = mesh.p[:, mesh.facets[:, facets]].mean(axis=1)
    lo, hi = mesh.p.min(axis=1), mesh.p.max(axis=1)
    tol = 1e-10 * max(1.0, float(np.max(hi - lo)))
    parts = {}
    for axis in range(mesh.p.shape[0]):
        low_name, high_name = _AXIS_NAMES[axis]
        parts[low_name] = facets[np.abs(mid[axis] - lo[axis]) < tol]
        parts[high_name] = facets[np.abs(mid[axis] - hi[axis]) < tol]
    tagged = mesh.with_boundaries(parts)
    # with_boundaries returns a copy without the facet structures just computed; hand them on
    # (they depend only on p and t) instead of rebuilding them (seconds at millions of cells)
    for cached in ("_facets", "_t2f", "_f2t", "_edges", "_t2e"):
        if hasattr(mesh, cached) and not hasattr(tagged, cached):
            setattr(tagged, cached, getattr(mesh, cached))
    return tagged


def unit_square(n: int):
    """(0,1)^2 with n x n cells, two triangles each (scikit-fem ``init_tensor``), named faces."""
    from skfem import MeshTri

    n = check_int("n", n, minimum=1)
    x = np.linspace(0.0, 1.0, n + 1)
    return tag_box_faces(MeshTri.init_tensor(x, x))


def box(nx: int, ny: int, nz: int, length: float = 1.0, height: float = 1.0, width: float = 1.0):
    """[0, length] x [0, height] x [0, width] with nx * ny * nz cubes of six tetrahedra each."""
    from skfem import MeshTet

    nx, ny, nz = (check_int(k, v, minimum=1) for k, v in (("nx", nx), ("ny", ny), ("nz", nz)))
    length = check_positive("length", length)
    height = check_positive("height", height)
    width = check_positive("width", width)
    mesh = MeshTet.init_tensor(np.linspace(0, length, nx + 1), np.linspace(0, height, ny + 1),
                               np.linspace(0, width, nz + 1))
    return tag_box_faces(mesh)


def load_mesh(path):
    """A triangle or tetrahedron mesh from any file meshio reads, with named boundary parts
    from gmsh physical groups or meshio cell sets on the facets (scikit-fem's importer)."""
    from skfem import Mesh

    path = Path(path)
    if not path.is_file():
        raise fail("mesh", str(path), "must be an existing mesh file")
    try:
        mesh = Mesh.load(str(path))
    except Exception as exc:  # meshio raises many kinds
        raise fail("mesh", str(path), f"could not be read ({type(exc).__name__}: {exc})") from None
    from ..fem.elasticity import check_simplex_mesh

    check_simplex_mesh(mesh, "mesh")
    return mesh


def from_meshio(m):
    """A scikit-fem mesh (with named parts from cell sets) from a ``meshio.Mesh`` object."""
    from skfem.io.meshio import from_meshio as _from

    from ..fem.elasticity import check_simplex_mesh

    mesh = _from(m)
    check_simplex_mesh(mesh, "mesh")
    return mesh
