"""Simplex meshes for P1 finite elements: builders, file import (meshio, gmsh included), checks.

Meshes are scikit-fem objects (:class:`skfem.MeshTri` in 2D, :class:`skfem.MeshTet` in 3D), so
everything scikit-fem offers (refinement, ``with_boundaries``, plotting) works on them. Named
boundary parts live in ``mesh.boundaries`` as arrays of facet indices (scikit-fem's convention).

Builders
    :func:`unit_square` (N x N cells, each split into two triangles, either all along the
    diagonal direction of y = x -- scikit-fem's ``init_tensor`` -- or in a "union jack" pattern
    that is symmetric under every reflection of the square), :func:`unit_cube` (N^3 cubes, six
    tetrahedra each, scikit-fem's ``init_tensor``). On these (and on any mesh without named
    parts) the sides of the bounding box are available by scikit-fem's default names ``left``,
    ``right`` (x), ``bottom``, ``top`` (y), ``front``, ``back`` (z): see :func:`box_part_nodes`.
    They are computed on demand, not attached with ``with_defaults()``, which rebuilds the
    facet list (1.8 s at 10^6 nodes).

Files
    :func:`load_mesh` reads anything meshio reads (gmsh ``.msh`` 2.2/4.x, ``.vtu``, ``.xdmf``,
    ...), keeps the triangle (2D) or tetrahedron (3D) cells and turns gmsh physical groups
    (``gmsh:physical`` cell data + ``field_data`` names) or meshio ``cell_sets`` on the facet
    cells (lines in 2D, triangles in 3D) into named boundary parts, and those on the volume
    cells into named subdomains (``mesh.subdomains``: cell indices, the material regions of
    :class:`rothe.eld.materials.PiecewiseMaterial`). Nodes used by no cell are dropped (gmsh
    files often keep geometry points).

Checks (:func:`check_mesh`): finite coordinates of magnitude at most :data:`MAX_COORDINATE`,
cell indices in range, no degenerate cell (|volume| > 1e-12 * h^d for the cell's longest edge
h). Every failure is a one-line :class:`~rothe.errors.RotheInputError`; :func:`load_mesh` checks
the coordinates before anything else computes with them.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np

from ..errors import RotheInputError, check_int, check_positive, described, fail

#: meshio cell type of the volume cells and of the boundary facets, by dimension
CELL_TYPE = {2: "triangle", 3: "tetra"}
FACET_TYPE = {2: "line", 3: "triangle"}
#: largest node coordinate (in magnitude) a mesh may have: squared lengths and tetrahedron
#: volumes (products of three lengths) of larger coordinates overflow double precision (1.8e308)
MAX_COORDINATE = 1e100


def bad(name: str, what: str, allowed: str) -> RotheInputError:
    """``<name>: got <what>, <allowed>`` with a described (unquoted) value."""
    return RotheInputError(f"{name}: got {what}, {allowed}")


def _skfem_class(dim: int):
    from skfem import MeshTet, MeshTri  # heavy: imported when first needed (start-up time)

    return {2: MeshTri, 3: MeshTet}[dim]


def unit_square(n: int = 40, pattern: str = "tensor", *, named: bool = False):
    """The unit square with n x n cells split into 2 n^2 triangles ((n + 1)^2 nodes).

    ``named=True``: the four sides are named boundary parts ``left``, ``right``, ``bottom``,
    ``top`` in ``mesh.boundaries`` (:func:`tag_box_faces`, as :func:`box` does).

    ``pattern='tensor'``: every cell split along its diagonal parallel to y = x (scikit-fem's
    ``MeshTri.init_tensor``); the mesh is symmetric under (x, y) -> (y, x) and under the point
    reflection (x, y) -> (1 - x, 1 - y). ``pattern='unionjack'``: the diagonal alternates with
    the parity of i + j, so for even n the mesh is symmetric under all eight symmetries of the
    square.
    """
    from skfem import MeshTri  # heavy: imported when first needed (start-up time)

    n = check_int("n", n, minimum=1)
    x = np.linspace(0.0, 1.0, n + 1)
    if pattern == "tensor":
        mesh = MeshTri.init_tensor(x, x)
    elif pattern == "unionjack":
        X, Y = np.meshgrid(x, x, indexing="ij")
        p = np.vstack([X.ravel(), Y.ravel()])
        i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        i, j = i.ravel(), j.ravel()
        v00 = i * (n + 1) + j
        v10 = (i + 1) * (n + 1) + j
        v01 = i * (n + 1) + j + 1
        v11 = (i + 1) * (n + 1) + j + 1
        slash = (i + j) % 2 == 0  # diagonal v00-v11 ("/"), else v10-v01 ("\")
        t1 = np.where(slash, [v00, v10, v11], [v00, v10, v01])
        t2 = np.where(slash, [v00, v11, v01], [v10, v11, v01])
        mesh = MeshTri(p, np.hstack([t1, t2]))
    else:
        raise fail("pattern", pattern, "must be one of tensor, unionjack")
    return tag_box_faces(mesh) if named else mesh


def unit_cube(n: int = 12):
    """The unit cube with n^3 cubes split into 6 n^3 tetrahedra ((n + 1)^3 nodes)."""
    from skfem import MeshTet  # heavy: imported when first needed (start-up time)

    n = check_int("n", n, minimum=1)
    x = np.linspace(0.0, 1.0, n + 1)
    return MeshTet.init_tensor(x, x, x)


def box(nx: int, ny: int, nz: int, length: float = 1.0, height: float = 1.0, width: float = 1.0):
    """[0, length] x [0, height] x [0, width] with nx * ny * nz cubes of six tetrahedra each."""
    from skfem import MeshTet  # heavy: imported when first needed (start-up time)

    nx, ny, nz = (check_int(k, v, minimum=1) for k, v in (("nx", nx), ("ny", ny), ("nz", nz)))
    length = check_positive("length", length)
    height = check_positive("height", height)
    width = check_positive("width", width)
    mesh = MeshTet.init_tensor(
        np.linspace(0, length, nx + 1),
        np.linspace(0, height, ny + 1),
        np.linspace(0, width, nz + 1),
    )
    return tag_box_faces(mesh)


def boundary_facets(mesh) -> np.ndarray:
    """(n_boundary_facets, d) node indices of the facets that belong to exactly one cell.

    Vectorized: every cell contributes its d+1 facets (sorted node tuples), each encoded as one
    integer; facets counted once are boundary facets. Independent of scikit-fem's facet list,
    which costs about 1.5 s to build at 10^6 nodes.
    """
    t = np.asarray(mesh.t)
    k, n = t.shape[0], int(mesh.p.shape[1])
    f = np.sort(np.concatenate([np.delete(t, j, axis=0) for j in range(k)], axis=1), axis=0)
    f = f.astype(np.int64)
    if float(n) ** (k - 1) < 2.0**62:
        key = f[0]
        for row in f[1:]:
            key = key * n + row
        _, first, counts = np.unique(key, return_index=True, return_counts=True)
    else:  # too many nodes to pack a facet into one int64
        _, first, counts = np.unique(f, axis=1, return_index=True, return_counts=True)
    return f[:, first[counts == 1]].T


BOX_PARTS = {
    "left": (0, np.min),
    "right": (0, np.max),
    "bottom": (1, np.min),
    "top": (1, np.max),
    "front": (2, np.min),
    "back": (2, np.max),
}


def box_part_nodes(mesh, name: str, facets: np.ndarray | None = None) -> np.ndarray:
    """Nodes of the boundary facets on one side of the bounding box (scikit-fem's names).

    A facet belongs to ``left`` if all its nodes have x = min x (to 1e-2 times the shortest
    boundary edge), and so on for ``right`` (max x), ``bottom``/``top`` (y), ``front``/``back``
    (z). Returns a sorted, possibly empty, array.
    """
    axis, pick = BOX_PARTS[name]
    p = mesh.p
    if axis >= p.shape[0]:
        return np.empty(0, dtype=np.int64)
    facets = boundary_facets(mesh) if facets is None else facets
    x = p[axis]
    level = pick(x)
    edge = np.linalg.norm(p[:, facets[:, 0]] - p[:, facets[:, 1]], axis=0)
    atol = 1e-2 * float(edge.min()) if edge.size else 0.0
    on = np.all(np.abs(x[facets] - level) <= atol, axis=1)
    return np.unique(facets[on]).astype(np.int64)


def check_simplex_mesh(mesh, name: str = "mesh") -> int:
    """Spatial dimension of a scikit-fem triangle/tetrahedron mesh (else a one-line error)."""
    from skfem import MeshTet, MeshTri  # heavy: imported when first needed (start-up time)

    if isinstance(mesh, MeshTri):
        return 2
    if isinstance(mesh, MeshTet):
        return 3
    raise fail(
        name, type(mesh).__name__, "must be a scikit-fem MeshTri or MeshTet (P1/P2 simplices)"
    )


def mesh_dim(mesh) -> int:
    """The space dimension d of a mesh (2: triangles, 3: tetrahedra)."""
    return int(mesh.p.shape[0])


def check_mesh_dim(mesh, dim: int, why: str, name: str = "mesh"):
    """``mesh`` (or None) if it is ``dim``-dimensional, else one line naming ``name``: ``got a
    kD mesh (<describe>), must be <dim>D (<why>)``."""
    if mesh is not None and mesh_dim(mesh) != dim:
        raise fail(
            name,
            described(f"a {mesh_dim(mesh)}D mesh ({describe(mesh)})"),
            f"must be {dim}D ({why})",
        )
    return mesh


def barycentric_gradients(p: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(grad lambda (d+1, d, nc), |K| (nc,)) for points p (d, n) and cells t (d+1, nc).

    Closed forms instead of batched LAPACK (3x faster at 10^6 cells): the rows of B^{-1},
    B = [x_1 - x_0, ..., x_d - x_0]; in 2D they are (e2_y, -e2_x) / det and (-e1_y, e1_x) / det,
    in 3D e2 x e3, e3 x e1, e1 x e2 divided by det = e1 . (e2 x e3), with e_k = x_k - x_0.
    Entry-major layout (one contiguous array per entry): every later operation is a plain
    vector operation.
    """
    d = p.shape[0]
    e = [p[:, t[k]] - p[:, t[0]] for k in range(1, d + 1)]
    if d == 2:
        det = e[0][0] * e[1][1] - e[0][1] * e[1][0]
        rows = [np.array([e[1][1], -e[1][0]]), np.array([-e[0][1], e[0][0]])]
        fact = 2.0
    else:
        rows = [
            np.cross(e[1], e[2], axis=0),
            np.cross(e[2], e[0], axis=0),
            np.cross(e[0], e[1], axis=0),
        ]
        det = np.sum(e[0] * rows[0], axis=0)
        fact = 6.0
    G = np.empty((d + 1, d, t.shape[1]))
    for k in range(d):
        G[k + 1] = rows[k] / det
    G[0] = -G[1:].sum(axis=0)
    return G, np.abs(det) / fact


def cell_volumes(mesh) -> np.ndarray:
    """Signed-free volumes |K| of the simplices (area in 2D), vectorized."""
    p, t = mesh.p, mesh.t
    d = p.shape[0]
    B = np.stack([p[:, t[k]] - p[:, t[0]] for k in range(1, d + 1)], axis=-1)  # (d, nc, d)
    B = np.moveaxis(B, 0, 1)  # (nc, d, d): columns are edge vectors
    return np.abs(np.linalg.det(B)) / (2.0 if d == 2 else 6.0)


def coordinates_problem(p: np.ndarray) -> str | None:
    """What is wrong with node coordinates ``p`` (non-finite, or larger than
    :data:`MAX_COORDINATE` in magnitude), as the end of a one-line message; None if nothing."""
    p = np.asarray(p, dtype=float)
    finite = np.isfinite(p)
    if not np.all(finite):
        return f"has a non-finite node coordinate ({p[~finite][0]:g}), coordinates must be finite"
    biggest = float(np.abs(p).max()) if p.size else 0.0
    if biggest > MAX_COORDINATE:
        return (
            f"has node coordinates up to {biggest:.3g} in magnitude, must be at most "
            f"{MAX_COORDINATE:g} (squared lengths and volumes would overflow; rescale the "
            "mesh)"
        )
    return None


def check_mesh(mesh, name: str = "mesh"):
    """Validate a P1 simplex mesh; returns it. One-line errors name ``name``."""
    p, t = np.asarray(mesh.p), np.asarray(mesh.t)
    d = p.shape[0]
    if d not in (2, 3) or t.shape[0] != d + 1:
        raise bad(
            name,
            f"a mesh with {t.shape[0]}-node cells in {d}D",
            "must be triangles (2D) or tetrahedra (3D)",
        )
    if t.shape[1] == 0:
        raise bad(name, "a mesh with 0 cells", "must have at least one cell")
    problem = coordinates_problem(p)
    if problem is not None:
        raise RotheInputError(f"{name}: {problem}", name)
    if t.min() < 0 or t.max() >= p.shape[1]:
        raise bad(
            name,
            f"cell node index {int(t.max())}",
            f"must be in [0, {p.shape[1] - 1}] (the number of nodes)",
        )
    vol = cell_volumes(mesh)
    edges = [p[:, t[a]] - p[:, t[b]] for a in range(d + 1) for b in range(a)]
    h = np.sqrt(np.max([np.sum(e * e, axis=0) for e in edges], axis=0))
    degenerate = np.nonzero(vol <= 1e-12 * h**d)[0]
    if degenerate.size:
        k = int(degenerate[0])
        raise bad(
            name,
            f"a degenerate cell (index {k}, volume {vol[k]:.3g})",
            f"all {t.shape[1]} cells must have positive volume",
        )
    return mesh


def _match_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Index into ``b`` (rows, sorted within each row) of every row of ``a``; -1 if absent."""
    a = np.sort(a, axis=1)
    both = np.vstack([b, a])
    _, inv = np.unique(both, axis=0, return_inverse=True)
    inv = inv.ravel()
    where = np.full(inv.max() + 1, -1, dtype=np.int64)
    where[inv[: len(b)]] = np.arange(len(b))
    return where[inv[len(b) :]]


def _read_meshio(path: Path, name: str):
    """meshio.read, silenced: meshio prints to stdout/stderr and calls sys.exit(1) when no
    reader for the extension succeeds; both become one RotheInputError line here."""

    import meshio  # heavy: imported when first needed (start-up time)

    chatter = io.StringIO()
    try:
        with contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter):
            return meshio.read(str(path))
    except (Exception, SystemExit) as exc:  # meshio raises many types, or exits
        lines = [
            ln.strip()
            for ln in (str(exc) if not isinstance(exc, SystemExit) else "").splitlines()
            + chatter.getvalue().splitlines()
            if ln.strip()
        ]
        msg = lines[0] if lines else type(exc).__name__
        for noise in (f"'{path}'", str(path), "Error: "):
            msg = msg.replace(noise, "")
        msg = " ".join(msg.split()).rstrip(" .")
        raise fail(name, str(path), f"is not a mesh meshio can read ({msg})") from None


#: what :func:`load_mesh` does with coincident nodes used by different cells
DUPLICATE_NODES = ("error", "merge", "keep")


def coincident_nodes(p: np.ndarray, rel: float = 1e-12) -> np.ndarray:
    """(k, 2) pairs i < j of nodes closer than ``rel`` times the bounding-box diameter.

    ``p``: (d, n) finite coordinates. A k-d tree (scipy.spatial.cKDTree), so O(n log n) in C: no
    Python loop over nodes. The tree works on the coordinates scaled to the unit box, so that
    any finite coordinates (1e200 included) give squared distances without overflow.
    """
    from scipy.spatial import cKDTree  # heavy: imported when first needed (start-up time)

    if p.shape[1] < 2:
        return np.empty((0, 2), dtype=np.int64)
    lo = p.min(axis=1, keepdims=True)
    span = p.max(axis=1, keepdims=True) - lo  # may overflow to inf for |x| ~ 1e308
    scale = float(np.max(span)) if np.all(np.isfinite(span)) else float(np.abs(p).max())
    q = (p - lo) / scale if scale > 0 else p - lo
    diameter = float(np.linalg.norm(np.ptp(q, axis=1)))
    pairs = cKDTree(q.T).query_pairs(rel * max(diameter, 1e-300), output_type="ndarray")
    return np.asarray(pairs, dtype=np.int64).reshape(-1, 2)


def _merge_map(n: int, pairs: np.ndarray) -> np.ndarray:
    """Index of the representative (smallest index of its cluster) of every node."""
    import scipy.sparse as sp  # heavy: imported when first needed (start-up time)
    from scipy.sparse.csgraph import (
        connected_components,  # heavy: imported when first needed (start-up time)
    )

    graph = sp.csr_matrix(
        (np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n)
    )
    _, label = connected_components(graph, directed=False)
    rep = np.full(label.max() + 1, n, dtype=np.int64)
    np.minimum.at(rep, label, np.arange(n))
    return rep[label]


def load_mesh(path, dim: int | None = None, name: str = "mesh", duplicate_nodes: str = "error"):
    """Read a triangle (2D) or tetrahedron (3D) mesh from any file meshio reads.

    ``dim`` = 2 or 3 asks for that cell type; ``None`` takes tetrahedra if there are any, else
    triangles. Named boundary parts come from gmsh physical groups (``$PhysicalNames``) or
    meshio cell sets on the facet cells, named subdomains (``mesh.subdomains``, cell indices)
    from those on the volume cells; unnamed physical tags are called ``tag<k>``.

    ``duplicate_nodes``: what to do with coincident nodes (closer than 1e-12 of the diameter)
    used by different cells. Such a mesh is cut there -- a crack: the cells on the two sides
    share no node, the P1 space allows a jump across the cut, and its faces are boundary
    facets (so the default Dirichlet boundary, the whole boundary, includes them). Meshes glued
    from parts without merging their nodes look exactly like this and silently give another
    solution, so ``"error"`` (default) refuses the file and names the first pair;
    ``"merge"`` glues every cluster of coincident nodes into one node (the mesh the file
    presumably meant); ``"keep"`` takes the cut as intended.
    """
    if duplicate_nodes not in DUPLICATE_NODES:
        raise fail(
            "duplicate_nodes", duplicate_nodes, "must be one of " + ", ".join(DUPLICATE_NODES)
        )
    if str(path) == "":
        raise fail(name, "", "must name a mesh file")
    path = Path(path)
    if not path.exists():
        raise fail(name, str(path), "no such file")
    if path.is_dir():
        raise fail(name, str(path), "is a directory, must be a mesh file")
    if not path.is_file():  # a FIFO or a device would block or never end
        raise fail(
            name, str(path), "is not a regular file (a FIFO, socket or device), must be a mesh file"
        )
    m = _read_meshio(path, name)
    blocks: dict[str, list[np.ndarray]] = {}
    for block in m.cells:
        blocks.setdefault(block.type, []).append(np.asarray(block.data))
    if dim is None:
        dim = 3 if "tetra" in blocks else 2
    ctype = CELL_TYPE[dim]
    if ctype not in blocks:
        found = ", ".join(sorted(blocks)) or "none"
        raise fail(
            name,
            str(path),
            f"has no {ctype} cells (found: {found}); a {dim}D run needs {ctype} cells",
        )
    cells = np.vstack(blocks[ctype])
    points = np.asarray(m.points, dtype=float)
    if points.shape[1] > dim:
        extra = points[:, dim:]
        if np.ptp(extra, axis=0).max() > 1e-12 * max(1.0, np.abs(points).max()):
            raise fail(
                name,
                str(path),
                f"has {ctype} cells that are not flat in {dim}D "
                "(a surface mesh?), must be a planar 2D mesh",
            )
        points = points[:, :dim]
    if points.shape[1] < dim:
        raise fail(name, str(path), f"has {points.shape[1]}D points, a {dim}D mesh needs {dim}")

    # drop nodes used by no cell and renumber
    used = np.zeros(len(points), dtype=bool)
    if cells.size:
        if cells.min() < 0 or cells.max() >= len(points):
            raise fail(name, str(path), "has cells with node indices out of range")
        used[cells.ravel()] = True
    new_index = np.full(len(points), -1, dtype=np.int64)
    new_index[used] = np.arange(int(used.sum()))
    p = points[used].T.copy()
    t = new_index[cells].T.copy()
    problem = coordinates_problem(p)  # before the k-d tree and the volumes compute with them
    if problem is not None:
        raise fail(name, str(path), problem)
    if duplicate_nodes != "keep":
        pairs = coincident_nodes(p)
        if len(pairs) and duplicate_nodes == "error":
            x = ", ".join(f"{v:g}" for v in p[:, pairs[0, 0]])
            raise fail(
                name,
                str(path),
                f"has {len(pairs)} pair(s) of coincident nodes used by "
                f"different cells (the first at ({x})): the mesh is cut "
                "there like a crack; --duplicate-nodes merge glues them, "
                "keep takes the cut as intended",
            )
        if len(pairs):  # merge: renumber the cells onto one node per cluster, drop the rest
            rep = _merge_map(p.shape[1], pairs)
            keep = np.unique(rep)
            renumber = np.full(p.shape[1], -1, dtype=np.int64)
            renumber[keep] = np.arange(keep.size)
            new_index = np.where(new_index >= 0, renumber[rep[np.maximum(new_index, 0)]], -1)
            p = p[:, keep].copy()
            t = new_index[cells].T.copy()

    cls = _skfem_class(dim)
    mesh = cls(p, t, validate=False)
    check_mesh(mesh, name)
    parts = _boundary_parts(m, blocks, dim, new_index)
    subdomains = _subdomains(m, dim)
    if parts or subdomains:
        bnd = None
        if parts:
            facets = mesh.facets.T  # (nf, dim), each row sorted
            bnd = {}
            for part, rows in parts.items():
                idx = _match_rows(rows, facets) if len(rows) else np.empty(0, dtype=np.int64)
                # kept even when empty, so that choosing it for Dirichlet data gets a clear error
                bnd[part] = np.unique(idx[idx >= 0]).astype(np.int64)
        mesh = cls(p, mesh.t, _boundaries=bnd, _subdomains=subdomains or None, validate=False)
    return mesh


def _subdomains(m, dim) -> dict[str, np.ndarray]:
    """Cell indices of every named group on the volume cells (gmsh physical groups of
    dimension ``dim``, unnamed ones ``tag<k>``, tag 0 -- no group -- skipped, and meshio cell
    sets): the material regions.

    Cell k of the mesh is row k of the volume blocks stacked in file order (as in
    :func:`load_mesh`)."""
    ctype = CELL_TYPE[dim]
    offsets, start = [], 0
    for block in m.cells:
        offsets.append(start)
        if block.type == ctype:
            start += len(block.data)
    out: dict[str, list[np.ndarray]] = {}
    tags_by_block = m.cell_data.get("gmsh:physical") if m.cell_data else None
    names = {}
    for key, val in (m.field_data or {}).items():
        val = np.asarray(val).ravel()
        if val.size >= 2 and int(val[1]) == dim:
            names[int(val[0])] = key
    if tags_by_block is not None:
        for block, tags, off in zip(m.cells, tags_by_block, offsets, strict=True):
            if block.type != ctype:
                continue
            tags = np.asarray(tags).ravel()
            for tag in np.unique(tags):
                if tag == 0:  # gmsh's "in no physical group" (meshio writes it for untagged)
                    continue
                label = names.get(int(tag), f"tag{int(tag)}")
                out.setdefault(label, []).append(off + np.flatnonzero(tags == tag))
    for label, per_block in (m.cell_sets or {}).items():
        if label.startswith("gmsh:"):
            continue
        for block, ids, off in zip(m.cells, per_block, offsets, strict=True):
            if block.type == ctype and ids is not None and len(ids):
                out.setdefault(label, []).append(off + np.asarray(ids, dtype=np.int64))
    return {k: np.unique(np.concatenate(v)).astype(np.int64) for k, v in out.items()}


def _boundary_parts(m, blocks, dim, new_index) -> dict[str, np.ndarray]:
    """Facet node rows (renumbered) of every named group on the facet cells."""
    ftype = FACET_TYPE[dim]
    if ftype not in blocks:
        return {}
    parts: dict[str, list[np.ndarray]] = {}
    # gmsh physical groups: per-block tags + names from field_data {name: [tag, dim]}
    tags_by_block = m.cell_data.get("gmsh:physical") if m.cell_data else None
    names = {}
    for key, val in (m.field_data or {}).items():
        val = np.asarray(val).ravel()
        if val.size >= 2 and int(val[1]) == dim - 1:
            names[int(val[0])] = key
    if tags_by_block is not None:
        for block, tags in zip(m.cells, tags_by_block, strict=True):
            if block.type != ftype:
                continue
            data = np.asarray(block.data)
            tags = np.asarray(tags).ravel()
            for tag in np.unique(tags):
                label = names.get(int(tag), f"tag{int(tag)}")
                parts.setdefault(label, []).append(data[tags == tag])
    # meshio cell sets (e.g. from .xdmf/.vtu writers that keep them)
    for label, per_block in (m.cell_sets or {}).items():
        if label.startswith("gmsh:"):
            continue
        for block, ids in zip(m.cells, per_block, strict=True):
            if block.type == ftype and ids is not None and len(ids):
                parts.setdefault(label, []).append(np.asarray(block.data)[np.asarray(ids)])
    out = {}
    for label, rows in parts.items():
        rows = np.vstack(rows)
        mapped = new_index[rows]
        if np.any(mapped < 0):  # a facet on nodes no cell uses cannot be a boundary facet
            mapped = mapped[np.all(mapped >= 0, axis=1)]
        out[label] = mapped
    return out


def _part_facets(mesh, part: str, name: str, where: str = "") -> np.ndarray:
    """The facets of the named boundary ``part``; an unknown or empty part is refused in one
    line naming ``name`` and listing the mesh's parts (``where`` ends that line)."""
    facets = (mesh.boundaries or {}).get(part)
    if facets is None or len(facets) == 0:
        known = ", ".join(boundary_part_names(mesh)) or "(the mesh has no named parts)"
        raise fail(name, part, f"must be one of {known}{where}")
    return facets


def _facet_normals(x: np.ndarray) -> np.ndarray:
    """Normals of the facets with nodes ``x`` (d, d, nf: coordinate, node, facet) whose length
    is the facet's measure |f| (length in 2D, area in 3D); their orientation is the node order's."""
    if x.shape[0] == 2:
        e = x[:, 1] - x[:, 0]
        return np.stack([e[1], -e[0]])
    return np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], axis=0) / 2


