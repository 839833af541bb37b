"""The linear algebra of the steps on one mesh: everything of a run that depends on the mesh.

An :class:`ELDSystem` holds the problem on its mesh, the free dofs, the damping operator, the
step data (:class:`rothe.eld.data.StepData`), the right inverse B^- (regularized form) with its
thin products, the linear solver with its stored factorization and the key it was built from,
and the sparsity pattern of the step matrix. A space-adaptive run builds a new one on every new
mesh (the *rebuild* phase of the adapt cycle, :mod:`rothe.eld.adapt`); a run on a fixed mesh
builds one. :class:`RegularizedSystem` and :class:`OriginalSystem` are the two forms
(:mod:`rothe.eld.form`).

Since y^j = (alpha_0 x^j + h_x)/tau_j and b^j = (alpha_0 y^j + h_y)/tau_j with history terms h
(:mod:`rothe.eld.stepper`), the step operator in x is, with the effective step
tau_eff = tau_j / alpha_0,

    A(tau_eff) x = (rho/tau_eff^2) M x + D((x + ...)/tau_eff) + K x,
    for linear damping C:  rho alpha_0^2/tau_j^2 M + alpha_0/tau_j C + K,

restricted to the free dofs (ker B, regularized form) or bordered by B (original form).

Linear algebra: with linear damping and constant tau_eff the step matrix is factored once and
every step is one back-substitution plus two sparse products (M x, K x; every other product is
a combination of cached ones and thin products with the lifted data). When tau_eff changes,
the system is solved by Krylov iterations preconditioned with the stored factorization, which is
rebuilt from the current matrix when they stall (below :data:`REFACTOR_BELOW` unknowns with the
direct solver: a new LU for every new tau_eff). Nonlinear damping: Newton's method
(:mod:`rothe.eld.stepper`), corrections by Krylov iterations preconditioned the same way
(:mod:`rothe.eld.solvers`). With linear damping and no user matrix, A(tau_eff) restricted to the
free nodes is gathered from the blocks of K and the scalar mass
(:meth:`rothe.fem.elasticity.VectorSpace.restricted_combination`): A itself and its row and
column slices (0.6 GB each at a million unknowns) are never formed.

The factorization is a function of a *key* (tau_eff and, for nonlinear damping, the velocity of
the Jacobian it factors), so that a checkpoint can name it (:attr:`ELDSystem.reference`,
:meth:`ELDSystem.restore_reference`). Factorizations and solves are timed into ``times``
(phases ``factor`` and ``solve``; a Krylov solve that rebuilds its preconditioner counts as
``solve``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..fem.topology import cell_diameters
from ..timing import PhaseTimes
from .constraint import NodalLifting, make_lifting
from .data import StepData
from .materials import pressure_wave_speed
from .solvers import SHORT_LIVED_AMG, ConstrainedSolver, ReferenceSolver, resolve_kind
from .state import PRODUCTS, ELDState

#: below this many unknowns a new tau_eff gets its own LU (cheaper than ~10 preconditioned
#: Krylov iterations with the stored one; measured: factor / solve ~ 26 at 25k in 2D)
REFACTOR_BELOW = 20_000


def _dot(a, b) -> float:
    return float(a @ b)


class ELDSystem:
    """The steps' linear algebra on one mesh (module docstring); build with :meth:`build`.

    Parameters
    ----------
    problem : ELDProblem
        The problem on this mesh.
    tau_eff : float
        The effective step tau/alpha_0 of the first matrix, factored now with linear damping.
    variable_steps : bool
        Whether the steps vary (adaptive or given): new tau_eff are assembled on a stored
        pattern then.
    solver : {'auto', 'direct', 'amg'}
    linear_rtol : float
        Relative residual of the iterative linear solves.
    data : DataMode, optional
        How the data of a step enter (:mod:`rothe.eld.data`).
    noise : DataNoise, optional
    times : PhaseTimes, optional
        Where ``factor`` and ``solve`` are timed.
    symmetric_lu : bool
        LU in SuperLU's symmetric mode (:class:`rothe.eld.solvers.ReferenceSolver`; space
        adaptivity: one factorization per mesh).
    short_lived : bool
        A mesh of a space-adaptive run (it lives ``adapt_every`` steps): 'auto' takes LU in
        3D up to fewer unknowns and above them Jacobi-CG when the CFL number (:meth:`cfl`) is
        moderate (:func:`rothe.eld.solvers.resolve_kind`), and AMG builds its hierarchy with
        the cheap setup :data:`rothe.eld.solvers.SHORT_LIVED_AMG`.
    """

    #: the right inverse B^- (regularized form), None in the original form
    lifting = None

    def __init__(
        self,
        problem,
        *,
        tau_eff: float,
        variable_steps: bool,
        solver: str = "auto",
        linear_rtol: float = 1e-10,
        data=None,
        noise=None,
        times: PhaseTimes | None = None,
        symmetric_lu: bool = False,
        short_lived: bool = False,
    ):
        self.problem = p = problem
        #: the run made ``problem`` for this system (an adaptive rebuild): :meth:`release` may
        #: drop its matrices; False for the caller's problem
        self.owns_problem = False
        #: :meth:`release` dropped what solving needs (:meth:`revived` builds it again)
        self.released = False
        self.symmetric_lu = bool(symmetric_lu)
        self.times = times if times is not None else PhaseTimes()
        self.data = StepData(p, data, noise)
        c = p.constraint
        self.rho = p.material.rho
        self.D = p.damping_op
        self.I = c.free
        self.variable_steps = bool(variable_steps)
        self._A_te = tau_eff
        self._A_stored = None
        self._parts = None
        self._ref: dict | None = None  # what the solver's stored factorization was built from
        self._mass_values = None  # the scalar mass of the cells' densities (several materials)
        self._free_nodes = free_nodes = np.setdiff1d(np.arange(p.space.n_scalar), c.scalar_dofs)
        self._lean = self.D.matrix is None
        self.kind = resolve_kind(
            solver,
            self.I.size,
            p.space.dim,
            short_lived,
            self.cfl(tau_eff) if short_lived and p.space.dim == 3 else None,
        )
        self._amg_options = dict(SHORT_LIVED_AMG) if short_lived else None
        rbm = p.space.rigid_body_modes(free_nodes) if self.kind == "amg" else None
        self.solver = self._make_solver(rbm, linear_rtol)
        self._store_first_matrix(tau_eff)
        if self.D.is_linear:
            self.factor(tau_eff, None)
        self.initial_factorizations = self.solver.stats.factorizations

    def cfl(self, te: float) -> float:
        """The CFL number of A(te) on this mesh, c_p sqrt(rho c_stiff / c_mass) / h_min
        (= c_p te / h_min undamped; c_p of the fastest material, h_min the shortest cell
        diameter): with it the Jacobi-scaled A(te) has a bounded condition number (mass-
        dominated), which decides the solver of a short-lived 3D mesh
        (:func:`rothe.eld.solvers.resolve_kind`)."""
        c_mass, c_stiff = self.coefficients(te)
        mesh = self.problem.space.mesh
        h_min = float(cell_diameters(mesh.p, mesh.t).min())
        c_p = pressure_wave_speed(self.problem.material)
        return c_p * float(np.sqrt(self.rho * c_stiff / c_mass)) / h_min

    @staticmethod
    def build(problem, form, **kwargs) -> ELDSystem:
        """The system of ``form`` (a :class:`rothe.eld.form.Form`) for ``problem``; the keyword
        arguments are those of :class:`ELDSystem`."""
        if form.lifting is None:
            return OriginalSystem(problem, **kwargs)
        return RegularizedSystem(problem, lifting=form.lifting, **kwargs)

    def rebuilt(self, problem, **changes) -> ELDSystem:
        """The same system on the problem ``problem`` (on a new mesh), its solver's counters
        continued from this one's and its first factorization counted; ``changes`` replace
        keyword arguments of the constructor (e.g. ``symmetric_lu``)."""
        new = type(self)(problem, **dict(self._arguments, **changes))
        new.solver.stats = replace(self.solver.stats)
        new.solver.stats.factorizations += new.initial_factorizations
        return new

    # -- what the forms define ------------------------------------------------------------------
    def _make_solver(self, near_nullspace, rtol):
        raise NotImplementedError  # pragma: no cover - each form defines its solver

    def _store_first_matrix(self, te: float) -> None:
        """Keep A(te) of the first step (at a million unknowns every matrix of this size costs
        0.6 GB: only this one)."""
        self._A_stored = self._operator_matrix(te)

    @property
    def size(self) -> int:
        """Unknowns of the step's linear systems."""
        raise NotImplementedError  # pragma: no cover

    @property
    def A_II(self):
        """The stored step matrix A(tau_eff) on the free dofs (regularized form; else None)."""
        return None

    # -- matrices -------------------------------------------------------------------------------
    @property
    def ndofs(self) -> int:
        """The dofs of the space on this mesh."""
        return self.problem.space.ndofs

    def coefficients(self, te: float) -> tuple[float, float]:
        """(c_mass, c_stiff) of A(te) = c_mass M + c_stiff K (+ E/te)."""
        D = self.D
        return self.rho / te**2 + D.mass_coef / te, 1.0 + D.stiffness_coef / te

    def _step_matrix(self, te: float) -> sp.csr_matrix:
        """A(te) = (rho/te^2) M + C/te + K with C = a_M M + a_K K (+ E), without forming C."""
        p, D = self.problem, self.D
        A = (
            (self.rho / te**2 + D.mass_coef / te) * p.M + (1.0 + D.stiffness_coef / te) * p.K
        ).tocsr()
        if D.matrix is not None:
            A = (A + (1.0 / te) * D.matrix).tocsr()
        return A

    def _restricted(self, te: float):
        """A(te) on the free nodes, a BlockMatrix gathered from K and the scalar mass (of the
        cells' densities rho_c/rho_ref with several materials, as the problem's M)."""
        c_mass, c_stiff = self.coefficients(te)
        p = self.problem
        cells = getattr(p, "cell_material", None)
        if cells is not None and self._mass_values is None:
            self._mass_values = p.space.weighted_scalar_mass_values(cells.density_weight)
        return p.space.restricted_combination(
            p.K, c_stiff, c_mass, self._free_nodes, mass_values=self._mass_values
        )

    def _apply_full(self, full: np.ndarray, te: float) -> np.ndarray:
        """A(te) times a full dof vector."""
        p, D = self.problem, self.D
        out = (self.rho / te**2 + D.mass_coef / te) * (p.M @ full) + (
            1.0 + D.stiffness_coef / te
        ) * (p.K @ full)
        if D.matrix is not None:
            out = out + (D.matrix @ full) / te
        return out

    def _pattern_parts(self):
        """The system's sparsity pattern with the values of M, K, E (and B) on it, so that A(te)
        for a new te is one linear combination of value arrays (variable steps)."""
        if self._parts is None:
            p, D = self.problem, self.D
            n = p.space.ndofs
            E = sp.csr_matrix(D.matrix) if D.matrix is not None else sp.csr_matrix((n, n))
            P = sp.csr_matrix(self._system_of(p.M + p.K + E, self._pattern_border()))
            P.sum_duplicates()
            P.sort_indices()
            ncol = P.shape[1]
            keys = (
                np.repeat(np.arange(P.shape[0], dtype=np.int64), np.diff(P.indptr)) * ncol
                + P.indices
            )

            def on_pattern(X):
                X = sp.csr_matrix(X)
                X.sum_duplicates()
                xk = (
                    np.repeat(np.arange(X.shape[0], dtype=np.int64), np.diff(X.indptr)) * ncol
                    + X.indices
                )
                out = np.zeros(keys.size)
                out[np.searchsorted(keys, xk)] = X.data
                return out

            border = self._pattern_border()
            parts = {
                "M": on_pattern(self._system_of(p.M)),
                "K": on_pattern(self._system_of(p.K)),
                "E": on_pattern(self._system_of(E)),
                "B": None
                if border is None
                else on_pattern(self._system_of(sp.csr_matrix((n, n)), border)),
            }
            self._parts = (P.indices.copy(), P.indptr.copy(), P.shape, parts)
        return self._parts

    def _system_matrix(self, te: float, v: np.ndarray | None) -> sp.csr_matrix:
        """The matrix a factorization is built from: A(te) (+ N'(v)/te), restricted or bordered.
        A function of (te, v) alone, so that a checkpoint can name it (variable steps with
        linear damping: by value arrays on a fixed pattern, :meth:`_pattern_parts`)."""
        if v is None and self.variable_steps:
            indices, indptr, shape, parts = self._pattern_parts()
            D = self.D
            data = (
                (self.rho / te**2 + D.mass_coef / te) * parts["M"]
                + (1.0 + D.stiffness_coef / te) * parts["K"]
                + (1.0 / te) * parts["E"]
            )
            if parts["B"] is not None:
                data = data + parts["B"]
            return sp.csr_matrix((data, indices.copy(), indptr.copy()), shape=shape)
        A = self._step_matrix(te)
        if v is not None:
            A = (A + (1.0 / te) * self.D.nonlinear_jacobian(v)).tocsr()
        return self._of_full(A)

    # -- factorizations and solves --------------------------------------------------------------
    def factor(self, te: float, v: np.ndarray | None) -> None:
        """Factor A(te) (+ N'(v)/te) and remember the key (te, v) (the solver times the
        factorization)."""
        self._factor(te, v)
        self._ref = {"tau_eff": float(te), "v": None if v is None else v.copy()}

    def _factor(self, te: float, v: np.ndarray | None) -> None:
        self.solver.factor(self._system_matrix(te, v))

    def assembler(self, te: float, v: np.ndarray | None):
        """A callable that assembles the matrix of key (te, v) for the solver (when its Krylov
        iterations stall) and remembers that key."""

        def assemble():
            self._ref = {"tau_eff": float(te), "v": None if v is None else v.copy()}
            return self._system_matrix(te, v)

        return assemble

    def solve(self, A, rhs: np.ndarray, *, assemble, rtol: float | None = None) -> np.ndarray:
        """A z = rhs by Krylov iterations preconditioned with the stored factorization
        (rebuilt by ``assemble`` when they stall)."""
        with self.times.phase("solve"):
            return self.solver.solve(A, rhs, assemble=assemble, rtol=rtol)

    def solve_linear(self, rhs: np.ndarray, te: float, guess=None) -> np.ndarray:
        """A(te) z = rhs (bordered in the original form) for linear damping."""
        ref = self._ref
        if ref is not None and ref["v"] is None and ref["tau_eff"] == te:
            with self.times.phase("solve"):
                return self.solver.solve_reference(rhs, x0=guess)
        n = rhs.size
        if self.kind == "direct" and n <= REFACTOR_BELOW:
            self.factor(te, None)
            with self.times.phase("solve"):
                return self.solver.solve_reference(rhs, x0=guess)
        return self.solve(self._operator(te, n), rhs, assemble=self.assembler(te, None))

    def snapshot(self, stored: bool = True) -> dict:
        """The key of the stored factorization and the solver's state (references, see
        :meth:`~rothe.eld.solvers.ReferenceSolver.snapshot`), for :meth:`rollback`.
        ``stored=False``: the key and the counters only, so that the snapshot does not keep
        the factorization alive after :meth:`release`."""
        return {"ref": self._ref, "solver": self.solver.snapshot(stored)}

    def rollback(self, state: dict) -> None:
        """Put back what :meth:`snapshot` returned (no refactorization: the stored one is the
        very object that was stored then; a snapshot without it refactors the matrix of its
        key if another one is stored now, its counters as they were)."""
        if state["solver"]["stored"] is None:
            self.restore_reference(state["ref"])
        self._ref = state["ref"]
        self.solver.rollback(state["solver"])

    # -- one mesh's system alive at a time (space adaptivity) ------------------------------------
    def release(self) -> None:
        """Drop what solving on this mesh needs and recording a step on it does not: the stored
        step matrix, the factorization or AMG hierarchy, the pattern's value arrays, the thin
        products and the space's assembly caches, and, when the run made this system's problem
        (:attr:`owns_problem`: an adaptive rebuild's, never the caller's), the problem's K, M
        and damping operator (about 34 MB for a 15k-dof P2 mesh in 3D). What stays: the
        problem's space, constraint and material, the key of the stored factorization and the
        solver's counters. The space-adaptive rebuild calls it on the system of the mesh it
        leaves before it builds the new one (:meth:`rothe.eld.adapt.ELDAdaptivity.rebuild`), so
        that one mesh's system lives at a time; :meth:`revived` makes a working system again."""
        if self.released:
            return
        self.released = True
        self.solver.release()
        self._A_stored = self._parts = self._mass_values = None
        self._release_form()
        self.problem.space.release_assembly_caches()
        if self.owns_problem:
            self.problem.release_operators()
            self.D = None

    def _release_form(self) -> None:
        """What the form keeps besides the solver (:meth:`release`)."""

    def revived(self) -> ELDSystem:
        """This system, or after :meth:`release` the same system built again on its mesh (its
        problem too when it was released): the matrix of the stored key factored, the
        counters continued as they were (the refactorization not counted, as on a resume,
        :meth:`rothe.eld.stepper.ELDStepper.restore_state`). Bit for bit the system before the
        release (assembly and factorization are deterministic). Rare: a stop signal, a failed
        adaptation or a rejected step that goes back to a mesh the run had left."""
        if not self.released:
            return self
        again = getattr(self, "_revival", None)
        if again is not None and not again.released:
            return again  # revived already (abandon after going back to the step's mesh)
        p = self.problem
        problem = p.on_mesh(p.space.mesh) if self.owns_problem else p
        new = type(self)(problem, **self._arguments)
        new.owns_problem = self.owns_problem
        new.restore_reference(self._ref)
        new.solver.rollback(self.solver.snapshot(stored=False))
        self._revival = new
        return new

    @property
    def reference(self) -> dict | None:
        """The key of the stored factorization: {"tau_eff": ..., "v": None or a velocity}."""
        ref = self._ref
        if ref is None:
            return None
        return {"tau_eff": ref["tau_eff"], "v": None if ref["v"] is None else ref["v"].copy()}

    def restore_reference(self, ref: dict | None) -> None:
        """Refactor the matrix of the key ``ref`` (a checkpoint's) unless it is stored already."""
        if ref is None:
            return
        same = (
            self._ref is not None
            and self._ref["tau_eff"] == ref["tau_eff"]
            and (
                (self._ref["v"] is None and ref["v"] is None)
                or (
                    self._ref["v"] is not None
                    and ref["v"] is not None
                    and np.array_equal(self._ref["v"], ref["v"])
                )
            )
        )
        if not same:
            self.factor(
                ref["tau_eff"], None if ref["v"] is None else np.asarray(ref["v"], dtype=float)
            )

    # -- products and the energy of a state -----------------------------------------------------
    def fill_products(self, state: ELDState, names=None) -> None:
        """Compute the cached products (:data:`rothe.eld.state.PRODUCTS`) that ``state`` lacks
        (only ``names`` if given)."""
        p = self.problem
        mats = {"M": p.M, "K": p.K}
        for name, (mat, fname) in PRODUCTS.items():
            if names is not None and name not in names:
                continue
            if fname in state.fields and name not in state.products:
                state.products[name] = mats[mat] @ state.fields[fname]

    def adopt(self, state: ELDState) -> ELDState:
        """Take over a state mapped from another mesh (:meth:`ELDState.mapped`): a new state
        with the cached products of this mesh's M and K, the energy and the G-form pieces of the
        ledger recomputed; the energy change is booked as ``transfer``."""
        state = replace(
            state, products={}, fields=dict(state.fields), boundary=dict(state.boundary)
        )
        self.fill_products(state)
        p = self.problem
        f, pr = state.fields, state.products
        L = state.ledger
        kin, el = 0.5 * self.rho * _dot(f["v"], pr["Mv"]), 0.5 * _dot(f["u"], pr["Ku"])
        new = replace(L, kinetic=kin, elastic=el, transfer=L.transfer + (kin + el) - L.energy)
        if "u_1" in f:
            dv, du = f["v"] - f["v_1"], f["u"] - f["u_1"]
            Mdv, Kdu = pr["Mv"] - p.M @ f["v_1"], pr["Ku"] - p.K @ f["u_1"]
            new.g_zd_kin = self.rho * _dot(pr["Mv"], dv)
            new.g_sq_kin = self.rho * _dot(Mdv, dv)
            new.g_zd_el = _dot(pr["Ku"], du)
            new.g_sq_el = _dot(Kdu, du)
        state.ledger = new
        return state


