"""The discrete trace B on the Dirichlet boundary, its right inverses, and the multiplier space.

Trace and multiplier (Sec. 2.2.3). Let S select the vector dofs on the closure of the Dirichlet
parts Gamma_D (m of them, interleaved like the space) and M_G the vector boundary mass on
Gamma_D, (M_G)_{kl} = int_{Gamma_D} phi_k . phi_l ds. The multiplier space Q_h is the trace
space of V_h on Gamma_D (same dofs) and

    <B u, q> = int_{Gamma_D} u . q ds,   i.e.  B = M_G S  (an m x n matrix).

So lambda_h in Q_h is a *traction density* (units of stress); with the paper's sign convention
rho u'' + D u' + K u + B* lambda = F, the exact multiplier is lambda = -sigma(u + ...) n, and the
reaction force the support exerts on the body through a part P is  -int_P lambda ds.
The constraint B u = G in Q_h* is imposed with G given by its nodal values g on the constrained
dofs (the functional M_G g), which is equivalent to S u = g.

Right inverses B^- (the complement V^c = range of B^-):

- :class:`NodalLifting` (default): B^- (M_G g) = S^T g, the finite element function with nodal
  values g on Gamma_D and zero at every other node. V^c is spanned by the basis functions of
  the constrained dofs; costs nothing. Its norm C_{B^-} grows like h^{-1/2} under refinement,
  which does not matter for the tau-behaviour on a fixed mesh.
- :class:`HarmonicLifting`: the discrete elastic extension, u_C = g and K_II u_I = -K_IC g
  (I = free dofs). V^c is the K-orthogonal complement of V_B = ker B, the paper's canonical
  choice, with C_{B^-} bounded uniformly in h; costs one back-substitution with K_II per
  lifted vector.

Whatever the complement, testing the equation with V^c determines lambda uniquely: once the
V_B-rows hold, the residual r = F - (rho M a + D v + K u) vanishes on the free dofs and
M_G lambda = r_C (see :meth:`DirichletConstraint.multiplier_from_residual`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import RotheInputError, fail

LIFTINGS = ("nodal", "harmonic")


class DirichletConstraint:
    """B = M_G S on the named Dirichlet parts of a :class:`~rothe.fem.elasticity.VectorSpace`.

    Parameters
    ----------
    space : VectorSpace
    parts : sequence of str
        The boundary parts where u = G.
    name : str
        The parameter an unknown part's error names.
    """

    def __init__(self, space, parts, name: str = "dirichlet"):
        parts = tuple(parts)
        if not parts:
            raise fail(
                name,
                "no part",
                "needs at least one boundary part (pure Neumann "
                "problems are not covered by Sec. 2.2)",
            )
        self.space = space
        self.parts = parts
        d = space.dim
        self.scalar_dofs = space.scalar_dofs_on(parts, name)
        self.dofs = space.vector_dofs(self.scalar_dofs)
        self.m = self.dofs.size
        mask = np.ones(space.ndofs, dtype=bool)
        mask[self.dofs] = False
        self.free = np.flatnonzero(mask)
        # positions of each part's scalar dofs inside the union (for data and reactions)
        self.part_positions = {}
        Ms_union = space.boundary_scalar_mass(parts, name)[self.scalar_dofs][:, self.scalar_dofs]
        self.boundary_mass = sp.kron(Ms_union, sp.identity(d), format="csc")
        self._bm_lu = spla.splu(self.boundary_mass, permc_spec="MMD_AT_PLUS_A")
        self._reaction_weights = {}
        for part in parts:
            sdofs = space.scalar_dofs_on((part,), name)
            self.part_positions[part] = np.searchsorted(self.scalar_dofs, sdofs)
            Ms_part = space.boundary_scalar_mass((part,), name)
            Ms_part = Ms_part[self.scalar_dofs][:, self.scalar_dofs]
            # int_P lambda_c ds = 1^T M_P lambda_c
            self._reaction_weights[part] = np.asarray(Ms_part.sum(axis=0)).ravel()
        S = sp.csr_matrix(
            (np.ones(self.m), (np.arange(self.m), self.dofs)), shape=(self.m, space.ndofs)
        )
        self.B = (self.boundary_mass @ S).tocsr()

    # -- data on the constrained dofs -----------------------------------------------------------
    @property
    def scalar_points(self) -> np.ndarray:
        """Coordinates (d, m/d) of the constrained scalar dofs."""
        return self.space.doflocs[:, self.scalar_dofs]

    def restrict(self, u: np.ndarray) -> np.ndarray:
        """S u: the values of u on the constrained dofs."""
        return np.asarray(u)[self.dofs]

    def embed(self, g: np.ndarray) -> np.ndarray:
        """S^T g: g on the constrained dofs, zero elsewhere."""
        out = np.zeros(self.space.ndofs)
        out[self.dofs] = g
        return out

    # -- multiplier -----------------------------------------------------------------------------
    def multiplier_from_residual(self, r_C: np.ndarray) -> np.ndarray:
        """lambda = M_G^{-1} r_C: the equation tested with the constrained basis functions."""
        return self._bm_lu.solve(np.asarray(r_C, dtype=float))

    def reactions(self, lam: np.ndarray) -> dict[str, np.ndarray]:
        """Reaction force per part: -int_P lambda ds, one d-vector per part (support on body)."""
        L = np.asarray(lam).reshape(-1, self.space.dim)
        return {p: -(w @ L) for p, w in self._reaction_weights.items()}

    def l2_norm(self, lam: np.ndarray) -> float:
        """||lambda||_{L2(Gamma_D)} = (lambda^T M_G lambda)^{1/2}: the norm used for multipliers."""
        lam = np.asarray(lam)
        return float(np.sqrt(max(lam @ (self.boundary_mass @ lam), 0.0)))


class NodalLifting:
    """B^- g = S^T g (zero extension by the nodal basis; see the module docstring).

    Parameters
    ----------
    constraint : DirichletConstraint
    """

    name = "nodal"

    def __init__(self, constraint: DirichletConstraint):
        self.constraint = constraint

    def __call__(self, g: np.ndarray) -> np.ndarray:
        return self.constraint.embed(g)

    def lift_many(self, gs: list[np.ndarray]) -> list[np.ndarray]:
        """[B^- g for g in gs]: S^T g for each (nodal lifting)."""
        return [self.constraint.embed(g) for g in gs]


class HarmonicLifting:
    """B^- g: u_C = g, K_II u_I = -K_IC g (discrete elastic extension, K-orthogonal complement).

    Parameters
    ----------
    constraint : DirichletConstraint
    K : sparse matrix
        The stiffness matrix.
    """

    name = "harmonic"

    def __init__(self, constraint: DirichletConstraint, K):
        self.constraint = constraint
        I, C = constraint.free, constraint.dofs
        K = sp.csr_matrix(K)
        self._K_IC = K[I][:, C]
        try:
            self._lu = spla.splu(sp.csc_matrix(K[I][:, I]), permc_spec="MMD_AT_PLUS_A")
        except RuntimeError as exc:  # pragma: no cover - K_II is SPD if |Gamma_D| > 0
            raise RotheInputError(
                f"dirichlet: got parts {constraint.parts}, K is singular on their kernel ({exc})"
            ) from exc

    def __call__(self, g: np.ndarray) -> np.ndarray:
        return self.lift_many([g])[0]

    def lift_many(self, gs: list[np.ndarray]) -> list[np.ndarray]:
        """Lift several boundary vectors with one multi-column back-substitution."""
        c = self.constraint
        G = np.column_stack(gs)
        interior = self._lu.solve(-(self._K_IC @ G))
        outs = []
        for k, g in enumerate(gs):
            u = np.zeros(c.space.ndofs)
            u[c.dofs] = g
            u[c.free] = interior[:, k]
            outs.append(u)
        return outs


def make_lifting(kind: str, constraint: DirichletConstraint, K):
    """The right inverse B^- of ``kind`` ('nodal' or 'harmonic') for ``constraint`` (K: the
    stiffness the harmonic extension uses).
    """
    if kind == "nodal":
        return NodalLifting(constraint)
    if kind == "harmonic":
        return HarmonicLifting(constraint, K)
    raise fail("lifting", kind, "must be one of " + ", ".join(LIFTINGS))