def part_frame(mesh, part: str, name: str = "part") -> tuple[np.ndarray, np.ndarray]:
    """The centre of a named boundary part's bounding box and its mean inward unit normal.

    n = sum_f |f| n_f / |sum_f |f| n_f|, n_f the unit normal of facet f pointing into its cell
    (length-weighted in 2D, area-weighted in 3D); c = (min x + max x)/2 over the part's nodes,
    per axis. A straight side gets its exact normal and midpoint (the left side of [0, L] x
    [0, 1]: c = (0, 1/2), n = (1, 0), to the bit). A part whose normals cancel (a closed
    curve) is refused.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        With named boundary parts (``mesh.boundaries``).
    part : str
    name : str
        The parameter named in errors.

    Returns
    -------
    (center (d,), normal (d,))
    """
    facets = _part_facets(mesh, part, name)
    p = np.asarray(mesh.p)
    nodes = np.asarray(mesh.facets)[:, facets]  # (d, nf)
    x = p[:, nodes]  # (d, d, nf): coordinate, node, facet
    normal = _facet_normals(x)
    cells = np.asarray(mesh.f2t)[0, facets]
    inside = p[:, np.asarray(mesh.t)[:, cells]].mean(axis=1) - x.mean(axis=1)
    normal = normal * np.where(np.sum(normal * inside, axis=0) < 0, -1.0, 1.0)
    total = normal.sum(axis=1)
    size = float(np.sqrt(total @ total))
    scale = float(np.abs(normal).sum())
    if not size > 1e-8 * scale:
        raise fail(name, part, "has no mean normal (its facets' normals cancel: a closed part)")
    part_nodes = np.unique(nodes)
    lo, hi = p[:, part_nodes].min(axis=1), p[:, part_nodes].max(axis=1)
    return (lo + hi) / 2, total / size


