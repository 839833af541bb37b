"""One mesh on many processes: partition, dof numbering and PETSc matrices from local assembly.

**Partition** (:func:`coordinate_bisection`). Recursive coordinate bisection of the vertices:
split the longest extent of the point set at the quantile that gives each side its share of
the parts, recursively, ties broken by the vertex number (so every process computes the same
partition from the same mesh). For the compact bodies of ``rothe`` (beams, boxes, plates) the
cut surfaces are planes across the short directions, as METIS would choose for a beam; for
meshes of complicated shape a graph partitioner cuts fewer edges (a limit, docs/scaling.md).

**Ownership and numbering.** A vertex belongs to its part; a P2 edge dof to the part of the
edge's smaller vertex number. The serial scalar dof numbering of scikit-fem (vertices, then
edges) is the *key* of a dof; the distributed numbering orders the keys by owner (rank 0's
first), inside one owner by key, so every process owns one contiguous range of scalar dofs
and, with the d components interleaved (block size d), of vector dofs:
``new_vector = d * new_scalar[key] + component``.

**Assembly without communication** (:class:`Partition`). Process r keeps the cells that touch
one of its vertices (the *overlap submesh*, with the named boundary parts restricted to it).
Every cell that contributes to a row r owns is there, so the serial assembly on the submesh
gives those rows exactly; the other rows (ghost dofs on the overlap's rim) are dropped. The
cost is one layer of duplicated cells per interface. The owned rows become one distributed
PETSc AIJ matrix (:meth:`Partition.petsc_matrix`, block size d, 32-bit indices in the PyPI
build of PETSc: at most 2^31 - 1 dofs and nonzeros per process).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..errors import RotheInputError


def coordinate_bisection(points: np.ndarray, nparts: int) -> np.ndarray:
    """The part (0..nparts-1) of every point (n, d) by recursive coordinate bisection."""
    n = points.shape[0]
    owner = np.zeros(n, dtype=np.int32)

    def split(idx: np.ndarray, first: int, count: int) -> None:
        if count == 1 or idx.size == 0:
            owner[idx] = first
            return
        left = count // 2
        x = points[idx]
        axis = int(np.argmax(x.max(axis=0) - x.min(axis=0)))
        # stable order by (coordinate, vertex number): the same on every process
        order = np.lexsort((idx, x[:, axis]))
        cut = int(round(idx.size * left / count))
        split(idx[order[:cut]], first, left)
        split(idx[order[cut:]], first + left, count - left)

    split(np.arange(n), 0, int(nparts))
    return owner


def _edge_codes(edges: np.ndarray, nv: int) -> np.ndarray:
    lo, hi = np.minimum(edges[0], edges[1]), np.maximum(edges[0], edges[1])
    return lo.astype(np.int64) * nv + hi


class Partition:
    """The part of a mesh one process works on (module docstring).

    Attributes
    ----------
    submesh : the overlap submesh (scikit-fem mesh with the named boundaries restricted)
    keys : (n_local_scalar,) serial scalar dof number of every scalar dof of the submesh's
        degree-``degree`` space (vertices first, then edges), i.e. of ``VectorSpace(submesh)``
    new_scalar : (n_scalar_global,) distributed number of every serial scalar dof
    ranges : (size + 1,) owned scalar dof range of every process in the distributed numbering
    own_local : local vector dofs of the submesh that this process owns, ordered by their
        distributed number (the rows it contributes)
    """

    def __init__(self, mesh, degree: int, comm, dim: int):
        size, rank = comm.size, comm.rank
        self.comm = comm
        self.dim = d = dim
        self.degree = int(degree)
        nv = mesh.p.shape[1]
        ncells = mesh.t.shape[1]
        if size > nv or size > ncells:
            raise RotheInputError(
                f"processes: got {size}, must be at most the mesh's {min(nv, ncells)} "
                f"{'vertices' if nv <= ncells else 'cells'} (every process needs a part): "
                "run on fewer processes or a finer mesh"
            )
        owner_v = coordinate_bisection(np.ascontiguousarray(mesh.p.T), size)
        if degree == 1:
            owner_keys = owner_v
        elif degree == 2:
            edges = mesh.edges
            owner_keys = np.concatenate([owner_v, owner_v[np.minimum(edges[0], edges[1])]])
        else:
            raise RotheInputError(f"degree: got {degree}, must be 1 or 2")
        counts = np.bincount(owner_keys, minlength=size)
        if np.any(counts == 0):
            raise RotheInputError(
                f"processes: got {size}, the mesh leaves a process without "
                "dofs: run on fewer processes or a finer mesh"
            )
        self.ranges = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        order = np.argsort(owner_keys, kind="stable")  # by owner, inside an owner by key
        self.new_scalar = np.empty(order.size, dtype=np.int64)
        self.new_scalar[order] = np.arange(order.size)
        self.n_scalar = int(order.size)
        self.owner_v = owner_v
        # the overlap submesh: every cell with a vertex of this part
        self.whole = size == 1  # one process: the submesh is the mesh, every numbering the serial
        if self.whole:
            # (mesh.restrict of every cell would copy the mesh and rebuild its facets: 2 s at
            # 420 k dofs, a sixth of the problem's set-up)
            cells, self.submesh, ix = np.arange(ncells), mesh, np.arange(nv)
        else:
            cells = np.flatnonzero((owner_v[mesh.t] == rank).any(axis=0))
            self.submesh, ix = mesh.restrict(cells, return_mapping=True)
        self.cells = cells
        keys = [np.asarray(ix, dtype=np.int64)]
        if self.whole and degree == 2:
            keys.append(nv + np.arange(mesh.edges.shape[1], dtype=np.int64))
        elif degree == 2:
            gcodes = _edge_codes(mesh.edges, nv)
            sort = np.argsort(gcodes)
            lcodes = _edge_codes(ix[self.submesh.edges], nv)
            pos = sort[np.searchsorted(gcodes, lcodes, sorter=sort)]
            keys.append(nv + pos.astype(np.int64))
        self.keys = np.concatenate(keys)
        owned_scalar = np.flatnonzero(owner_keys[self.keys] == rank)
        owned_scalar = owned_scalar[np.argsort(self.new_scalar[self.keys[owned_scalar]])]
        self.own_scalar = owned_scalar
        self.own_local = (d * owned_scalar[:, None] + np.arange(d)[None, :]).ravel()
        self.rstart = int(d * self.ranges[rank])
        self.n_own = int(self.own_local.size)
        self.n_global = int(d * self.n_scalar)
        if d * self.n_scalar >= 2**31:
            raise RotheInputError(
                f"mesh: got {d * self.n_scalar} dofs, must be below 2^31 for "
                "PETSc's 32-bit indices (a PETSc built with 64-bit indices "
                "is not supported yet)"
            )
        # local vector dof -> distributed global vector dof (int32: PETSc's index type, and
        # the column indices of the owned rows need no second copy)
        self.global_of_local = (
            (d * self.new_scalar[self.keys][:, None] + np.arange(d)[None, :])
            .ravel()
            .astype(np.int32)
        )
        # owned vector dof (in owned order) -> serial vector dof (outputs, checkpoints)
        self.serial_of_own = (d * self.keys[owned_scalar][:, None] + np.arange(d)[None, :]).ravel()

    # -- matrices -------------------------------------------------------------------------------
    def owned_rows(self, A) -> sp.csr_matrix:
        """The owned rows of a submesh matrix, columns in the distributed numbering (sorted)."""
        if self.whole:  # one process: the serial numbering, every row owned
            A = sp.csr_matrix(A)
            A.sort_indices()
            return A
        A = sp.csr_matrix(A)[self.own_local]
        out = sp.csr_matrix(
            (A.data, self.global_of_local[A.indices], A.indptr), shape=(self.n_own, self.n_global)
        )
        out.sort_indices()
        return out

    def petsc_matrix(self, A, PETSc):
        """The distributed PETSc AIJ matrix (block size d) whose owned rows are those of the
        submesh matrix ``A`` (module docstring)."""
        R = self.owned_rows(A)
        M = PETSc.Mat().create(comm=self.comm_petsc(PETSc))
        M.setSizes(((self.n_own, self.n_global), (self.n_own, self.n_global)), bsize=self.dim)
        M.setType("aij")
        # setPreallocationCSR copies the arrays (createAIJ(csr=...) may keep pointers to them)
        M.setPreallocationCSR(
            (R.indptr.astype(PETSc.IntType), R.indices.astype(PETSc.IntType), R.data)
        )
        M.assemble()
        return M

    def comm_petsc(self, PETSc):
        """The partition's communicator as a PETSc communicator."""
        return PETSc.Comm(self.comm)

    # -- vectors --------------------------------------------------------------------------------
    def gather_serial(self, w: np.ndarray, root: int = 0) -> np.ndarray | None:
        """The owned parts of a distributed vector, as one serial-numbered vector on ``root``
        (None elsewhere). Collective."""
        comm = self.comm
        if not getattr(self, "_gathered_index", False):  # the same on every process
            idx = comm.gather(self.serial_of_own, root=root)
            self._all_idx = np.concatenate(idx) if comm.rank == root else None
            self._gathered_index = True
        parts = comm.gather(np.ascontiguousarray(w, dtype=float), root=root)
        if comm.rank != root:
            return None
        out = np.empty(self.n_global)
        out[self._all_idx] = np.concatenate(parts)
        return out

    def scatter_serial(self, full: np.ndarray | None, root: int = 0) -> np.ndarray:
        """The owned part of a serial-numbered vector held on ``root``."""
        comm = self.comm
        idx = comm.gather(self.serial_of_own, root=root)
        chunks = None
        if comm.rank == root:
            full = np.asarray(full, dtype=float)
            chunks = [full[i] for i in idx]
        return np.asarray(comm.scatter(chunks, root=root), dtype=float)
