"""Linear isotropic elastic material: density rho and Lamé constants lam, mu (Sec. 2.2.1).

sigma(u) = lam tr(eps(u)) I + 2 mu eps(u). The stiffness K of (2.3) is coercive on the kernel
of the trace (Korn) exactly when mu > 0 and the bulk modulus lam + 2 mu / d is positive, i.e.
lam > -2 mu / d; both are checked here, where the values enter.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import check_positive, check_real, fail
from ..fem.elasticity import lame_from_young


@dataclass(frozen=True)
class Material:
    """rho > 0, mu > 0, lam > -2 mu / dim (dim = 2 plane strain, or 3).

    Parameters
    ----------
    rho : float
        Density.
    lam, mu : float
        Lamé constants.
    dim : int
        2 (plane strain) or 3.
    """

    rho: float
    lam: float
    mu: float
    dim: int = 2

    def __post_init__(self):
        check_positive("rho", self.rho)
        check_positive("mu", self.mu)
        lam = check_real("lam", self.lam)
        if self.dim not in (2, 3):
            raise fail("dim", self.dim, "must be 2 or 3")
        bound = -2.0 * self.mu / self.dim
        if not lam > bound:
            raise fail("lam", lam, f"must be > -2 mu / d = {bound:g} (positive bulk modulus)")

    @classmethod
    def from_young(cls, E: float, nu: float, rho: float, dim: int = 3) -> Material:
        """From Young's modulus E > 0 and Poisson ratio -1 < nu < 1/2."""
        lam, mu = lame_from_young(E, nu)
        return cls(rho=rho, lam=lam, mu=mu, dim=dim)

    @property
    def wave_speeds(self) -> tuple[float, float]:
        """(pressure, shear) wave speeds sqrt((lam + 2 mu)/rho), sqrt(mu/rho)."""
        return ((self.lam + 2 * self.mu) / self.rho) ** 0.5, (self.mu / self.rho) ** 0.5