def part_centroid(mesh, part: str, name: str = "part") -> tuple[np.ndarray, float]:
    """The centroid of a named boundary part and its measure (length in 2D, area in 3D).

    c = sum_f |f| m_f / sum_f |f|, m_f the midpoint (centroid) of facet f; the right side
    x = L of [0, L] x [0, H] gives c = (L, H/2), |part| = H (to round-off). An unknown part is
    refused in one line naming ``name`` and listing the mesh's parts.

    Returns
    -------
    (center (d,), measure)
    """
    facets = _part_facets(mesh, part, name, " (boundary parts of the mesh)")
    p = np.asarray(mesh.p)
    x = p[:, np.asarray(mesh.facets)[:, facets]]  # (d, d, nf): coordinate, node, facet
    size = np.linalg.norm(_facet_normals(x), axis=0)
    total = float(size.sum())
    return (x.mean(axis=1) * size).sum(axis=1) / total, total


def boundary_part_names(mesh) -> list[str]:
    """The names of the mesh's boundary parts, sorted (empty without named parts)."""
    return sorted((mesh.boundaries or {}).keys())


def describe(mesh) -> str:
    """``'<nodes> nodes, <cells> triangles'`` (or tetrahedra), for messages."""
    d = mesh_dim(mesh)
    kind = "triangles" if d == 2 else "tetrahedra"
    return f"{mesh.p.shape[1]} nodes, {mesh.t.shape[1]} {kind}"


def require_dim(mesh, dim: int, name: str = "mesh"):
    """``mesh`` if it is ``dim``-dimensional, else a one-line error naming ``name``."""
    d = mesh_dim(mesh)
    if d != dim:
        raise RotheInputError(
            f"{name}: got a {d}D mesh ({describe(mesh)}), must be {dim}D for this example"
        )
    return mesh


def from_meshio(m):
    """A scikit-fem mesh (with named parts from cell sets) from a ``meshio.Mesh`` object."""
    # heavy: imported when first needed (start-up time of the command line)
    from skfem.io.meshio import (
        from_meshio as _from,  # heavy: imported when first needed (start-up time)
    )

    mesh = _from(m)
    check_simplex_mesh(mesh, "mesh")
    return mesh


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
        part = key[r * ne : (r + 1) * ne]
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
    facets = np.flatnonzero(
        np.bincount(np.asarray(mesh.t2f).ravel(), minlength=mesh.facets.shape[1]) == 1
    )
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