class RegularizedSystem(ELDSystem):
    """The regularized form: unknowns on the free dofs (ker B), the lifting B^-, an SPD
    matrix; the products with lifted data by the thin columns of M and K on Gamma_D (nodal
    lifting)."""

    def __init__(self, problem, *, lifting: str = "nodal", **kwargs):
        self._arguments = dict(kwargs, lifting=lifting)
        c = problem.constraint
        self.lifting = make_lifting(lifting, c, problem.K)
        self._thin = None
        if isinstance(self.lifting, NodalLifting):
            # B^- g = S^T g: products with lifted data only touch the columns of Gamma_D
            self._thin = (
                problem.space.symmetric_columns(problem.M, c.scalar_dofs),
                problem.space.symmetric_columns(problem.K, c.scalar_dofs),
            )
        super().__init__(problem, **kwargs)

    def _release_form(self) -> None:
        self._thin = None
        if not isinstance(self.lifting, NodalLifting):
            self.lifting = None  # the harmonic lifting holds a factorization of K_II

    def _make_solver(self, near_nullspace, rtol):
        return ReferenceSolver(
            self.kind,
            spd=True,
            near_nullspace=near_nullspace,
            rtol=rtol,
            amg_options=self._amg_options,
            times=self.times,
            symmetric_lu=self.symmetric_lu,
        )

    @property
    def size(self) -> int:
        return self.I.size

    @property
    def A_II(self):
        return self._A_stored

    def _operator_matrix(self, te: float):
        if self._lean:
            return self._restricted(te)
        return self._step_matrix(te)[self.I][:, self.I].tocsr()

    def _of_full(self, A):
        return A[self.I][:, self.I].tocsr()

    def _system_of(self, X, border=None):
        return sp.csr_matrix(X)[self.I][:, self.I]

    def _pattern_border(self):
        return None

    def _system_matrix(self, te, v):
        if v is None and self._lean:
            return self._restricted(te)
        return super()._system_matrix(te, v)

    def _factor(self, te, v):
        if v is None and self._lean and te == self._A_te:
            # the stored step matrix itself: no second copy for the solver; the AMG setup is
            # the peak of a large run, so first free what only assemblies need
            if self.kind == "amg":
                self.problem.space.release_assembly_caches()
            self.solver.factor(self._A_stored)
        else:
            super()._factor(te, v)

    def apply_A(self, w: np.ndarray, te: float) -> np.ndarray:
        """A(te) w on the free dofs."""
        if te == self._A_te:
            return self._A_stored @ w
        full = np.zeros(self.problem.space.ndofs)
        full[self.I] = w
        return self._apply_full(full, te)[self.I]

    def _operator(self, te: float, n: int):
        return spla.LinearOperator((n, n), matvec=lambda w: self.apply_A(w, te), dtype=float)

    def lifted(self, vals):
        """[(B^- g, M B^- g, K B^- g) for g in (G, G_dot, G_ddot)] (thin products for nodal)."""
        gs = (vals.G, vals.G_dot, vals.G_ddot)
        if self._thin is not None:
            M_C, K_C = self._thin
            return [(self.lifting(g), M_C @ g, K_C @ g) for g in gs]
        p = self.problem
        return [(w, p.M @ w, p.K @ w) for w in self.lifting.lift_many(list(gs))]

    def split(self, w: np.ndarray) -> np.ndarray:
        """The kernel part w - B^-(w|Gamma_D) (exactly zero on Gamma_D)."""
        c = self.problem.constraint
        out = w - self.lifting(w[c.dofs])
        out[c.dofs] = 0.0
        return out


