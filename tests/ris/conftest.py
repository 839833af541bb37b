"""Problems and step checks shared by the RIS tests (``from .conftest import ...``)."""

from __future__ import annotations

import numpy as np

from rothe import RISProblem
from rothe.fem.scalar import lumped_mass
from rothe.ris import examples
from rothe.ris.inner import InnerOptions

#: the sparse LU, whatever the size (the tests compare runs bit for bit)
DIRECT = InnerOptions(linear_solver="direct")


def readme_problem(**overrides) -> RISProblem:
    """The README's first Python example (3 unknowns, a double well, T = 1)."""
    n = 3
    kw = dict(
        A=np.diag([2.0, 2.0, 2.0]) - np.diag([1.0, 1.0], 1) - np.diag([1.0, 1.0], -1),
        F=lambda z: float(np.sum((1 - z**2) ** 2)),
        dF=lambda z: -4 * z * (1 - z**2),
        d2F=lambda z: 12 * z**2 - 4,
        load=lambda t: np.full(n, 3.0 * t),
        dissipation_weights=0.5,
        metric_weights=1.0,
        z0=np.full(n, -1.0),
        T=1.0,
    )
    kw.update(overrides)
    return RISProblem(**kw)


def ris_1d_problem(**overrides) -> RISProblem:
    """Example 7.1 built by hand, with any argument of RISProblem replaced."""
    kw = dict(
        A=np.array([[1.0]]),
        F=examples.p,
        dF=examples.dp,
        d2F=examples.d2p,
        load=lambda t: np.array([t + 1.0]),
        dissipation_weights=1.0,
        metric_weights=1.0,
        z0=np.array([-2.0]),
        T=5.0,
    )
    kw.update(overrides)
    return RISProblem(**kw)


def check_every_step(problem, traj):
    """KKT residual, (3.2), Lemma 4.12, the ball, complementarity of lambda, t monotone."""
    kkt, kkt_tol = traj["kkt"], traj["kkt_tol"]
    assert np.all(kkt <= kkt_tol), f"KKT residual above tolerance: {np.nonzero(kkt > kkt_tol)[0]}"
    energy = traj["energy"]
    scale = 1e-12 * max(1.0, float(np.max(np.abs(energy))))
    assert np.all(traj["descent"] >= -scale), "(3.2) violated"
    I1, I2 = traj["I1"], traj["I2"]
    assert np.all(I1 >= -1e-14)
    # Lemma 4.12: I2 >= 0 up to the quadrature error (embedded-rule estimate) and round-off
    assert np.all(I2 >= -(traj["I2_err"] + 1e-12)), f"min I2 = {I2.min():.3g}"
    m_all = lumped_mass(problem.mesh)
    Z, tau, lam, t = traj["z"], traj["tau"], traj["lam"], traj["t"]
    nd = np.sqrt(np.sum(m_all * np.diff(Z, axis=0) ** 2, axis=1))
    # ||z_k - z_{k-1}||_V <= tau_k up to round-off of the difference of two O(1) states
    roundoff = 1e-14 * max(1.0, float(np.max(np.abs(Z))))
    assert np.all(nd <= tau * (1 + 1e-10) + roundoff)
    on_sphere = lam > 0  # complementarity (4.3): lambda > 0 only on the sphere
    assert np.all(np.abs(nd[on_sphere] - tau[on_sphere]) <= 1e-8 * tau[on_sphere] + roundoff)
    assert np.all(np.diff(t) >= 0) and abs(t[-1] - problem.T) <= 1e-9
    assert np.all(Z[:, problem.fixed] == 0)
