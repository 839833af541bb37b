"""Euler (3.4) and variable-step BDF2 on many processes: the serial scheme, PETSc linear algebra.

The scheme is the serial one (:mod:`rothe.eld.stepper`, the paper's (3.4) in the regularized
form (2.8) and the original form (2.7)); every step is the stationary problem

    A(tau_eff) x = r,   A(tau_eff) = (rho/tau_eff^2 + a_M/tau_eff) M + (1 + a_K/tau_eff) K,
    tau_eff = tau_j / alpha_0               (module docstrings of rothe.eld.stepper, .system)

for the scheme's unknown x (regularized: u_1 in ker B, x = 0 on Gamma_D; original: u, x = G^j
on Gamma_D, i.e. the bordered system with B = M_G S condensed: M_G is invertible, so B u = G
is S u = g and the multiplier follows from the Gamma_D rows). What is distributed:

- every dof vector of the state (``fields``, ``products``) holds the dofs this process owns
  (the PETSc layout, :class:`rothe.fem.distributed.Partition`); lambda and the data on Gamma_D
  are replicated, in the serial order;
- M, K and A(tau_eff) are PETSc AIJ matrices; A has the rows and columns of the constrained
  dofs replaced by the identity (``MatZeroRowsColumns``), which is A_II on the free dofs;
  products with the lifted data use the thin column blocks M_C, K_C;
- the linear solves are PETSc CG (``solver='amg'``: preconditioned by GAMG with the rigid-body
  modes as near-nullspace; ``'direct'``: by MUMPS's LU, so CG stops after one iteration);
  when tau_eff changes (adaptive steps, BDF2 step ratios) the stored preconditioner is reused
  for the new A and rebuilt when CG needs more than twice the iterations it needed when built
  (the serial solver's policy);
- every inner product (energy ledger, error estimate, lambda's Gamma_D residual) is a sum of
  the processes' partial sums (one ``allreduce`` per step for the whole ledger): the numbers
  are the serial ones up to the order of summation (round-off).

Refused with one line (not distributed here): data 'means'/'differenced', noise, the harmonic
lifting and user damping matrices (see docs/scaling.md). Nonlinear damping: Newton's method
as serial, the corrections by CG with the stored preconditioner of A(tau_eff) on the matrix-free
J = A + N'(v)/tau_eff (N, N' by the serial quadrature on the overlap submesh after a ghost
update).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict

import numpy as np

from ...errors import RotheInputError, RunFailed, check_choice, check_positive, described, fail
from ...fem.petsc_env import release_product_data
from ...io.trajectory import Trajectory
from ...stepping import interrupt
from ...stepping.controllers import Adaptive
from ...stepping.evolve import single_threaded_blas
from ...timing import PhaseTimes
from ..data import DEFAULT_DATA, Points, StepValues, as_data_mode
from ..form import DEFAULT_FORM, Regularized, as_form
from ..scheme import DEFAULT_SCHEME, as_scheme
from ..solvers import AMG_PRODUCTS, SolveFailed, SolverStats, resolve_kind
from ..state import PRODUCTS, ELDState, ELDStepResult, EnergyLedger
from ..stepper import (
    DEFAULT_CONTROL,
    NewtonOptions,
    StepperBase,
    as_control,
    history_terms,
    kinematics,
    newton,
)
from .problem import DistributedDamping

#: the checkpoint format of :meth:`PetscELDStepper.checkpoint_state` (the serial stepper's
#: state gathered in the serial numbering, plus the number of processes)
CHECKPOINT_FORMAT = "rothe-eld-petsc-1"

#: CG iterations relative to those right after the preconditioner was built, beyond which it
#: is rebuilt for the current A(tau_eff) (the serial ReferenceSolver's stall rule)
REBUILD_FACTOR = 2.0


class PetscELDStepper(StepperBase):
    """One step of Euler or BDF2 in either form on a :class:`DistributedELDProblem` (module
    docstring); the evolve loop drives it on every process. Parameters as
    :class:`rothe.eld.stepper.ELDStepper` (no ``adapt``), and ``amg_products`` (``'fast'``,
    default, or ``'lean'``: how GAMG forms its coarse operators,
    :data:`rothe.eld.solvers.AMG_PRODUCTS`). The time grid is the serial one
    (:class:`rothe.eld.stepper.StepGrid`), and so are the history terms and the kinematics of
    a step (:func:`rothe.eld.stepper.history_terms`, :func:`rothe.eld.stepper.kinematics`),
    applied to the owned dofs.

    Signals: unlike the serial stepper, a step here never calls
    :func:`rothe.stepping.interrupt.check` (nor runs a factorization through
    :func:`~rothe.stepping.interrupt.call`), so it is never abandoned half way. A signal may
    reach one process and not the others; a process that abandoned its step while the others
    wait in the step's collective reductions (the norms of Newton's method, the ledger's
    allreduce, PETSc's solves) would hang the job. All processes stop after the same step
    instead: :meth:`finished` makes a signal that reached any of them everybody's."""

    def __init__(
        self,
        problem,
        *,
        scheme=DEFAULT_SCHEME,
        form=DEFAULT_FORM,
        control=DEFAULT_CONTROL,
        data=DEFAULT_DATA,
        solver: str = "auto",
        newton: NewtonOptions | None = None,
        noise=None,
        store_fields: bool = True,
        keep_every: int = 1,
        observer=None,
        linear_rtol: float = 1e-10,
        error_scale: float | None = None,
        amg_products: str = "fast",
    ):
        self.problem = p = problem
        self.amg_products = check_choice("amg_products", amg_products, AMG_PRODUCTS)
        self.comm = p.comm
        self.PETSc = PETSc = p.PETSc
        self.scheme = as_scheme(scheme)
        self.form = as_form(form)
        self.control = as_control(control)
        self.data_mode = as_data_mode(data)
        if not isinstance(self.data_mode, Points):
            raise fail(
                "data",
                described(f"{type(self.data_mode).__name__}()"),
                "must be Points() with backend 'petsc' (means and differenced data are not "
                "distributed yet)",
            )
        if noise is not None:
            raise fail("noise", described("a DataNoise"), "is not supported by backend 'petsc'")
        if self.form.lifting not in (None, "nodal"):
            raise fail(
                "form",
                described(f"Regularized(lifting={self.form.lifting!r})"),
                "must have the nodal lifting with backend 'petsc' (the harmonic lifting is not "
                "distributed yet)",
            )
        self.D = D = DistributedDamping(p)
        if D.matrix is not None:
            raise fail(
                "damping",
                p.damping.name,
                "must be Rayleigh, nonlinear or none with "
                "backend 'petsc' (a user's damping matrix is not distributed)",
            )
        self._set_common(p, newton, store_fields, keep_every, observer, error_scale)
        self.linear_rtol = check_positive("linear_rtol", linear_rtol)
        self.rho = p.material.rho
        part = p.partition
        self.C = p.C
        self.bpos = p.bpos
        self.n = p.n_own
        self.kind = resolve_kind(solver, p.ndofs - p.constraint.m, p.dim)
        self.stats = SolverStats()
        self.times = PhaseTimes()  # factor (preconditioner set-up) and solve, as serial
        self.krylov_seconds = 0.0  # wall time inside PETSc's CG (benchmarks: per-phase times)
        # PETSc objects: vectors on the owned dofs sharing numpy buffers, thin Gamma_D blocks
        self._in = np.zeros(self.n)
        self._vin = PETSc.Vec().createWithArray(self._in, comm=self.comm)
        self._vout = self._vin.duplicate()
        self._b = np.zeros(self.n)
        self._vb = PETSc.Vec().createWithArray(self._b, comm=self.comm)
        self._x = np.zeros(self.n)
        self._vx = PETSc.Vec().createWithArray(self._x, comm=self.comm)
        self.Cglob = (part.rstart + self.C).astype(PETSc.IntType)
        rows = PETSc.IS().createStride(self.n, part.rstart, 1, comm=self.comm)
        cols = PETSc.IS().createGeneral(self.Cglob, comm=self.comm)
        self._M_C = p.M.createSubMatrix(rows, cols)
        self._K_C = p.K.createSubMatrix(rows, cols)
        self._g = np.zeros(self.C.size)
        self._vg = PETSc.Vec().createWithArray(self._g, comm=self.comm)
        self._A = p.K.duplicate(copy=True)
        self._A_te = None
        self._set_operator(self.tau / self.scheme.alpha0)
        self._ksp = self._make_ksp()
        self._pc_te = None
        self._pc_its = None
        self._rebuild = True
        self._setup_pc()
        self.initial_factorizations = self.stats.factorizations

    # -- linear algebra -------------------------------------------------------------------------
    def _coefficients(self, te: float) -> tuple[float, float]:
        D = self.D
        return self.rho / te**2 + D.mass_coef / te, 1.0 + D.stiffness_coef / te

    def _set_operator(self, te: float) -> None:
        """A <- A(te) with the identity on the constrained rows and columns."""
        if te == self._A_te:
            return
        # K's pattern holds M's (the vector mass couples equal components only)
        Struct = self.PETSc.Mat.Structure
        cm, ck = self._coefficients(te)
        p = self.problem
        p.K.copy(self._A, structure=Struct.SAME_NONZERO_PATTERN)
        self._A.scale(ck)
        self._A.axpy(cm, p.M, structure=Struct.SUBSET_NONZERO_PATTERN)
        self._A.zeroRowsColumns(self.Cglob, diag=1.0)
        self._A_te = te

    def _rigid_body_modes(self):
        """Translations and rotations at the owned dofs, orthonormalized (global inner
        products), as PETSc vectors: GAMG's near-nullspace."""
        p = self.problem
        part = p.partition
        d = p.dim
        x = p.local.space.doflocs[:, part.own_scalar].T  # (n_own/d, d)
        modes = []
        for c in range(d):
            w = np.zeros((x.shape[0], d))
            w[:, c] = 1.0
            modes.append(w.ravel())
        if d == 2:
            w = np.zeros((x.shape[0], 2))
            w[:, 0], w[:, 1] = -x[:, 1], x[:, 0]
            modes.append(w.ravel())
        else:
            for i, j in ((0, 1), (1, 2), (2, 0)):
                w = np.zeros((x.shape[0], 3))
                w[:, i], w[:, j] = -x[:, j], x[:, i]
                modes.append(w.ravel())
        basis = []
        for w in modes:
            for q in basis:
                w = w - self._dot(q, w) * q
            basis.append(w / math.sqrt(self._dot(w, w)))
        vecs = [self.PETSc.Vec().createWithArray(w.copy(), bsize=d, comm=self.comm) for w in basis]
        return self.PETSc.NullSpace().create(vectors=vecs, comm=self.comm)

    def _make_ksp(self):
        PETSc = self.PETSc
        ksp = PETSc.KSP().create(self.comm)
        ksp.setOptionsPrefix("rothe_eld_")
        ksp.setType("cg")
        ksp.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)
        ksp.setTolerances(rtol=self.linear_rtol, atol=0.0, max_it=2000)
        ksp.setInitialGuessNonzero(True)
        pc = ksp.getPC()
        opts = PETSc.Options("rothe_eld_")
        if self.kind == "amg":
            self._A.setNearNullSpace(self._rigid_body_modes())
            pc.setType("gamg")
            # as the FEniCSx peer (anchors/eld_beam_dolfinx011.py): Chebyshev/Jacobi smoothing
            opts["mg_levels_ksp_type"] = "chebyshev"
            opts["mg_levels_pc_type"] = "jacobi"
            opts["pc_gamg_coarse_eq_limit"] = 1000
        else:
            pc.setType("lu")
            pc.setFactorSolverType("mumps")
        ksp.setOperators(self._A)
        ksp.setFromOptions()
        return ksp

    def _setup_pc(self) -> None:
        with self.times.phase("factor"):
            self._setup_pc_timed()

    def _setup_pc_timed(self) -> None:
        t0 = time.perf_counter()
        self._ksp.getPC().setReusePreconditioner(False)
        self._ksp.setOperators(self._A)
        if self.kind == "amg" and self.amg_products == "lean":
            self._setup_lean()
        else:
            self._ksp.setUp()
        if self.kind == "amg":
            release_product_data(self._ksp.getPC())
        self._ksp.getPC().setReusePreconditioner(True)
        self.stats.factorizations += 1
        self.stats.setup_seconds += time.perf_counter() - t0
        self._pc_te = self._A_te
        self._pc_its = None
        self._rebuild = False

    def _setup_lean(self) -> None:
        """GAMG's set-up with PETSc's all-at-once Galerkin products (``-matptap_via
        allatonce``), which never form A P: the least memory per process (docs/scaling.md).
        A ``-matptap_via`` the user gave (e.g. in PETSC_OPTIONS) is theirs and stays. The
        all-at-once product on the finest level only halves the set-up but leaves the peak
        15-40 MB higher, above the issue's 0.6 of the serial peak (docs/scaling.md, eighth
        session): not taken, ``lean`` is the choice for the least memory."""
        options = self.PETSc.Options()
        if options.hasName("matptap_via") or self.comm.size == 1:
            # on one process the products are sequential (SeqAIJ, which stores no A P and knows
            # no all-at-once algorithm: PETSc refused the option, 'Unknown option')
            self._ksp.setUp()
            return
        options["matptap_via"] = "allatonce"
        try:
            self._ksp.setUp()
        finally:
            options.delValue("matptap_via")

    def _solve(self, rhs: np.ndarray, te: float, guess: np.ndarray) -> np.ndarray:
        """A(te) x = rhs by CG with the stored preconditioner (module docstring)."""
        self._set_operator(te)
        if self._rebuild:
            self._setup_pc()
        its, reason = self._krylov(rhs, guess)
        if reason < 0 and self._pc_te != te:
            # a preconditioner built for another tau_eff can fail outright (GAMG's Chebyshev
            # bounds belong to the old matrix: reason -8, indefinite): rebuild it and retry
            self._setup_pc()
            its, reason = self._krylov(rhs, guess)
        if reason < 0:
            raise SolveFailed(f"PETSc CG did not converge (reason {reason}, {its} iterations)")
        if self._pc_its is None and te == self._pc_te:
            self._pc_its = max(its, 1)
        elif self._pc_its is not None and its > REBUILD_FACTOR * self._pc_its + 2:
            self._rebuild = True  # the next solve rebuilds for its own A(te)
        return self._x.copy()

    def _krylov(self, rhs: np.ndarray, guess: np.ndarray) -> tuple[int, int]:
        """One CG solve with the current operators into ``self._x``: (iterations, reason)."""
        # setArray (not a write into the shared buffer) so that PETSc's cached norms go stale
        self._vb.setArray(rhs)
        self._vx.setArray(guess)
        t0 = time.perf_counter()
        with self.times.phase("solve"):
            self._ksp.solve(self._vb, self._vx)
        self.krylov_seconds += time.perf_counter() - t0
        its = self._ksp.getIterationNumber()
        self.stats.solves += 1
        self.stats.backsolves += 1
        self.stats.krylov_iterations += its
        return its, self._ksp.getConvergedReason()

    def _mult(self, A, w: np.ndarray) -> np.ndarray:
        self._vin.setArray(w)
        A.mult(self._vin, self._vout)
        return self._vout.getArray().copy()

    def _thin(self, A, g_serial: np.ndarray) -> np.ndarray:
        """A S^T g for g on the whole Gamma_D (serial order): the thin column block."""
        self._vg.setArray(g_serial[self.bpos])
        A.mult(self._vg, self._vout)
        return self._vout.getArray().copy()

    def _embed(self, g_serial: np.ndarray) -> np.ndarray:
        w = np.zeros(self.n)
        w[self.C] = g_serial[self.bpos]
        return w

    def _dot(self, a, b) -> float:
        return self.comm.allreduce(float(a @ b))

    def _dots(self, pairs) -> list[float]:
        """Several global inner products with one allreduce."""
        local = np.array([float(a @ b) for a, b in pairs])
        out = np.empty_like(local)
        self.comm.Allreduce(local, out)
        return list(out)

    def _any(self, flag: bool) -> bool:
        return bool(self.comm.allreduce(int(bool(flag))))

    # -- initial state --------------------------------------------------------------------------
    def consistent_acceleration(self, t, u, v, G_ddot):
        """(a, lambda) from (2.7a) at t: a = G_ddot on Gamma_D, rho M_II a_I = (F - D v - K u -
        rho M S^T G_ddot)_I by CG + Jacobi on M with identity constrained rows (rtol 1e-13),
        lambda from the Gamma_D rows."""
        p, D, PETSc = self.problem, self.D, self.PETSc
        Mv = self._mult(p.M, v)
        Ku = self._mult(p.K, u)
        Kv = self._mult(p.K, v) if D.stiffness_coef else 0.0
        rhs = p.load(t) - (D.mass_coef * Mv + D.stiffness_coef * Kv) - Ku
        if not D.is_linear:
            rhs = rhs - D.nonlinear_apply(v)
        a = self._embed(G_ddot)
        r = (rhs - self.rho * self._mult(p.M, a)) / self.rho
        r[self.C] = 0.0
        # M_II with identity rows on Gamma_D as an operator on M, not a copy of it (a copy with
        # zeroRowsColumns cost a transient as large as M: 160 MB per process at 1.07 M dofs, N = 2)
        C = self.C

        class _MII:
            def mult(self, mat, x, y):
                xa = x.getArray(readonly=True).copy()
                xc = xa[C]
                xa[C] = 0.0
                x_free.setArray(xa)
                p.M.mult(x_free, y)
                ya = y.getArray()
                ya[C] = xc

            def getDiagonal(self, mat, d):
                p.M.getDiagonal(d)
                d.getArray()[C] = 1.0

        x_free = self._vout.duplicate()
        Md = PETSc.Mat().createPython(p.M.getSizes(), context=_MII(), comm=self.comm)
        Md.setUp()
        ksp = PETSc.KSP().create(self.comm)
        ksp.setOperators(Md)
        ksp.setType("cg")
        ksp.getPC().setType("jacobi")
        ksp.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)
        ksp.setTolerances(rtol=1e-13, atol=0.0, max_it=1000)
        self._vb.setArray(r)
        self._vx.set(0.0)
        ksp.solve(self._vb, self._vx)
        aI = self._x.copy()
        ksp.destroy()
        Md.destroy()
        x_free.destroy()
        aI[self.C] = 0.0
        a = a + aI
        res = rhs - self.rho * self._mult(p.M, a)
        lam = p.constraint.multiplier_from_residual(p.gather_boundary(res)[0])
        return a, lam

    def initial_state(self) -> ELDState:
        """The initial state (single-threaded BLAS, floating-point warnings off)."""
        with single_threaded_blas(), np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return self._initial_state()

    def _initial_state(self) -> ELDState:
        p = self.problem
        G0, Gd0, Gdd0 = p.boundary_values(0.0)
        vc = p.v0.copy()
        vc[self.C] = Gd0[self.bpos]
        F0 = p.load(0.0)
        if self._any(not np.all(np.isfinite(F0))) or not (
            np.all(np.isfinite(Gd0)) and np.all(np.isfinite(Gdd0))
        ):
            raise fail("initial data", "non-finite values", "must be finite")
        a0, lam0 = self.consistent_acceleration(0.0, p.u0, vc, Gdd0)
        if self._any(not np.all(np.isfinite(a0))) or not np.all(np.isfinite(lam0)):
            raise RunFailed(
                "non-finite initial state: the consistent acceleration or multiplier "
                "at t = 0 has NaN or inf entries (overflow?)",
                where={
                    "step": 0,
                    "s": 0.0,
                    "t": 0.0,
                    "form": self.form.name,
                    "scheme": self.scheme.name,
                },
            )
        C = self.C
        if isinstance(self.form, Regularized):
            u2, v2, w2 = self._embed(G0), self._embed(Gd0), self._embed(Gdd0)
            x = p.u0 - u2
            x[C] = 0.0
            y = vc - v2
            y[C] = 0.0
            b = a0 - w2
            b[C] = 0.0
            u, v = x + u2, y + v2
        else:
            x, y, b = p.u0.copy(), p.v0.copy(), a0.copy()
            u, v = x, p.v0.copy()
        fields = {"x": x, "y": y, "b": b, "u": u, "v": v, "a": a0}
        state = ELDState(
            t=0.0,
            j=0,
            tau_prev=None,
            fields=fields,
            boundary={"lam": lam0},
            products={},
            ledger=EnergyLedger(),
        )
        self._fill_products(state)
        vMv, uKu = self._dots([(v, state.products["Mv"]), (u, state.products["Ku"])])
        kin, el = 0.5 * self.rho * vMv, 0.5 * uKu
        state.ledger = EnergyLedger(kinetic=kin, elastic=el, initial=kin + el)
        norm0 = math.sqrt(max(2.0 * (kin + el), 0.0))
        if self.error_scale is None and isinstance(self.control, Adaptive):
            self.error_scale = max(norm0, self._data_scale()) or 1.0
        state.energy_norm_max = max(norm0, self.error_scale or 0.0)
        return state

    def _data_scale(self) -> float:
        """max over 65 times in [0, T] of (rho|S^T G_dot|_M^2 + |S^T G|_K^2)^{1/2}."""
        p = self.problem
        best = 0.0
        for t in np.linspace(0.0, self.T, 65):
            g, gd = p.boundary_values(t, ("G", "G_dot"))
            if not (np.all(np.isfinite(g)) and np.all(np.isfinite(gd))):
                continue
            u2, v2 = self._embed(g), self._embed(gd)
            a, b = self._dots([(v2, self._thin(self._M_C, gd)), (u2, self._thin(self._K_C, g))])
            best = max(best, self.rho * a + b)
        return math.sqrt(best)

    def _fill_products(self, state: ELDState) -> None:
        mats = {"M": self.problem.M, "K": self.problem.K}
        for name, (mat, fname) in PRODUCTS.items():
            if fname in state.fields and name not in state.products:
                state.products[name] = self._mult(mats[mat], state.fields[fname])

    def record_initial(self, traj: Trajectory, state: ELDState) -> None:
        """Record the initial state (energies; its fields gathered to rank 0 if kept)."""
        traj.append(t=0.0, **state.ledger.record())
        if self.store_fields:
            self._keep(traj, state)
        if self.observer is not None:  # as the serial stepper: lambda(0) is known here
            self.observer(state, None)

    def _keep(self, traj: Trajectory, state: ELDState) -> None:
        part = self.problem.partition
        u, v, a = (part.gather_serial(state.fields[k]) for k in ("u", "v", "a"))
        if self.comm.rank == 0:
            traj.append(kept_step=state.j, kept_t=state.t, u=u, v=v, a=a, lam=state.lam.copy())

    # -- evolve-loop interface ------------------------------------------------------------------
    def finished(self, state: ELDState) -> bool:
        """The serial test, after making the signals that reached any process everybody's (the
        loop checks :func:`rothe.stepping.interrupt.requested` right after this call, and
        :func:`~rothe.stepping.interrupt.checkpoint_requested` at the end of the attempt):
        :func:`rothe.stepping.interrupt.agree`, one allreduce."""
        interrupt.agree(self._maximum)
        return self.grid.finished(state)

    def _maximum(self, values: list[int]) -> list[int]:
        """The elementwise maximum over the processes (one Allreduce of an int64 array;
        mpi4py's allreduce of a list would take Python's max of whole lists)."""
        mine = np.asarray(values, dtype=np.int64)
        out = np.empty_like(mine)
        self.comm.Allreduce(mine, out, op=self.problem.MPI.MAX)
        return out.tolist()

    def where(self, state: ELDState, result=None) -> dict:
        """Where the run is: step, t, tau, form, scheme (as serial) and the processes."""
        return {**super().where(state, result), "processes": int(self.comm.size)}

    def progress_fields(self, state: ELDState) -> dict:
        """The time and the last Newton count, for the progress line."""
        return {"t": f"{state.t:.4g}", "newton": self._last_newton}

    def adapt(self, state, result):
        """The mesh stays (no space adaptivity on this backend): the state unchanged."""
        return state

    def step(self, state: ELDState, tau: float, s_end=None) -> ELDStepResult:
        """One step of size tau from ``state`` (:meth:`StepperBase._try_step`, floating-point
        warnings off)."""
        return self._attempt(state, tau)

    # -- the backend of StepperBase: PETSc's linear algebra on the owned dofs ----------------------
    def _values(self, j: int, state: ELDState, t_new: float, coeffs) -> StepValues:
        p = self.problem
        return StepValues(p.load(t_new), *p.boundary_values(t_new))

    def _nonfinite(self, vals: StepValues) -> str | None:
        # F holds the owned dofs (any process's NaN counts); G, G_dot, G_ddot are replicated
        if self._any(not np.all(np.isfinite(vals.F))):
            return "F"
        for name in ("G", "G_dot", "G_ddot"):
            if not np.all(np.isfinite(getattr(vals, name))):
                return name
        return None

    def _linear_stats(self) -> SolverStats:
        return self.stats

    def _result_system(self):
        return None

    def _multiplier(self, k: dict, vals: StepValues):
        # (3.4a) tested with V^c on the constrained rows, gathered in the constraint's order
        r_own = vals.F - self.rho * k["Ma"] - k["Dv"] - k["Ku"]
        r_C, v_C = self.problem.gather_boundary(r_own, k["v"])
        return self.problem.constraint.multiplier_from_residual(r_C), v_C

    # -- BDF2 start (rothe.eld.start.with_prehistory on the owned dofs) -------------------------
    def _start_data(self, tau: float, cubic: bool):
        p, bpos = self.problem, self.bpos
        gd0 = p.boundary_values(0.0, ("G_dot",))[0][bpos]
        g3 = None
        if cubic:
            g_tau = p.boundary_values(tau, ("G_ddot",))[0]
            g_0 = p.boundary_values(0.0, ("G_ddot",))[0]
            g3 = ((g_tau - g_0) / tau)[bpos]
        return gd0, g3

    def _split(self, w: np.ndarray) -> np.ndarray:
        """The scheme's unknown of a field w: regularized, w - S^T(w|Gamma_D), the kernel part
        (nodal lifting); original, w itself."""
        if not isinstance(self.form, Regularized):
            return w
        out = w.copy()
        out[self.C] = 0.0
        return out

    # -- one step ---------------------------------------------------------------------------------
    def _solve_step(self, state, vals: StepValues, coeffs, tau) -> tuple[dict, int]:
        """The step's solve, the kinematics and the Newton iterations
        (ELDStepper._step_regularized/_step_original)."""
        p, rho, D, C = self.problem, self.rho, self.D, self.C
        F, G, Gd, Gdd = vals.F, vals.G, vals.G_dot, vals.G_ddot
        a0 = coeffs[0]
        te = tau / a0
        h = history_terms(state, coeffs)
        guess = self._guess(state, tau)
        if isinstance(self.form, Regularized):
            lifted = [
                (self._embed(G), None, self._thin(self._K_C, G)),
                (self._embed(Gd), self._thin(self._M_C, Gd), self._thin(self._K_C, Gd)),
                (self._embed(Gdd), self._thin(self._M_C, Gdd), None),
            ]
            (_, _, Ku2), (_, Mv2, Kv2), (_, Mw2, _) = lifted
            rhs = (
                F
                - rho * (a0 * h["Mx"] / tau**2 + h["My"] / tau + Mw2)
                - D.mass_coef * (h["Mx"] / tau + Mv2)
                - D.stiffness_coef * (h["Kx"] / tau + Kv2)
                - Ku2
            )
            guess[C] = 0.0
            if not D.is_linear:
                return self._newton(state, F, h, coeffs, tau, lifted, guess)
            rhs[C] = 0.0
            x = self._solve(rhs, te, guess)
            x[C] = 0.0
        else:
            zero = (None, 0.0, 0.0)
            lifted = [zero, zero, zero]
            if not D.is_linear:
                guess[C] = G[self.bpos]
                return self._newton(state, F, h, coeffs, tau, lifted, guess)
            rhs = (
                F
                - rho * (a0 * h["Mx"] / tau**2 + h["My"] / tau)
                - D.mass_coef * h["Mx"] / tau
                - D.stiffness_coef * h["Kx"] / tau
            )
            # condensed constraint: x_C = g, A_II x_I = rhs_I - A_IC g
            cm, ck = self._coefficients(te)
            rhs = rhs - (cm * self._thin(self._M_C, G) + ck * self._thin(self._K_C, G))
            gC = G[self.bpos]
            rhs[C] = gC
            guess[C] = gC
            x = self._solve(rhs, te, guess)
            x[C] = gC
        Mx, Kx = self._mult(p.M, x), self._mult(p.K, x)
        return kinematics(h, coeffs, tau, x, Mx, Kx, lifted, self.D), 0

    def _norm(self, w: np.ndarray) -> float:
        return math.sqrt(max(self._dot(w, w), 0.0))

    def _newton(self, state, F, h, coeffs, tau, lifted, z0):
        """Newton's method with backtracking for nonlinear damping (the serial stepper's, every norm
        global); the unknown is x with its Gamma_D values fixed (0 regularized, G original: the
        bordered system condensed), the residual R = rho M a + D(v) + K u - F on the free
        dofs. Corrections: J dz = -R, J = A(tau_eff) + N'(v)/tau_eff, by CG preconditioned with
        the stored preconditioner of A(tau_eff) (matrix-free J, as serial)."""
        p, rho, C = self.problem, self.rho, self.C
        te = tau / coeffs[0]
        opts = self.newton

        def residual(x):
            k = kinematics(
                h, coeffs, tau, x, self._mult(p.M, x), self._mult(p.K, x), lifted, self.D
            )
            R = rho * k["Ma"] + k["Dv"] + k["Ku"] - F
            R[C] = 0.0
            return R, k

        def correction(R, k):
            dz = self._solve_jacobian(k["v"], -R, te, opts.krylov_rtol)
            dz[C] = 0.0
            return dz

        _, k, its = newton(residual, correction, z0, state.fields["x"], opts, norm=self._norm)
        return k, its

    def _solve_jacobian(self, v, rhs, te, rtol) -> np.ndarray:
        """(A(te) + N'(v)/te) dz = rhs on the free dofs (identity on Gamma_D), matrix-free."""
        PETSc, C = self.PETSc, self.C
        self._set_operator(te)
        if self._rebuild:
            self._setup_pc()
        action = self.D.nonlinear_jacobian_action(v)
        A = self._A

        class _J:
            def mult(self, mat, x, y):
                A.mult(x, y)
                extra = action(x.getArray(readonly=True).copy()) / te
                extra[C] = 0.0
                y.setArray(y.getArray(readonly=True) + extra)

        n, N = self.n, self.problem.ndofs
        J = PETSc.Mat().createPython(((n, N), (n, N)), context=_J(), comm=self.comm)
        J.setUp()
        ksp = self._ksp
        zero = np.zeros(self.n)
        try:
            for attempt in range(2):
                ksp.setOperators(J, A)
                ksp.setTolerances(rtol=rtol)
                its, reason = self._krylov(rhs, zero)
                ksp.setTolerances(rtol=self.linear_rtol)
                ksp.setOperators(A, A)
                if reason >= 0 or self._pc_te == te or attempt:
                    break
                self._setup_pc()  # built for another tau_eff: rebuild for A(te) and retry
        finally:
            ksp.setTolerances(rtol=self.linear_rtol)
            ksp.setOperators(A, A)
            J.destroy()
        if reason < 0:
            raise SolveFailed(
                f"PETSc CG on the Newton system did not converge (reason "
                f"{reason}, {its} iterations)"
            )
        if self._pc_its is not None and its > REBUILD_FACTOR * self._pc_its + 2:
            self._rebuild = True
        return self._x.copy()

    # -- recording --------------------------------------------------------------------------------
    def record(self, traj: Trajectory, result: ELDStepResult, state=None) -> None:
        """As the serial stepper: scalars on every process, the kept fields gathered to rank 0
        (serial numbering); the observer is called on every process (it is collective)."""
        st = result.state
        traj.append(**self._step_record(result, self.problem.constraint))
        if self.store_fields and (st.j % self.keep_every == 0 or self.grid.finished(st)):
            self._keep(traj, st)
        if self.observer is not None:
            self.observer(st, result)

    # -- checkpoints ------------------------------------------------------------------------------
    def checkpoint_state(self, state: ELDState) -> dict | None:
        """The serial stepper's checkpoint dict, with every dof vector gathered to rank 0 in the
        serial numbering (None on the other processes). Collective."""
        part = self.problem.partition
        fields = {k: part.gather_serial(w) for k, w in sorted(state.fields.items())}
        products = {k: part.gather_serial(w) for k, w in sorted(state.products.items())}
        if self.comm.rank != 0:
            return None
        return {
            "format": CHECKPOINT_FORMAT,
            "scheme": self.scheme.name,
            "form": self.form.name,
            "backend": "petsc",
            "processes": int(self.comm.size),
            "t": float(state.t),
            "j": int(state.j),
            "tau_prev": state.tau_prev,
            "fields": fields,
            "products": products,
            "boundary": {k: w.copy() for k, w in state.boundary.items()},
            "ledger": {k: float(v) for k, v in asdict(state.ledger).items()},
            "energy_norm_max": float(state.energy_norm_max),
            "mesh_id": 0,
            "error_scale": None if self.error_scale is None else float(self.error_scale),
            "solver_reference": {"tau_eff": self._pc_te, "v": None},
            "solver_stats": asdict(self.stats),
            "pc_its": self._pc_its,
            "pc_rebuild": bool(self._rebuild),
            "last_newton": int(self._last_newton),
        }

    def restore_state(self, data: dict | None) -> ELDState:
        """The state of :meth:`checkpoint_state` (``data`` on rank 0, None elsewhere): scattered
        to the owners; the preconditioner is rebuilt for the stored tau_eff. Collective."""
        comm = self.comm
        head = None
        if comm.rank == 0:
            if data.get("format") != CHECKPOINT_FORMAT or data.get("backend") != "petsc":
                head = RotheInputError("checkpoint: not written by backend 'petsc'")
            elif int(data.get("processes", -1)) != comm.size:
                head = RotheInputError(
                    f"checkpoint: written by {data.get('processes')} processes, this run has "
                    f"{comm.size}: resume with mpiexec -n {data.get('processes')}"
                )
            else:
                head = {
                    k: data[k]
                    for k in (
                        "t",
                        "j",
                        "tau_prev",
                        "boundary",
                        "ledger",
                        "energy_norm_max",
                        "error_scale",
                        "solver_reference",
                        "solver_stats",
                        "pc_its",
                        "pc_rebuild",
                    )
                }
                head["names"] = (sorted(data["fields"]), sorted(data["products"]))
        head = comm.bcast(head, root=0)
        if isinstance(head, Exception):
            raise head
        part = self.problem.partition
        fields = {
            k: part.scatter_serial(data["fields"][k] if comm.rank == 0 else None)
            for k in head["names"][0]
        }
        products = {
            k: part.scatter_serial(data["products"][k] if comm.rank == 0 else None)
            for k in head["names"][1]
        }
        te = head["solver_reference"]["tau_eff"]
        if te is not None:
            self._set_operator(float(te))
            self._setup_pc()
        self._pc_its = head["pc_its"]
        self._rebuild = bool(head["pc_rebuild"])  # as the uninterrupted run would go on
        self.stats = SolverStats(**head["solver_stats"])
        if head["error_scale"] is not None:
            self.error_scale = float(head["error_scale"])
        tp = head["tau_prev"]
        return ELDState(
            t=float(head["t"]),
            j=int(head["j"]),
            tau_prev=None if tp is None else float(tp),
            fields=fields,
            boundary={k: np.asarray(w, dtype=float).copy() for k, w in head["boundary"].items()},
            products=products,
            ledger=EnergyLedger(**head["ledger"]),
            energy_norm_max=float(head["energy_norm_max"]),
        )

    def close(self) -> None:
        """Free the PETSc objects (collective)."""
        for obj in (self._ksp, self._A, self._M_C, self._K_C):
            obj.destroy()