class OriginalSystem(ELDSystem):
    """The original form: the bordered system [[A, B^T], [B, 0]] for (u, lambda), solved by
    condensing the constraint (:class:`rothe.eld.solvers.ConstrainedSolver`): the size of
    A_II, and LU or AMG of A_II both apply."""

    def __init__(self, problem, **kwargs):
        self._arguments = dict(kwargs)
        super().__init__(problem, **kwargs)

    def _make_solver(self, near_nullspace, rtol):
        return ConstrainedSolver(
            self.problem.constraint,
            self.kind,
            near_nullspace=near_nullspace,
            rtol=rtol,
            amg_options=self._amg_options,
            times=self.times,
            symmetric_lu=self.symmetric_lu,
        )

    def _store_first_matrix(self, te):
        # the lean original form keeps no matrix: its products with A(te) go through M and K
        if self._lean:
            self._A_te = None
        else:
            super()._store_first_matrix(te)

    @property
    def size(self) -> int:
        return self.problem.space.ndofs + self.problem.constraint.m

    def _operator_matrix(self, te: float):
        return self._step_matrix(te)

    def _kkt(self, A) -> sp.csr_matrix:
        B = self.problem.constraint.B
        return sp.bmat([[A, B.T], [B, None]], format="csr")

    def _of_full(self, A):
        return self._kkt(A)

    def _system_of(self, X, border=None):
        B = self.problem.constraint.B
        border = sp.csr_matrix(B.shape) if border is None else border
        m = border.shape[0]
        return sp.bmat([[X, border.T], [border, sp.csr_matrix((m, m))]], format="csr")

    def _pattern_border(self):
        return self.problem.constraint.B

    def _factor(self, te, v):
        if v is None and self._lean:
            # A_II and the thin blocks of A on the constrained dofs, for the condensed solve
            # (A is symmetric: its rows on the constrained dofs are the transposed columns)
            p = self.problem
            c = p.constraint
            c_mass, c_stiff = self.coefficients(te)
            A_C = (
                c_mass * p.space.symmetric_columns(p.M, c.scalar_dofs)
                + c_stiff * p.space.symmetric_columns(p.K, c.scalar_dofs)
            ).tocsr()
            A_IC = A_C[self.I]
            A_II = self._restricted(te)
            if self.kind == "amg":
                p.space.release_assembly_caches()
            self.solver.factor_parts(A_II, A_IC, A_IC.T, A_C[c.dofs])
            del A_II
        else:
            super()._factor(te, v)

    def apply_A(self, w: np.ndarray, te: float) -> np.ndarray:
        """A(te) w on all dofs."""
        if te == self._A_te:
            return self._A_stored @ w
        return self._apply_full(w, te)

    def _operator(self, te: float, n: int):
        B = self.problem.constraint.B
        nu = self.problem.space.ndofs

        def matvec(z):
            return np.concatenate([self.apply_A(z[:nu], te) + B.T @ z[nu:], B @ z[:nu]])

        return spla.LinearOperator((n, n), matvec=matvec, dtype=float)

    def lifted(self, vals):
        """No lifting: u = x, v = y, a = b."""
        zero = (None, 0.0, 0.0)
        return [zero, zero, zero]

    def split(self, w: np.ndarray) -> np.ndarray:
        """The original form's unknown is u itself."""
        return w
