"""Adaptive simplex meshes by bisection, with a refinement history that coarsening undoes.

:class:`AdaptiveMesh` keeps a *binary forest*: the cells of the initial (conforming) triangle or
tetrahedron mesh are its roots, every bisection gives a cell two children, and the current mesh
is the set of leaves. Refinement bisects marked leaves and then every leaf with a hanging node
until the mesh is conforming again; coarsening undoes bisections, returning to the ancestors in
the history. Nothing is a loop over cells, edges or nodes: every pass works on arrays of all
cells concerned; only the *rounds* of the conformity closure and the levels of the leaf
ordering are Python loops.

Why not scikit-fem's ``Mesh.refined(marked)``: for triangles it does red-green-blue refinement
(the green closure cells are not children that a later refinement keeps, so the meshes are not
nested in a tree), for tetrahedra longest-edge bisection with random noise on the coordinates
to break ties; neither records parents, neither can coarsen, and both drop the named boundary
parts (``_boundaries=None``). What is kept from scikit-fem is the mesh type: the current mesh is
a ``MeshTri`` / ``MeshTet`` with named boundaries and subdomains (:attr:`AdaptiveMesh.mesh`).

Bisection rule (2D, newest vertex bisection; Mitchell 1991, Binev-Dahmen-DeVore 2004)
    A triangle is stored as [n0, n1, n2] with refinement edge n0n1 (n2 is its newest vertex).
    Bisection at m = (x_n0 + x_n1)/2 gives the children [n0, n2, m] and [n1, n2, m]: each
    child's refinement edge is the parent edge opposite the new vertex m. Initial labelling:
    the refinement edge of every root is its longest edge (global strict order: length, then
    vertex numbers). Any labelling gives a conforming closure in 2D; the longest edge keeps the
    angles of all descendants in at most four similarity classes per root.

Bisection rule (3D; Arnold, Mukherjee & Pouly 2000, "Locally adapted tetrahedral meshes using
bisection", SISC 22; equivalent to Maubach/Traxler/Kossaczky bisection after the first level)
    A tetrahedron is a *marked tetrahedron*: vertices [n0, n1, n2, n3] with refinement edge
    n0n1, one marked edge on every face such that n0n1 is the marked edge of the two faces
    containing it, and a flag. The marked edge of a face is stored by its *peak* (the face
    vertex opposite the marked edge): q0 for the face opposite n1 (n0, n2, n3), q1 for the face
    opposite n0 (n1, n2, n3). The tetrahedron is *planar* if all marked edges lie in one face
    (q0 = q1); "P_f" if planar and flagged. Bisection at m: child i keeps n_i, n2, n3, m; its
    refinement edge is the marked edge of the face (n_i, n2, n3) it inherits whole, so child i
    is stored as [a, b, c, m] with c = q_i and {a, b} the other two vertices of that face. Every
    face of a child that contains m has peak m (newest vertex bisection on the faces, and the
    new interior face (m, n2, n3) is marked with n2n3), except that the new interior face of a
    P_f parent is marked with the edge (m, x), x the vertex of the marked plane off the
    refinement edge (peak c). Children of a planar unflagged parent are flagged, all others are
    unflagged. On a Kuhn cube mesh (scikit-fem's ``MeshTet.init_tensor``) this is exactly
    Maubach's bisection with tags 3, 2, 1, 3, ... (the face peaks reproduce the tag cycle;
    tested: eight children similar to the parent after three generations).
    Initial marking, valid for ANY conforming tetrahedral mesh (AMP, Sec. 4): a strict global
    order on the edges (length, then vertex numbers); the refinement edge of each tetrahedron
    is its largest edge, the marked edge of each face is the face's largest edge (so two
    tetrahedra sharing a face agree on its marking), all flags unset. AMP prove that the
    closure below terminates and that the descendants fall in finitely many similarity
    classes. No initial refinement (as Stevenson's matching-condition construction would
    need) is required, so coarsening returns exactly to the user's mesh.

Conformity closure (both dimensions; :meth:`AdaptiveMesh._refine_leaves`)
    Edge-wise: W = the edges to bisect, at first the refinement edges of the marked leaves
    (edge key min * 2^32 + max). Each pass (a) adds the refinement edge of every leaf that
    contains an edge of W to W, and (b) bisects, for every *compatible* edge of W (the
    refinement edge of all leaves around it), all those leaves at once, with one new vertex per
    edge. Bisecting an edge for its whole patch at once keeps the history coarsenable: a vertex
    then depends only on newer ones. If no edge is compatible while W is closed (the refinement
    edges around some vertex form a cycle, which the longest-edge labelling of an irregular
    tetrahedral mesh allows), every leaf whose refinement edge is in W is bisected (AMP's rule,
    whose termination they prove); a registry of the edges split in this call reuses their
    midpoints. Only leaves with both end points of an edge of W are looked at.

Coarsening (undoing bisections; :meth:`AdaptiveMesh._coarsen_round`)
    A vertex created by bisection is a candidate when every leaf containing it is marked. It
    depends on the midpoints of the parents of those leaves (when they differ from it) and of
    refined siblings; candidates depending on a non-candidate are dropped until none is left.
    One round removes a *generation*: the sinks of that dependency graph and every strongly
    connected component (a cycle left by the rule above) whose dependencies stay inside.
    Their bisections are undone bottom-up; an undone cell whose removed vertices are still
    used by another cell (it would leave a hanging node) is split again, until the mesh is
    conforming. ``coarsen_rounds`` repeats with the merged parents marked.

Numbering
    Cells are ordered depth-first in the forest (roots in the order of the initial mesh,
    child 0 before child 1): the same set of leaves always has the same order, whatever the
    history. Vertices of the initial mesh keep their numbers 0..N0-1; new vertices are appended
    (per round, in the order of their edge keys); removed vertices are squeezed out, keeping
    the order of the rest. Coarsening everything therefore returns the initial mesh exactly:
    the same nodes and the same cell columns (roots are output in their input vertex order).

Boundary parts and subdomains
    Every stored face remembers the facet of the initial mesh it lies in (or -1 for faces
    interior to a root): children inherit it face by face. The named boundary parts of the
    initial mesh (``mesh.boundaries``) are therefore the same named parts of every refined or
    coarsened mesh, and subdomains (``mesh.subdomains``) are inherited from the roots.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import check_int, described, fail
from ..mesh import _read_meshio
from ..topology import (
    SKFEM_FACETS,
    FacetTopology,
    barycentric_gradients,
    cell_diameters,
    entities,
    facet_structures,
    number_rows,
    opposite_faces,
    pack_rows,
)
from .transfer import edge_numbering, transfer_matrix

#: version of the checkpoint layout written by :meth:`AdaptiveMesh.checkpoint_state`
CHECKPOINT_VERSION = 1

#: positions of (a, b, c) in the inherited face (n_i, n2, n3) given the position of the peak c
_PERM = np.array([[1, 2, 0], [0, 2, 1], [0, 1, 2]])
#: storage type of the forest (vertex and node numbers < 2^31); keys are formed in int64
_INT = np.int32


_SIMPLEX_VOLUME = {"triangle": 2, "tetra": 3}
_OTHER_VOLUME = {
    "quad": "quadrilaterals",
    "quad8": "quadrilaterals",
    "quad9": "quadrilaterals",
    "hexahedron": "hexahedra",
    "hexahedron20": "hexahedra",
    "hexahedron27": "hexahedra",
    "wedge": "wedges",
    "pyramid": "pyramids",
    "triangle6": "quadratic triangles",
    "tetra10": "quadratic tetrahedra",
}
_SKFEM_KINDS = {
    "MeshQuad": "quadrilaterals",
    "MeshQuad1": "quadrilaterals",
    "MeshQuad2": "quadratic quadrilaterals",
    "MeshHex": "hexahedra",
    "MeshHex1": "hexahedra",
    "MeshHex2": "quadratic hexahedra",
    "MeshTri2": "quadratic triangles",
    "MeshTet2": "quadratic tetrahedra",
    "MeshWedge1": "wedges",
    "MeshLine": "line segments",
    "MeshLine1": "line segments",
}


def check_adaptable(mesh, name: str = "mesh"):
    """Return ``mesh`` if bisection can adapt it, else raise a one-line error naming ``name``.

    Accepts a scikit-fem mesh (``MeshTri`` / ``MeshTet``; a ``MeshQuad``, ``MeshHex``, ...
    is refused with its cell type), a ``meshio.Mesh`` or a path to a file meshio reads: any
    volume cell other than linear triangles/tetrahedra is refused, and a file mixing them with
    other cells is named "a mixed mesh (...)". Boundary cells (lines in 2D, triangles next to
    tetrahedra in 3D) are fine. ``name`` is the caller's parameter (the command line passes
    its option ``--adapt-space``).
    """

    from skfem import MeshTet, MeshTri  # heavy: imported when first needed (start-up time)

    if isinstance(mesh, (MeshTri, MeshTet)):
        return mesh
    if isinstance(mesh, (str, Path)):
        mesh = _read_meshio(Path(mesh), "mesh")
    if hasattr(mesh, "cells") and hasattr(mesh, "points") and not hasattr(mesh, "t"):
        types = {b.type for b in mesh.cells}
        other = sorted(types & set(_OTHER_VOLUME))
        dim = 3 if "tetra" in types else (2 if "triangle" in types else 0)
        simplex = ["tetra"] if dim == 3 else (["triangle"] if dim == 2 else [])
        if other and simplex:
            kinds = ", ".join(simplex + other)
            raise fail(
                name,
                described(f"a mixed mesh ({kinds})"),
                "needs a mesh of triangles (2D) or tetrahedra (3D) only",
            )
        if other:
            raise fail(
                name,
                described(f"a mesh of {_OTHER_VOLUME[other[0]]}"),
                "needs triangles (2D) or tetrahedra (3D); bisection refines only simplices",
            )
        if not simplex:
            raise fail(
                name,
                described("a mesh without triangles or tetrahedra"),
                "needs triangles (2D) or tetrahedra (3D)",
            )
        return mesh
    kind = _SKFEM_KINDS.get(type(mesh).__name__, type(mesh).__name__)
    raise fail(
        name,
        described(f"a mesh of {kind}"),
        "needs triangles (2D) or tetrahedra (3D); bisection refines only simplices",
    )


@dataclass
class MeshChange:
    """What one adaptation did, and what the transfer of fields from the old mesh needs.

    ``old_points`` (n_old, d) / ``old_cells`` (nc_old, d+1) and ``new_points`` / ``new_cells``
    are the two meshes (cells in scikit-fem vertex order, as ``mesh.t.T``). For every new cell c
    the old cells that overlap it are the contiguous range ``old_start[c] : old_start[c] +
    old_count[c]`` of the old cell order: one old cell (the new cell is that cell or one of its
    descendants) or several (the new cell is an ancestor of old cells: coarsened). See
    :mod:`rothe.fem.adapt.transfer`. ``unchanged`` (nc_new,) marks the new cells that are old
    cells (same vertices in the same order, renumbered).
    """

    old_points: np.ndarray
    old_cells: np.ndarray
    new_points: np.ndarray
    new_cells: np.ndarray
    old_start: np.ndarray
    old_count: np.ndarray
    unchanged: np.ndarray
    bisections: int
    merges: int
    removed_vertices: int
    old_mesh_id: int
    new_mesh_id: int
    #: per-mesh caches (dof numberings) shared with the AdaptiveMesh: a numbering computed for
    #: the new mesh by one transfer is reused as the old one by the next change
    old_cache: dict = field(default_factory=dict, repr=False, compare=False)
    new_cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def changed(self) -> bool:
        return self.bisections > 0 or self.merges > 0

    def transfer(self, degree: int = 1, components: int = 1):
        """Sparse matrix (n_new, n_old) mapping P1/P2 dof vectors old -> new (see transfer)."""

        return transfer_matrix(self, degree=degree, components=components)

    def describe(self) -> dict:
        """The sizes of the two meshes and what changed (mesh ids, cells, vertices, bisections,
        merges, removed vertices), for statistics and summaries.
        """
        return {
            "old_mesh_id": self.old_mesh_id,
            "new_mesh_id": self.new_mesh_id,
            "old_cells": int(len(self.old_cells)),
            "new_cells": int(len(self.new_cells)),
            "old_vertices": int(len(self.old_points)),
            "new_vertices": int(len(self.new_points)),
            "bisections": self.bisections,
            "merges": self.merges,
            "removed_vertices": self.removed_vertices,
        }


class AdaptiveMesh:
    """A triangle (2D) or tetrahedron (3D) mesh that refines and coarsens by bisection.

    Parameters
    ----------
    mesh : skfem.MeshTri | skfem.MeshTet
        Any conforming initial mesh (built-in grids, ``rothe.fem.mesh.load_mesh``,
        ``rothe.fem.mesh``); its named boundary parts and subdomains are inherited by every
        mesh of the hierarchy.

    Attributes and methods (shapes: d the dimension, nc cells, nv vertices):

    - :attr:`mesh` -- the current scikit-fem mesh (cached per version), with boundaries;
    - :attr:`points` (nv, d), :attr:`cells` (nc, d+1): the current mesh as arrays;
    - :attr:`mesh_id` -- increases by one with every change (0 for the initial mesh);
    - :meth:`refine`, :meth:`coarsen`, :meth:`adapt` -> :class:`MeshChange`;
    - :meth:`ndofs` (degree, components) -- dofs of P1/P2 (vector) spaces, without building
      them; :attr:`levels` -- bisection generation of every cell;
    - :meth:`checkpoint_state` / :meth:`restore_state` -- the whole hierarchy as arrays.
    """

    def __init__(self, mesh, *, name: str = "mesh"):
        check_adaptable(mesh, name)
        p = np.asarray(mesh.p, dtype=float)
        t = np.asarray(mesh.t, dtype=np.int64)
        d = p.shape[0]
        self.dim = d
        self._mesh_cls = type(mesh)
        nv, nc = p.shape[1], t.shape[1]
        if nc == 0:
            raise fail(name, described("a mesh with 0 cells"), "must have at least one cell")
        _, vol = barycentric_gradients(p, t)
        h = cell_diameters(p, t)
        bad = np.flatnonzero(vol <= 1e-12 * h**d)
        if bad.size:
            raise fail(
                name,
                described(f"a degenerate cell (index {int(bad[0])})"),
                "all cells must have positive volume",
            )

        # initial facets: numbering, boundary flags, named parts
        faces = opposite_faces(d)
        init_facets, cell_facets = entities(t, faces, nv)  # (d, nf0), (d+1, nc)
        nf0 = init_facets.shape[1]
        counts = np.bincount(cell_facets.ravel(), minlength=nf0)
        if np.any(counts > 2):
            raise fail(
                name,
                described("a facet shared by more than two cells"),
                "must be a conforming simplicial mesh",
            )
        self._facet_is_boundary = counts == 1
        self._initial_facets = init_facets.T.copy()  # (nf0, d) sorted tuples
        parts = {}
        for part, idx in (mesh.boundaries or {}).items():
            idx = np.asarray(idx, dtype=np.int64)
            rows = (
                np.sort(np.asarray(mesh.facets)[:, idx].T, axis=1)
                if idx.size
                else np.zeros((0, d), dtype=np.int64)
            )
            mask = np.zeros(nf0, dtype=bool)
            if len(rows):
                mask[self._find_initial_facets(rows)] = True
            parts[str(part)] = mask
        self._parts = parts
        subdomains = {}
        for sub, idx in (mesh.subdomains or {}).items():
            mask = np.zeros(nc, dtype=bool)
            mask[np.asarray(idx, dtype=np.int64)] = True
            subdomains[str(sub)] = mask
        self._subdomains = subdomains

        # global strict edge order (length, then vertex numbers) and the initial labelling
        edges, cell_edges = entities(
            t, np.array([[a, b] for a in range(d + 1) for b in range(a + 1, d + 1)]), nv
        )
        length = np.linalg.norm(p[:, edges[1]] - p[:, edges[0]], axis=0)
        rank = np.empty(edges.shape[1], dtype=np.int64)
        rank[np.lexsort((edges[1], edges[0], length))] = np.arange(edges.shape[1])
        n_edges0 = edges.shape[1]
        self._euler = nv - n_edges0 + nf0 - nc if d == 3 else nv - n_edges0 + nf0
        labelled, peaks = self._initial_labelling(t, rank, cell_edges)

        # forest
        self._root_input = t.T.copy()
        self._init_storage(nc, nv)
        self._p[:nv] = p.T
        self._nv = nv
        self._n = nc
        self._cells[:nc] = labelled
        if d == 3:
            self._peaks[:nc] = peaks
            self._flag[:nc] = False
        self._parent[:nc] = -1
        self._child[:nc] = -1
        self._mid[:nc] = -1
        self._root[:nc] = np.arange(nc)
        self._level[:nc] = 0
        # face origins follow the labelled vertex order
        # labelled[c, k] = t[perm[c, k], c]; face opposite labelled k = face opposite input perm
        perm = np.argmax(labelled[:, :, None] == t.T[:, None, :], axis=2)
        self._origin[:nc] = np.take_along_axis(cell_facets.T, perm, axis=1)
        self._leaves = np.arange(nc, dtype=np.int64)
        self.mesh_id = 0
        self._cache = {}
        self._initial_cells = nc
        self._initial_vertices = nv
        self._stats = {"cycle_breaks": 0}

    # -- construction helpers -----------------------------------------------------------------
    def _find_initial_facets(self, rows: np.ndarray) -> np.ndarray:
        """Indices into the initial facets of sorted vertex rows (error if not a facet)."""
        d = self.dim
        nmax = int(max(self._initial_facets.max(initial=0), rows.max(initial=0))) + 1
        both = np.vstack([self._initial_facets, rows])
        _, ids = number_rows(np.sort(both, axis=1), nmax)
        nf0 = len(self._initial_facets)
        where = np.full(ids.max() + 1, -1, dtype=np.int64)
        where[ids[:nf0]] = np.arange(nf0)
        out = where[ids[nf0:]]
        if np.any(out < 0):
            raise fail(
                "mesh.boundaries",
                described("a facet that is not a facet of the mesh"),
                f"boundary parts must list facets of the {d}D mesh",
            )
        return out

    def _initial_labelling(self, t, rank, cell_edges):
        """Vertex order with the refinement edge first (and the face peaks in 3D) per root."""
        d = self.dim
        nc = t.shape[1]
        pairs = [(a, b) for a in range(d + 1) for b in range(a + 1, d + 1)]
        r = rank[cell_edges]  # (n_local_edges, nc)
        best = r.argmax(axis=0)
        pa = np.array([a for a, _ in pairs])[best]
        pb = np.array([b for _, b in pairs])[best]
        cols = np.arange(nc)
        rest = np.ones((d + 1, nc), dtype=bool)
        rest[pa, cols] = False
        rest[pb, cols] = False
        others = np.nonzero(rest.T)[1].reshape(nc, d - 1)  # local indices, ascending
        n0, n1 = t[pa, cols], t[pb, cols]
        labelled = np.column_stack([n0, n1] + [t[others[:, k], cols] for k in range(d - 1)])
        if d == 2:
            return labelled, None
        # peak of a face = face vertex opposite the face's largest edge
        edge_rank = {}
        for k, (a, b) in enumerate(pairs):
            edge_rank[(a, b)] = r[k]
        loc = np.column_stack([pa, pb, others[:, 0], others[:, 1]])  # local input indices

        def rank_of(la, lb):
            lo, hi = np.minimum(la, lb), np.maximum(la, lb)
            out = np.empty(nc, dtype=np.int64)
            for (a, b), vals in edge_rank.items():
                sel = (lo == a) & (hi == b)
                out[sel] = vals[sel]
            return out

        def peak(lx, ly, lz):
            # face (x, y, z): peak = vertex opposite the largest of (y,z), (x,z), (x,y)
            rx, ry, rz = rank_of(ly, lz), rank_of(lx, lz), rank_of(lx, ly)
            which = np.argmax(np.column_stack([rx, ry, rz]), axis=1)
            return np.choose(which, [lx, ly, lz])

        q0_local = peak(loc[:, 0], loc[:, 2], loc[:, 3])  # face opposite n1
        q1_local = peak(loc[:, 1], loc[:, 2], loc[:, 3])  # face opposite n0
        peaks = np.column_stack([t[q0_local, cols], t[q1_local, cols]])
        return labelled, peaks

    def _init_storage(self, n_cells: int, n_vertices: int) -> None:
        d = self.dim
        cap = max(16, 2 * n_cells)
        capv = max(16, 2 * n_vertices)
        if n_cells >= 2**31 // 4 or n_vertices >= 2**31 // 4:
            raise fail(
                "mesh",
                described(f"a mesh with {n_cells} cells and {n_vertices} vertices"),
                "must have fewer than 5*10^8 of each to be adapted",
            )
        self._cap, self._capv = cap, capv
        self._p = np.zeros((capv, d))
        self._cells = np.zeros((cap, d + 1), dtype=_INT)
        self._peaks = np.zeros((cap, 2), dtype=_INT) if d == 3 else None
        self._flag = np.zeros(cap, dtype=bool) if d == 3 else None
        self._parent = np.zeros(cap, dtype=_INT)
        self._child = np.zeros(cap, dtype=_INT)
        self._mid = np.zeros(cap, dtype=_INT)
        self._root = np.zeros(cap, dtype=_INT)
        self._level = np.zeros(cap, dtype=np.int32)
        self._origin = np.zeros((cap, d + 1), dtype=_INT)
        self._src_start = np.zeros(cap, dtype=_INT)
        self._src_count = np.zeros(cap, dtype=_INT)

    _NODE_FIELDS = (
        "_cells",
        "_peaks",
        "_flag",
        "_parent",
        "_child",
        "_mid",
        "_root",
        "_level",
        "_origin",
        "_src_start",
        "_src_count",
    )

    def _reserve(self, n_nodes: int, n_vertices: int) -> None:
        if n_nodes > self._cap:
            cap = max(n_nodes, self._cap + self._cap // 2)
            for f in self._NODE_FIELDS:
                a = getattr(self, f)
                if a is None:
                    continue
                b = np.zeros((cap,) + a.shape[1:], dtype=a.dtype)
                b[: self._n] = a[: self._n]
                setattr(self, f, b)
            self._cap = cap
        if n_vertices > self._capv:
            capv = max(n_vertices, self._capv + self._capv // 2)
            b = np.zeros((capv, self.dim))
            b[: self._nv] = self._p[: self._nv]
            self._p = b
            self._capv = capv

    # -- the current mesh -----------------------------------------------------------------------
    @property
    def n_cells(self) -> int:
        return int(len(self._leaves))

    @property
    def n_vertices(self) -> int:
        return int(self._nv)

    @property
    def points(self) -> np.ndarray:
        """(nv, d) coordinates of the current vertices (a view; do not modify)."""
        return self._p[: self._nv]

    @property
    def cells(self) -> np.ndarray:
        """(nc, d+1) vertex indices of the current cells (scikit-fem order: ``mesh.t.T``).

        Triangles are sorted per cell, as scikit-fem's ``MeshTri`` does; tetrahedra keep the
        bisection order (cells of the initial mesh: their input order).
        """
        if "cells" not in self._cache:
            leaves = self._leaves
            t = self._cells[leaves].copy()
            is_root = self._parent[leaves] < 0
            t[is_root] = self._root_input[self._root[leaves[is_root]]]
            if self.dim == 2:
                # scikit-fem's MeshTri sorts the vertices of every triangle (sort_t=True);
                # a three-element sorting network is 5x faster than np.sort(axis=1)
                a, b, c = t[:, 0], t[:, 1], t[:, 2]
                lo, hi = np.minimum(a, b), np.maximum(a, b)
                mid = np.minimum(hi, c)
                t = np.column_stack([np.minimum(lo, mid), np.maximum(lo, mid), np.maximum(hi, c)])
            self._cache["cells"] = t
        return self._cache["cells"]

    @property
    def levels(self) -> np.ndarray:
        """Bisection generation of every current cell (0 for cells of the initial mesh)."""
        return self._level[self._leaves].astype(np.int64)

    def vertex_parents(self) -> np.ndarray:
        """The edge each vertex bisects: (nv, 2) vertex numbers, -1 for the initial vertices.

        Removing a vertex v (coarsening) replaces a P1 function by one that is affine on the
        parent edge (a, b): its value at v changes by the hierarchical surplus
        z_v - (z_a + z_b)/2, which a family can use to keep its state from being coarsened
        away (:mod:`rothe.ris.adapt`)."""
        out = np.full((self._nv, 2), -1, dtype=np.int64)
        n = self._n
        split = np.flatnonzero(self._child[:n] >= 0)
        out[self._mid[split]] = self._cells[split, :2]
        return out

    @property
    def boundary_names(self) -> list[str]:
        return sorted(self._parts)

    @property
    def subdomain_names(self) -> list[str]:
        return sorted(self._subdomains)

    def _boundary_face_count(self) -> int:
        orig = self._origin[self._leaves]
        on = orig >= 0
        return int(np.count_nonzero(self._facet_is_boundary[orig[on]]))

    def n_edges(self) -> int:
        """Number of edges of the current mesh (Euler's formula, no edge list needed)."""
        nc = self.n_cells
        nb = self._boundary_face_count()
        if self.dim == 2:
            return (3 * nc + nb) // 2
        n_faces = (4 * nc + nb) // 2
        return self._nv + n_faces - nc - self._euler

    def ndofs(self, degree: int = 1, components: int = 1) -> int:
        """Dofs of the P1/P2 space with ``components`` components on the current mesh."""
        scalar = self._nv if degree == 1 else self._nv + self.n_edges()
        return int(components * scalar)

    def boundary_facets(self, part: str | None = None) -> np.ndarray:
        """(nb, d) sorted vertex tuples of the boundary facets (of one named part, or all)."""
        d = self.dim
        leaves = self._leaves
        orig = self._origin[leaves]
        if part is None:
            sel = np.zeros(orig.shape, dtype=bool)
            on = orig >= 0
            sel[on] = self._facet_is_boundary[orig[on]]
        else:
            if part not in self._parts:
                known = ", ".join(sorted(self._parts)) or "(none)"
                raise fail("part", part, f"must be one of {known}")
            sel = np.zeros(orig.shape, dtype=bool)
            on = orig >= 0
            sel[on] = self._parts[part][orig[on]]
        c, j = np.nonzero(sel)
        cells = self._cells[leaves[c]]
        faces = opposite_faces(d)[j]  # (k, d)
        rows = np.take_along_axis(cells, faces, axis=1)
        return np.sort(rows, axis=1)

    @property
    def mesh(self):
        """The current mesh as a scikit-fem ``MeshTri`` / ``MeshTet`` with named boundaries.

        Built once per mesh version. The facet structures (``facets``, ``t2f``; for
        tetrahedra also ``edges``, ``t2e`` once a P2 transfer has numbered them) are computed
        here by sorting packed keys and handed to the mesh, so scikit-fem does not rebuild them.
        """
        if "mesh" in self._cache:
            return self._cache["mesh"]

        p = np.ascontiguousarray(self.points.T)
        t = np.ascontiguousarray(self.cells.T)
        if self.dim == 2:  # the facets are the edges: one numbering for both
            facets, t2f = edge_numbering(self._cache, t, p.shape[1])
        else:
            facets, t2f = facet_structures(t, p.shape[1])
        boundaries = None
        if self._parts:
            boundaries = {}
            nv = p.shape[1]
            fkeys = pack_rows(facets.T, nv)
            for part in self._parts:
                rows = self.boundary_facets(part)
                if fkeys is not None:
                    idx = np.searchsorted(fkeys, pack_rows(rows, nv))
                else:
                    both = np.vstack([facets.T, rows])
                    _, ids = number_rows(both, nv)
                    idx = ids[facets.shape[1] :]
                # unique: a named interior surface is seen from both sides
                boundaries[part] = np.unique(idx).astype(np.int64)
        subdomains = None
        if self._subdomains:
            roots = self._root[self._leaves]
            subdomains = {k: np.flatnonzero(v[roots]) for k, v in self._subdomains.items()}
        mesh = self._mesh_cls(
            p,
            t.astype(np.int32),
            _boundaries=boundaries,
            _subdomains=subdomains,
            validate=False,
            sort_t=False,
        )
        mesh._facets = facets.astype(np.int32)
        mesh._t2f = t2f.astype(np.int32)
        if self.dim == 3 and "edges" in self._cache:
            mesh._edges = self._cache["edges"][0].astype(np.int32)
            mesh._t2e = self._cache["edges"][1].astype(np.int32)
        self._cache["mesh"] = mesh
        return mesh

    # -- refinement -----------------------------------------------------------------------------
    def _as_leaf_ids(self, marked, name: str) -> np.ndarray:
        """Forest ids of the marked current cells (boolean mask or integer indices)."""
        nc = self.n_cells
        if marked is None:
            return np.zeros(0, dtype=np.int64)
        m = np.asarray(marked)
        if m.dtype == bool:
            if m.shape != (nc,):
                raise fail(
                    name,
                    described(f"a boolean mask of shape {m.shape}"),
                    f"must have one entry per cell ({nc})",
                )
            idx = np.flatnonzero(m)
        else:
            if m.size and not np.issubdtype(m.dtype, np.integer):
                raise fail(
                    name,
                    described(f"an array of dtype {m.dtype}"),
                    "must be a boolean mask or integer cell indices",
                )
            idx = np.unique(m.astype(np.int64).ravel())
            if idx.size and (idx[0] < 0 or idx[-1] >= nc):
                raise fail(
                    name,
                    described(f"cell index {int(idx[0] if idx[0] < 0 else idx[-1])}"),
                    f"must be in [0, {nc - 1}]",
                )
        return self._leaves[idx]

    def _bisect(self, S: np.ndarray, reg: dict) -> np.ndarray:
        """Bisect the leaves S (forest ids); returns the children (2k,).

        ``reg`` holds the edges split earlier in this call (sorted keys min * 2^32 + max and
        their midpoints); other refinement edges get new vertices, numbered in key order.
        """
        d = self.dim
        k = len(S)
        c = self._cells[S].astype(np.int64)
        lo = np.minimum(c[:, 0], c[:, 1])
        hi = np.maximum(c[:, 0], c[:, 1])
        ukey, first, inv = np.unique((lo << 32) | hi, return_index=True, return_inverse=True)
        rk, rm = reg["keys"], reg["mids"]
        pos = np.searchsorted(rk, ukey)
        found = np.zeros(len(ukey), dtype=bool)
        inside = pos < len(rk)
        found[inside] = rk[pos[inside]] == ukey[inside]
        mids_u = np.empty(len(ukey), dtype=np.int64)
        mids_u[found] = rm[pos[found]]
        new = ~found
        n_new = int(np.count_nonzero(new))
        self._reserve(self._n + 2 * k, self._nv + n_new)
        ids = np.arange(self._nv, self._nv + n_new)
        self._p[ids] = 0.5 * (self._p[lo[first[new]]] + self._p[hi[first[new]]])
        self._nv += n_new
        mids_u[new] = ids
        reg["keys"] = np.insert(rk, pos[new], ukey[new])
        reg["mids"] = np.insert(rm, pos[new], ids)
        m = mids_u[inv.ravel()]

        n = self._n
        ch0 = n + 2 * np.arange(k)
        self._child[S] = ch0
        self._mid[S] = m
        porig = self._origin[S]
        kids = np.empty((2, k, d + 1), dtype=np.int64)
        korig = np.empty((2, k, d + 1), dtype=np.int64)
        rows = np.arange(k)
        if d == 2:
            for i in (0, 1):
                kids[i] = np.column_stack([c[:, i], c[:, 2], m])
                korig[i] = np.column_stack([np.full(k, -1), porig[:, 2], porig[:, 1 - i]])
        else:
            q = self._peaks[S]
            f = self._flag[S]
            planar = q[:, 0] == q[:, 1]
            pf = planar & f
            kpeaks = np.empty((2, k, 2), dtype=np.int64)
            for i in (0, 1):
                G = np.column_stack([c[:, i], c[:, 2], c[:, 3]])
                GL = np.broadcast_to(np.array([i, 2, 3]), (k, 3))
                perm = _PERM[np.argmax(G == q[:, i][:, None], axis=1)]
                abc = np.take_along_axis(G, perm, axis=1)
                loc = np.take_along_axis(GL, perm, axis=1)
                kids[i] = np.column_stack([abc, m])
                a, b, cc = abc[:, 0], abc[:, 1], abc[:, 2]
                kpeaks[i, :, 0] = np.where(pf & (b == c[:, i]), cc, m)  # face opposite b
                kpeaks[i, :, 1] = np.where(pf & (a == c[:, i]), cc, m)  # face opposite a
                o = np.empty((k, 4), dtype=np.int64)
                for j in range(3):
                    o[:, j] = np.where(loc[:, j] == i, -1, porig[rows, loc[:, j]])
                o[:, 3] = porig[:, 1 - i]
                korig[i] = o
            kflag = planar & ~f
            self._peaks[ch0] = kpeaks[0]
            self._peaks[ch0 + 1] = kpeaks[1]
            self._flag[ch0] = kflag
            self._flag[ch0 + 1] = kflag
        for i in (0, 1):
            ids_i = ch0 + i
            self._cells[ids_i] = kids[i]
            self._origin[ids_i] = korig[i]
            self._parent[ids_i] = S
            self._child[ids_i] = -1
            self._mid[ids_i] = -1
            self._root[ids_i] = self._root[S]
            self._level[ids_i] = self._level[S] + 1
            self._src_start[ids_i] = self._src_start[S]
            self._src_count[ids_i] = self._src_count[S]
        self._n += 2 * k
        children = np.empty(2 * k, dtype=np.int64)
        children[0::2] = ch0
        children[1::2] = ch0 + 1
        return children

    def _refine_leaves(self, S: np.ndarray) -> np.ndarray:
        """Bisect the leaves S and close to a conforming mesh. Returns all bisected ids.

        Edge-wise closure: W = the edges to bisect (at first the refinement edges of S).
        Repeat: (a) every leaf containing an edge of W whose own refinement edge is not in W
        adds it to W (until none does); (b) an edge of W is *compatible* when it is the
        refinement edge of every leaf containing it; all leaves around all compatible edges
        are bisected at once and those edges leave W. Bisecting an edge for its whole patch at
        once is what keeps the history coarsenable: a vertex is only ever blocked by newer
        vertices, so the newest one can always be removed. Only leaves with both end points
        of some edge of W are looked at.
        """
        if S.size == 0:
            return S
        d = self.dim
        pairs = [(a, b) for a in range(d + 1) for b in range(a + 1, d + 1)]
        c = self._cells[S].astype(np.int64)
        W = np.unique((np.minimum(c[:, 0], c[:, 1]) << 32) | np.maximum(c[:, 0], c[:, 1]))
        active = self._leaves
        acells = self._cells[active].astype(np.int64)
        reg = {"keys": np.zeros(0, dtype=np.int64), "mids": np.zeros(0, dtype=np.int64)}
        done = []
        guard = 0
        while W.size:
            guard += 1
            if guard > 100000:  # pragma: no cover - the AMP/NVB closure terminates
                raise RuntimeError("bisection closure did not terminate")
            touched = np.zeros(self._nv, dtype=bool)
            touched[W >> 32] = True
            touched[W & 0xFFFFFFFF] = True
            near = np.count_nonzero(touched[acells], axis=1) >= 2
            C = active[near]
            cc = acells[near]
            ref = (np.minimum(cc[:, 0], cc[:, 1]) << 32) | np.maximum(cc[:, 0], cc[:, 1])
            last = len(W) - 1
            rpos = np.minimum(np.searchsorted(W, ref), last)
            ref_in = W[rpos] == ref
            has = np.zeros(len(C), dtype=bool)
            hits = []
            for a, b in pairs:
                key = (np.minimum(cc[:, a], cc[:, b]) << 32) | np.maximum(cc[:, a], cc[:, b])
                pos = np.minimum(np.searchsorted(W, key), last)
                hit = W[pos] == key
                has |= hit
                hits.append(pos[hit])
            grow = has & ~ref_in
            contains = np.bincount(np.concatenate(hits), minlength=len(W))
            is_ref = np.bincount(rpos[ref_in], minlength=len(W))
            compatible = (contains == is_ref) & (is_ref > 0)
            if grow.any():
                # (a) and (b) in the same pass: the new edges cannot make an edge of W
                # compatible or incompatible, they only add work for the next pass
                W_new = np.union1d(W, ref[grow])
            else:
                W_new = None
            if not compatible.any() and W_new is not None:
                W = W_new
                continue
            if not compatible.any():
                # the refinement edges around some vertex form a cycle (possible with the
                # longest-edge labelling of an arbitrary mesh): bisect every leaf whose
                # refinement edge is wanted (AMP's rule), the next rounds close the patches
                compatible = is_ref > 0
                self._stats["cycle_breaks"] += 1
            go = ref_in & compatible[rpos]
            B = C[go]
            children = self._bisect(B, reg)
            done.append(B)
            done_edges = W[compatible & (contains == is_ref)]
            W = W_new if W_new is not None else W
            W = W[~np.isin(W, done_edges, assume_unique=True)]
            split = np.zeros(self._n, dtype=bool)
            split[B] = True
            keep = ~split[active]
            active = np.concatenate([active[keep], children])
            acells = np.concatenate([acells[keep], self._cells[children].astype(np.int64)])
        bisected = np.concatenate(done) if done else np.zeros(0, dtype=np.int64)
        self._leaves = self._expand_leaves(self._leaves)
        return bisected

    def _expand_leaves(self, seq: np.ndarray) -> np.ndarray:
        """Replace every non-leaf in seq by its leaves, depth first (child 0 first)."""
        while True:
            inner = self._child[seq] >= 0
            if not inner.any():
                return seq
            counts = 1 + inner.astype(np.int64)
            start = np.cumsum(counts) - counts
            out = np.repeat(seq, counts)
            c0 = self._child[seq[inner]]
            out[start[inner]] = c0
            out[start[inner] + 1] = c0 + 1
            seq = out

    # -- coarsening -----------------------------------------------------------------------------
    def _removable_generation(self, marked_forest: np.ndarray) -> np.ndarray:
        """Boolean mask over vertices: the newest removable generation (see the module doc).

        A vertex v created by bisection is a *candidate* if every cell containing it is
        marked. Removing v first needs the removal of every vertex w that is the midpoint of
        the parent of a cell containing v (w newer than v in that cell's history), or of a
        refined sibling of such a cell: edges v -> w of a dependency graph. Candidates with a
        dependency on a non-candidate are dropped until none is left (greatest closed set);
        the generation removed now is the sinks of the graph and every strongly connected
        component (a cycle that the closure can create around a vertex with cyclic
        refinement edges) whose dependencies stay inside it.
        """
        from scipy.sparse import coo_matrix  # heavy: imported when first needed (start-up time)
        from scipy.sparse.csgraph import (
            connected_components,  # heavy: imported when first needed (start-up time)
        )

        d = self.dim
        nv = self._nv
        L = self._leaves
        cells = self._cells[L]
        cand = np.ones(nv, dtype=bool)
        cand[: self._initial_vertices] = False
        cand[cells[~marked_forest[L]].ravel()] = False
        par = self._parent[L]
        has_p = par >= 0
        w = np.full(len(L), -1, dtype=np.int64)
        w[has_p] = self._mid[par[has_p]]
        src = cells.ravel()
        dst = np.repeat(w, d + 1)
        sel = (dst >= 0) & (src != dst)
        src, dst = src[sel], dst[sel]
        # a refined sibling: mid(parent) depends on mid(sibling)
        idx = np.flatnonzero(has_p)
        c0 = self._child[par[idx]]
        sib = np.where(L[idx] == c0, c0 + 1, c0)
        refined = self._child[sib] >= 0
        src = np.concatenate([src, w[idx[refined]]])
        dst = np.concatenate([dst, self._mid[sib[refined]]])
        while True:
            viol = cand[src] & ~cand[dst]
            if not viol.any():
                break
            cand[src[viol]] = False
        inside = cand[src]
        src, dst = src[inside], dst[inside]
        out = np.bincount(src, minlength=nv)
        gen = cand & (out == 0)
        # vertices left after peeling all sinks repeatedly are in or behind a cycle
        alive = cand.copy()
        while True:
            live = alive[src] & alive[dst]
            sinks = alive & (np.bincount(src[live], minlength=nv) == 0)
            if not sinks.any():
                break
            alive &= ~sinks
        if alive.any():
            live = alive[src] & alive[dst]
            graph = coo_matrix(
                (np.ones(int(live.sum())), (src[live], dst[live])), shape=(nv, nv)
            ).tocsr()
            _, comp = connected_components(graph, directed=True, connection="strong")
            # a component is removable now if no dependency leaves it
            leaves_comp = comp[src] != comp[dst]
            blocked = np.zeros(comp.max() + 1, dtype=bool)
            blocked[comp[src[leaves_comp]]] = True
            gen |= alive & ~blocked[comp]
        return gen

    def _coarsen_round(
        self, marked_forest: np.ndarray, dead_nodes: list, dead_vertices: list
    ) -> int:
        """Remove one generation of vertices (:meth:`_removable_generation`) where allowed.

        Undoes, bottom-up, every bisection at those vertices whose children are leaves (or
        undone already), then re-splits any undone cell that would leave a hanging node (a
        vertex it removed still used by another cell), until the mesh is conforming.
        Returns the number of bisections undone.
        """
        gen = self._removable_generation(marked_forest)
        if not gen.any():
            return 0
        L = self._leaves
        n = self._n
        collapsed = np.zeros(n, dtype=bool)
        # bottom-up: nodes bisected at a vertex of the generation, children leaves or undone
        is_leaf_or_c = np.zeros(n, dtype=bool)
        is_leaf_or_c[L] = True
        par = self._parent[L]
        has_p = par >= 0
        pm = np.full(len(L), -1, dtype=np.int64)
        pm[has_p] = self._mid[par[has_p]]
        frontier = np.unique(par[has_p & gen[np.maximum(pm, 0)] & marked_forest[L]])
        while frontier.size:
            c0 = self._child[frontier]
            ok = (
                gen[self._mid[frontier]]
                & is_leaf_or_c[c0]
                & is_leaf_or_c[c0 + 1]
                & ~collapsed[frontier]
            )
            new = frontier[ok]
            if new.size == 0:
                break
            collapsed[new] = True
            is_leaf_or_c[new] = True
            up = self._parent[new]
            frontier = np.unique(up[up >= 0])
        # resolve hanging nodes: un-collapse cells whose removed vertices are still in use;
        # only the leaves below collapsed cells are looked at
        aff = np.flatnonzero(has_p & collapsed[np.maximum(par, 0)])
        cells_L = self._cells[L]
        rest = np.ones(len(L), dtype=bool)
        rest[aff] = False
        used_rest = np.zeros(self._nv, dtype=bool)
        used_rest[cells_L[rest].ravel()] = True
        cells_A = cells_L[aff]
        while True:
            top_A = L[aff]
            while True:
                p = self._parent[top_A]
                up = p >= 0
                up[up] = collapsed[p[up]]
                if not up.any():
                    break
                top_A[up] = p[up]
            in_use = used_rest.copy()
            own = self._cells[top_A]  # (nA, d+1): vertices of the leaf's tentative cell
            in_use[own.ravel()] = True
            removed = ~np.any(cells_A[:, :, None] == own[:, None, :], axis=2)
            hanging = np.any(removed & in_use[cells_A], axis=1)
            if not hanging.any():
                break
            collapsed[np.unique(top_A[hanging])] = False
        top = L.copy()
        top[aff] = top_A
        first = np.ones(len(top), dtype=bool)
        first[1:] = top[1:] != top[:-1]
        tl = top[first]
        top_level = collapsed.copy()
        pc = self._parent[:n]
        inner = np.flatnonzero(collapsed)
        pi = pc[inner]
        top_level[inner[(pi >= 0) & collapsed[np.maximum(pi, 0)]]] = False
        P = np.flatnonzero(top_level)
        if P.size == 0:
            return 0
        # new leaf order: every run of leaves under one collapsed cell becomes that cell
        starts = np.flatnonzero(first)
        is_new = top_level[tl]
        self._src_start[tl[is_new]] = self._src_start[L[starts[is_new]]]
        self._src_count[tl[is_new]] = np.add.reduceat(self._src_count[L], starts)[is_new]
        dead_nodes.append(L[top != L])
        dead_inner = inner[(pi >= 0) & collapsed[np.maximum(pi, 0)]]
        dead_nodes.append(dead_inner)
        all_c = np.flatnonzero(collapsed)
        dead_vertices.append(np.unique(self._mid[all_c]))
        self._leaves = tl
        self._child[all_c] = -1
        self._mid[all_c] = -1
        marked_forest[P] = True
        return int(all_c.size)

    def _compact(self, dead_nodes: np.ndarray, dead_vertices: np.ndarray) -> None:
        """Remove dead forest nodes and vertices, keeping the order of the rest."""
        if dead_nodes.size:
            alive = np.ones(self._n, dtype=bool)
            alive[dead_nodes] = False
            new_id = np.cumsum(alive) - 1
            keep = np.flatnonzero(alive)
            for f in self._NODE_FIELDS:
                a = getattr(self, f)
                if a is not None:
                    a[: len(keep)] = a[keep]
            n = len(keep)
            for f in ("_parent", "_child"):
                a = getattr(self, f)[:n]
                pos = a >= 0
                a[pos] = new_id[a[pos]]
            self._n = n
            self._leaves = new_id[self._leaves]
        if dead_vertices.size:
            alive = np.ones(self._nv, dtype=bool)
            alive[dead_vertices] = False
            vid = np.cumsum(alive) - 1
            keepv = np.flatnonzero(alive)
            self._p[: len(keepv)] = self._p[keepv]
            self._nv = len(keepv)
            n = self._n
            self._cells[:n] = vid[self._cells[:n]]
            mid = self._mid[:n]
            pos = mid >= 0
            mid[pos] = vid[mid[pos]]
            if self._peaks is not None:
                self._peaks[:n] = vid[self._peaks[:n]]

    # -- public operations ----------------------------------------------------------------------
    def refine(self, marked) -> MeshChange:
        """Bisect the marked cells once (plus the closure). ``marked``: mask or indices."""
        return self.adapt(refine=marked)

    def coarsen(self, marked, rounds: int = 1) -> MeshChange:
        """Undo bisections whose whole patch is marked, up to ``rounds`` generations."""
        return self.adapt(coarsen=marked, coarsen_rounds=rounds)

    def uniform(self, times: int = 1) -> MeshChange:
        """Bisect every cell ``times`` times (d times halve every edge: one red refinement)."""
        times = check_int("times", times, minimum=1)
        change = None
        for _ in range(times):
            c = self.refine(np.ones(self.n_cells, dtype=bool))
            change = c if change is None else _compose(change, c)
        return change

    def adapt(
        self,
        refine=None,
        coarsen=None,
        *,
        coarsen_rounds: int = 1,
        max_dofs: int | None = None,
        degree: int = 1,
        components: int = 1,
        priority=None,
        max_level: int | None = None,
    ) -> MeshChange:
        """Coarsen, then refine, the current mesh; returns the :class:`MeshChange`.

        Parameters
        ----------
        refine, coarsen : boolean masks (n_cells,) or integer cell indices, optional
            Cells to bisect once / to merge back into their parents. A cell in both is refined.
        coarsen_rounds : int >= 0
            Generations of bisections that one call may undo (1: at most one level).
        max_dofs : int, optional
            Cap on the dofs of the P``degree`` space with ``components`` components after
            the call. If refining all marked cells would exceed it, only the marked cells of
            highest ``priority`` (default: largest cells first) are refined: the largest k such
            that the closure of the top k stays within the cap (bisection search on k).
            Coarsening always happens first and frees room.
        max_level : int, optional
            Marked cells of this bisection generation or deeper are not refined (the
            conformity closure may still bisect them).
        """
        coarsen_rounds = check_int("coarsen_rounds", coarsen_rounds, minimum=0)
        ref_ids = self._as_leaf_ids(refine, "refine")
        coa_ids = self._as_leaf_ids(coarsen, "coarsen")
        if max_level is not None:
            max_level = check_int("max_level", max_level, minimum=0)
            ref_ids = ref_ids[self._level[ref_ids] < max_level]
        old_points = self.points.copy()
        old_cells = self.cells
        old_cache = self._cache
        nc_old = self.n_cells
        self._src_start[self._leaves] = np.arange(nc_old)
        self._src_count[self._leaves] = 1
        old_id = self.mesh_id
        n_start = self._n
        was_leaf = np.zeros(n_start, dtype=bool)
        was_leaf[self._leaves] = True

        # coarsening first (refine marks win; merged nodes stay until compaction)
        merges = 0
        dead_nodes: list = []
        dead_vertices: list = []
        if coa_ids.size and coarsen_rounds:
            mf = np.zeros(self._n, dtype=bool)
            mf[coa_ids] = True
            mf[ref_ids] = False
            for _ in range(coarsen_rounds):
                done = self._coarsen_round(mf, dead_nodes, dead_vertices)
                merges += done
                if not done:
                    break
        n_dead_vertices = int(sum(len(v) for v in dead_vertices))

        # refinement (with the dof cap)
        bisected = np.zeros(0, dtype=np.int64)
        if ref_ids.size:
            if max_dofs is None:
                bisected = self._refine_leaves(ref_ids)
            else:
                bisected = self._refine_capped(
                    ref_ids, int(max_dofs), degree, components, priority, nc_old, n_dead_vertices
                )

        L = self._leaves
        unchanged = L < n_start
        unchanged[unchanged] = was_leaf[L[unchanged]]
        if merges:
            self._compact(np.concatenate(dead_nodes), np.concatenate(dead_vertices))
        if merges or bisected.size:
            self.mesh_id += 1
            self._cache = {}
        leaves = self._leaves
        return MeshChange(
            old_points=old_points,
            old_cells=old_cells,
            new_points=self.points.copy(),
            new_cells=self.cells,
            old_start=self._src_start[leaves].astype(np.int64),
            old_count=self._src_count[leaves].astype(np.int64),
            unchanged=unchanged,
            bisections=int(bisected.size),
            merges=merges,
            removed_vertices=n_dead_vertices,
            old_mesh_id=old_id,
            new_mesh_id=self.mesh_id,
            old_cache=old_cache,
            new_cache=self._cache,
        )

    def _refine_capped(
        self, ref_ids, max_dofs, degree, components, priority, nc_old, n_dead_vertices
    ):
        """Refine the top-k marked cells (by priority) with k maximal under the dof cap."""
        if priority is None:
            _, vol = barycentric_gradients(self._p[: self._nv].T, self._cells[ref_ids].T)
            prio = vol
        else:
            prio_all = np.asarray(priority, dtype=float)
            if prio_all.shape != (nc_old,):
                raise fail(
                    "priority",
                    described(f"an array of shape {prio_all.shape}"),
                    f"must have one value per cell ({nc_old})",
                )
            prio = prio_all[self._src_start[ref_ids]]
        order = np.argsort(-prio, kind="stable")
        ranked = ref_ids[order]

        def count_after(k):
            state = (self._n, self._nv, self._leaves)
            bis = self._refine_leaves(ranked[:k])
            dofs = self._ndofs_alive(degree, components, n_dead_vertices)
            return dofs, bis, state

        def rollback(bis, state):
            self._child[bis] = -1
            self._mid[bis] = -1
            self._n, self._nv, self._leaves = state

        dofs, bis, state = count_after(len(ranked))
        if dofs <= max_dofs:
            return bis
        rollback(bis, state)
        lo, hi = 0, len(ranked)  # f(lo) <= cap < f(hi)
        while hi - lo > 1:
            k = (lo + hi) // 2
            dofs, bis, state = count_after(k)
            rollback(bis, state)
            if dofs <= max_dofs:
                lo = k
            else:
                hi = k
        if lo == 0:
            return np.zeros(0, dtype=np.int64)
        return self._refine_leaves(ranked[:lo])

    def _ndofs_alive(self, degree, components, n_dead_vertices):
        nv = self._nv - n_dead_vertices
        if degree == 1:
            return components * nv
        nc = self.n_cells
        nb = self._boundary_face_count()
        if self.dim == 2:
            ne = (3 * nc + nb) // 2
        else:
            ne = nv + (4 * nc + nb) // 2 - nc - self._euler
        return components * (nv + ne)

    # -- checks ---------------------------------------------------------------------------------
    def _origin_out(self) -> np.ndarray:
        """Face origins (nc, d+1) in the vertex order of :attr:`cells` (face opposite vertex j)."""
        leaves = self._leaves
        stored = self._cells[leaves]
        out_order = self.cells
        k = np.argmax(out_order[:, :, None] == stored[:, None, :], axis=2)
        return np.take_along_axis(self._origin[leaves], k, axis=1)

    def is_conforming(self) -> bool:
        """True if no cell has a hanging node: every facet that only one cell has lies in a
        boundary facet of the initial mesh (a hanging node would leave a face seen once
        inside the domain)."""
        topo = FacetTopology(self.points.T, self.cells.T)
        orig = self._origin_out()[topo.boundary_cells, topo.boundary_local]
        ok = orig >= 0
        ok[ok] = self._facet_is_boundary[orig[ok]]
        return bool(np.all(ok))

    def shape_quality(self) -> np.ndarray:
        """d! |K| / h_K^d of every cell: a scale-free shape measure (0 = degenerate)."""
        p = self.points.T
        t = self.cells.T
        _, vol = barycentric_gradients(p, t)
        h = cell_diameters(p, t)
        fact = 2.0 if self.dim == 2 else 6.0
        return fact * vol / h**self.dim

    # -- checkpoint -----------------------------------------------------------------------------
    def checkpoint_state(self) -> dict:
        """The whole hierarchy as arrays (BRIEF checkpoint protocol); see :meth:`restore_state`."""
        n, nv = self._n, self._nv
        data = {
            "version": CHECKPOINT_VERSION,
            "dim": self.dim,
            "mesh_id": int(self.mesh_id),
            "points": self._p[:nv].copy(),
            "cells": self._cells[:n].copy(),
            "parent": self._parent[:n].copy(),
            "child": self._child[:n].copy(),
            "mid": self._mid[:n].copy(),
            "root": self._root[:n].copy(),
            "level": self._level[:n].copy(),
            "origin": self._origin[:n].copy(),
            "leaves": self._leaves.copy(),
            "root_input": self._root_input.copy(),
            "initial_facets": self._initial_facets.copy(),
            "facet_is_boundary": self._facet_is_boundary.copy(),
            "euler": int(self._euler),
            "initial_vertices": int(self._initial_vertices),
            "parts": {k: v.copy() for k, v in self._parts.items()},
            "subdomains": {k: v.copy() for k, v in self._subdomains.items()},
        }
        if self.dim == 3:
            data["peaks"] = self._peaks[:n].copy()
            data["flag"] = self._flag[:n].copy()
        return data

    @classmethod
    def restore_state(cls, data: dict) -> AdaptiveMesh:
        """An identical hierarchy (same cells, order, numbering, history) from checkpoint data."""
        from skfem import MeshTet, MeshTri  # heavy: imported when first needed (start-up time)

        if int(data.get("version", -1)) != CHECKPOINT_VERSION:
            raise fail(
                "checkpoint",
                data.get("version"),
                f"must be an adaptive-mesh checkpoint of version {CHECKPOINT_VERSION}",
            )
        self = cls.__new__(cls)
        d = int(data["dim"])
        self.dim = d
        self._mesh_cls = MeshTri if d == 2 else MeshTet
        n = len(data["cells"])
        nv = len(data["points"])
        self._init_storage(n, nv)
        self._n, self._nv = n, nv
        self._p[:nv] = data["points"]
        for f, key in (
            ("_cells", "cells"),
            ("_parent", "parent"),
            ("_child", "child"),
            ("_mid", "mid"),
            ("_root", "root"),
            ("_level", "level"),
            ("_origin", "origin"),
        ):
            getattr(self, f)[:n] = data[key]
        if d == 3:
            self._peaks[:n] = data["peaks"]
            self._flag[:n] = data["flag"]
        self._leaves = np.asarray(data["leaves"], dtype=np.int64).copy()
        self._root_input = np.asarray(data["root_input"], dtype=np.int64).copy()
        self._initial_facets = np.asarray(data["initial_facets"], dtype=np.int64).copy()
        self._facet_is_boundary = np.asarray(data["facet_is_boundary"], dtype=bool).copy()
        self._euler = int(data["euler"])
        self._parts = {k: np.asarray(v, dtype=bool).copy() for k, v in data["parts"].items()}
        self._subdomains = {
            k: np.asarray(v, dtype=bool).copy() for k, v in data["subdomains"].items()
        }
        self.mesh_id = int(data["mesh_id"])
        self._cache = {}
        self._stats = {"cycle_breaks": 0}
        self._initial_cells = len(self._root_input)
        self._initial_vertices = int(data["initial_vertices"])
        return self


def _compose(first: MeshChange, second: MeshChange) -> MeshChange:
    """A change equivalent to ``first`` then ``second`` when ``second`` only refines."""
    if second.merges:
        raise ValueError("compose: the second change must not coarsen")
    start = first.old_start[second.old_start]
    count = first.old_count[second.old_start]
    return MeshChange(
        old_points=first.old_points,
        old_cells=first.old_cells,
        new_points=second.new_points,
        new_cells=second.new_cells,
        old_start=start,
        old_count=count,
        unchanged=first.unchanged[second.old_start] & second.unchanged,
        bisections=first.bisections + second.bisections,
        merges=first.merges,
        removed_vertices=first.removed_vertices,
        old_mesh_id=first.old_mesh_id,
        new_mesh_id=second.new_mesh_id,
        old_cache=first.old_cache,
        new_cache=second.new_cache,
    )


__all__ = ["AdaptiveMesh", "MeshChange", "check_adaptable", "SKFEM_FACETS"]
