"""An :class:`~rothe.eld.problem.ELDProblem` distributed over the processes of a communicator.

Every process builds the same mesh (or receives it), partitions it
(:class:`rothe.fem.distributed.Partition`) and builds the serial problem on its overlap
submesh: the serial element kernels then give the rows of M, K and of the loads that the
process owns, exactly (every cell touching an owned dof is in the submesh). Those rows become
distributed PETSc matrices; the submesh's own matrices are dropped right away.

The Dirichlet boundary Gamma_D is small (O(N^{2/3}) dofs in 3D): its multiplier lambda, the
boundary mass M_G and the data G, G_dot, G_ddot on it are kept **replicated** on every process,
in the serial order of the constrained dofs (``constraint.dofs`` of the serial problem), so
lambda, the reactions and the outputs are the serial ones. Only the rows of M_G that a process
owns are assembled there; they are exchanged once (allgather) and M_G is factored on every
process (as serial: ``splu``).
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ...errors import RotheInputError
from ...fem.distributed import Partition
from ...fem.petsc_env import require_petsc
from ...io.checkpoint import digest
from ..problem import CONSISTENCY_TOL, ELDProblem


class GlobalBoundary:
    """The replicated Gamma_D: the subset of :class:`~rothe.eld.constraint.DirichletConstraint`
    the stepper and the outputs use (``dofs``, ``m``, ``parts``, ``boundary_mass``,
    ``multiplier_from_residual``, ``reactions``, ``l2_norm``), in the serial numbering."""

    def __init__(self, dofs, dim, parts, boundary_mass, weights):
        self.dofs = dofs
        self.m = int(dofs.size)
        self.dim = dim
        self.parts = parts
        self.boundary_mass = boundary_mass.tocsc()
        self._lu = spla.splu(self.boundary_mass, permc_spec="MMD_AT_PLUS_A") if self.m else None
        self._weights = weights

    def multiplier_from_residual(self, r_C: np.ndarray) -> np.ndarray:
        """lambda = M_G^{-1} r_C (the serial constraint's formula)."""
        if self.m == 0:
            return np.zeros(0)
        return self._lu.solve(np.asarray(r_C, dtype=float))

    def reactions(self, lam: np.ndarray) -> dict:
        """Reaction force per part: -int_P lambda ds = -(w_P . Lambda)."""
        L = np.asarray(lam).reshape(-1, self.dim)
        return {p: -(w @ L) for p, w in self._weights.items()}

    def l2_norm(self, lam: np.ndarray) -> float:
        """The L2 norm of lambda, sqrt(lam . (M_b lam))."""
        lam = np.asarray(lam)
        return float(np.sqrt(max(lam @ (self.boundary_mass @ lam), 0.0)))


class DistributedDamping:
    """The damping operator on owned dof vectors: the linear part's coefficients (the stepper
    applies C = a_M M + a_K K with the PETSc matrices) and N(v), N'(v) w by the serial
    quadrature on the overlap submesh after a ghost update (owned rows exact)."""

    def __init__(self, problem):
        self._problem = problem
        self._D = D = problem.local.damping_op
        self.mass_coef, self.stiffness_coef = D.mass_coef, D.stiffness_coef
        self.matrix = D.matrix
        self.is_linear = D.is_linear

    def nonlinear_apply(self, v: np.ndarray) -> np.ndarray:
        """N(v) on the owned rows, by the serial quadrature after a ghost update."""
        p = self._problem
        return self._D.nonlinear_apply(p.local_values(v))[p.partition.own_local]

    def nonlinear_jacobian_action(self, v: np.ndarray):
        """The action w -> N'(v) w on the owned rows."""
        p = self._problem
        act = self._D.nonlinear_jacobian_action(p.local_values(v))
        own = p.partition.own_local
        return lambda w: act(p.local_values(w))[own]


class DistributedELDProblem:
    """The problem on the processes of ``comm`` (module docstring).

    Parameters
    ----------
    mesh : the whole mesh (the same on every process)
    data : the keyword arguments of :class:`ELDProblem` but the mesh (``problem.definition``)
    comm : an mpi4py communicator (default ``MPI.COMM_WORLD``)
    u0, v0 : serial dof vectors of the initial data, when ``data`` has none or arrays

    Attributes: ``M``, ``K`` (PETSc matrices, distributed numbering), ``constraint`` (the
    replicated :class:`GlobalBoundary`), ``partition``, ``local`` (the serial problem on the
    overlap submesh, without its matrices), ``u0``, ``v0`` (owned parts), ``material``,
    ``damping``, ``T``, ``name``.
    """

    def __init__(self, mesh, data: dict, comm=None, *, u0=None, v0=None):
        MPI, PETSc = require_petsc()
        self.MPI, self.PETSc = MPI, PETSc
        self.comm = comm = MPI.COMM_WORLD if comm is None else comm
        data = dict(data)
        dim = mesh.p.shape[0]
        self.partition = part = Partition(mesh, data.get("degree", 1), comm, dim)
        arrays = {}
        for key, given in (("u0", u0), ("v0", v0)):
            value = data.get(key)
            if given is not None or (value is not None and not callable(value)):
                arrays[key] = np.asarray(given if given is not None else value, dtype=float)
                if arrays[key].shape != (part.n_global,):
                    raise RotheInputError(
                        f"{key}: got an array of shape {arrays[key].shape}, "
                        f"must be ({part.n_global},)"
                    )
                data[key] = None
        with warnings.catch_warnings():
            if comm.rank != 0:  # the notes on differenced G are the same on every process
                warnings.simplefilter("ignore")
            lp = ELDProblem(part.submesh, **data)
        if lp.space.n_scalar != part.keys.size:
            raise RuntimeError("the submesh's scalar dofs do not match the partition's keys")
        self.local = lp
        self.name = lp.name
        self.material = lp.material
        self.damping = lp.damping
        self.damping_op = lp.damping_op
        self.T = lp.T
        self.dim = dim
        self.degree = lp.space.degree
        self.ndofs = part.n_global
        self.n_own = part.n_own
        own = part.own_local
        # one matrix at a time into PETSc, each scipy copy dropped at once (the largest arrays
        # of the process: the peak of the set-up)
        self.M = part.petsc_matrix(lp.M, PETSc)
        lp.M = lp.damping_op.M = None
        self.K = part.petsc_matrix(lp.K, PETSc)
        lp.K = lp.damping_op.K = None
        lp.space.release_assembly_caches()
        self._mesh_digest = digest(np.ascontiguousarray(mesh.p), np.ascontiguousarray(mesh.t))
        self.n_cells = int(mesh.t.shape[1])
        self.u0 = arrays["u0"][part.serial_of_own] if "u0" in arrays else lp.u0[own].copy()
        self.v0 = arrays["v0"][part.serial_of_own] if "v0" in arrays else lp.v0[own].copy()
        self._build_boundary(lp, part)
        self.has_loads = lp.has_loads
        self._ghosts = None

    # -- ghost values (nonlinear damping: quadrature on the overlap submesh) ---------------------
    def local_values(self, w_own: np.ndarray) -> np.ndarray:
        """The values of a distributed vector (given by its owned part) at every dof of this
        process's overlap submesh, in the submesh's numbering: one PETSc scatter (ghost update).
        Collective."""
        PETSc, part = self.PETSc, self.partition
        if self._ghosts is None:
            g = PETSc.Vec().createMPI((part.n_own, part.n_global), comm=self.comm)
            loc = PETSc.Vec().createSeq(part.global_of_local.size, comm=PETSc.COMM_SELF)
            index = PETSc.IS().createGeneral(part.global_of_local, comm=PETSc.COMM_SELF)
            self._ghosts = (g, loc, PETSc.Scatter().create(g, index, loc, None))
        g, loc, scatter = self._ghosts
        g.setArray(w_own)
        scatter.scatter(g, loc, addv=PETSc.InsertMode.INSERT_VALUES, mode=PETSc.ScatterMode.FORWARD)
        return loc.getArray().copy()

    # -- Gamma_D --------------------------------------------------------------------------------
    def _build_boundary(self, lp, part) -> None:
        comm, d = self.comm, self.dim
        c = lp.constraint
        position = np.full(lp.space.ndofs, -1, dtype=np.int64)
        position[part.own_local] = np.arange(part.n_own)
        serial = d * part.keys[c.dofs // d] + c.dofs % d  # serial number of the local Gamma_D
        owned = position[c.dofs] >= 0
        all_dofs = np.unique(np.concatenate(comm.allgather(serial[owned])))
        self.c_owned = np.flatnonzero(owned)  # positions in the local constraint's vectors
        self.C = position[c.dofs[owned]]  # owned constrained dofs (indices of owned arrays)
        self.bpos = np.searchsorted(all_dofs, serial[owned])  # their places in the serial order
        # M_G: the owned rows, columns by serial place
        Mg = sp.csr_matrix(c.boundary_mass)[self.c_owned].tocoo()
        rows = self.bpos[Mg.row]
        cols = np.searchsorted(all_dofs, serial[Mg.col])
        trip = comm.allgather((rows, cols, Mg.data))
        m = all_dofs.size
        MG = sp.csr_matrix(
            (
                np.concatenate([t[2] for t in trip]),
                (np.concatenate([t[0] for t in trip]), np.concatenate([t[1] for t in trip])),
            ),
            shape=(m, m),
        )
        # reaction weights (column sums of the part's boundary mass = row sums: complete on
        # the owned scalar dofs)
        sc_serial = part.keys[c.scalar_dofs]
        sc_owned = np.flatnonzero(position[d * c.scalar_dofs] >= 0)
        all_scalar = all_dofs[::d] // d
        weights = {}
        for p_name, w in c.reaction_weights.items():
            got = comm.allgather((np.searchsorted(all_scalar, sc_serial[sc_owned]), w[sc_owned]))
            full = np.zeros(all_scalar.size)
            for idx, vals in got:
                full[idx] = vals
            weights[p_name] = full
        self.constraint = GlobalBoundary(all_dofs, d, c.parts, MG, weights)

    def boundary_values(self, t: float, which=("G", "G_dot", "G_ddot")) -> list[np.ndarray]:
        """G, G_dot, G_ddot at t on the whole Gamma_D (serial order), on every process: each
        process evaluates its owned part (the serial problem's functions), one allgather."""
        lp = self.local
        mine = np.array([getattr(lp, w)(t)[self.c_owned] for w in which]).reshape(len(which), -1)
        out = np.empty((len(which), self.constraint.m))
        for pos, vals in self.comm.allgather((self.bpos, mine)):
            out[:, pos] = vals
        return list(out)

    def gather_boundary(self, *owned_vectors) -> list[np.ndarray]:
        """The values of owned full vectors on the whole Gamma_D (serial order), everywhere."""
        mine = np.array([w[self.C] for w in owned_vectors]).reshape(len(owned_vectors), -1)
        out = np.empty((len(owned_vectors), self.constraint.m))
        for pos, vals in self.comm.allgather((self.bpos, mine)):
            out[:, pos] = vals
        return list(out)

    def load(self, t: float) -> np.ndarray:
        """F(t) on the owned dofs."""
        if not self.has_loads:
            return np.zeros(self.n_own)
        return self.local.load(t)[self.partition.own_local]

    def step_bound(self) -> float:
        """The local problem's step bound."""
        return self.local.step_bound()

    def check_initial_consistency(self) -> None:
        """Raise RotheInputError unless u0 equals G(0) on the Dirichlet parts within tolerance."""
        g0 = self.boundary_values(0.0, ("G",))[0]
        u0C = self.gather_boundary(self.u0)[0]
        err = float(np.max(np.abs(u0C - g0))) if g0.size else 0.0
        scale = max(
            1.0,
            float(np.max(np.abs(g0), initial=0.0)),
            self.comm.allreduce(float(np.max(np.abs(self.u0), initial=0.0)), op=self.MPI.MAX),
        )
        if not err <= CONSISTENCY_TOL * scale:
            raise RotheInputError(
                f"u0: got max|u0 - G(0)| = {err:.3g} on the Dirichlet parts "
                f"{', '.join(self.constraint.parts)}, must equal G(0) there within "
                f"{CONSISTENCY_TOL * scale:.3g} (consistent initial data, Remark 2.2)"
            )

    # -- description and identity -----------------------------------------------------------------
    def describe(self) -> dict:
        """The local description with global dofs, constrained dofs, cells and processes."""
        info = self.local.describe()
        info.update(
            ndofs=self.ndofs,
            constrained_dofs=self.constraint.m,
            cells=self.n_cells,
            processes=int(self.comm.size),
        )
        return info

    def fingerprint(self) -> dict:
        """What a checkpoint must match (:func:`rothe.io.checkpoint.problem_fingerprint`)."""
        desc = self.describe()
        desc.pop("processes")
        return {
            "class": "ELDProblem",
            "ndofs": int(self.ndofs),
            "T": float(self.T),
            "mesh": self._mesh_digest,
            "description": digest(
                np.frombuffer(json.dumps(desc, sort_keys=True, default=str).encode(), np.uint8)
            ),
        }

    @classmethod
    def from_problem(cls, problem: ELDProblem, comm=None) -> DistributedELDProblem:
        """The distributed copy of a serial problem (its mesh and data; u0, v0 as given)."""
        return cls(problem.space.mesh, problem.definition, comm, u0=problem.u0, v0=problem.v0)
