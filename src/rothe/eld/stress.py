"""Stresses of a displacement field: Cauchy stress per cell, von Mises stress, nodal values.

For u_h in a vector P1/P2 space on simplices:

- **cell strain** eps_T = (1/|T|) int_T sym(grad u_h) dx: the cell mean (exact value for P1,
  where the strain is constant; for P2 the strain is linear and its mean is its value at the
  centroid), from the gradients at the quadrature points of the space (no loop over cells);
- **Cauchy stress** sigma_T = lam tr(eps_T) I + 2 mu eps_T, always as a 3 x 3 tensor: in 2D
  plane strain (eps_zz = eps_xz = eps_yz = 0) sigma_zz = lam tr(eps) is kept (it is nonzero)
  and sigma_xz = sigma_yz = 0; in plane stress sigma_zz = 0 and the in-plane law uses
  lam* = 2 lam mu/(lam + 2 mu) (:mod:`rothe.eld.materials`); with several materials
  (:class:`~rothe.eld.materials.PiecewiseMaterial`) lam and mu are those of each cell;
- **von Mises stress** sigma_vM = (3/2 s:s)^{1/2} with the deviator s = sigma - tr(sigma)/3 I,
  i.e. sqrt(1/2 [(s_xx - s_yy)^2 + (s_yy - s_zz)^2 + (s_zz - s_xx)^2]
  + 3 (s_xy^2 + s_yz^2 + s_zx^2)), with sigma_zz included in 2D;
- **nodal values** (for plotting): at every mesh vertex the volume-weighted average of the cell
  values of the cells around it, sum_T |T| sigma_T / sum_T |T| (exact for a constant field; one
  bincount per component).

This is the elastic stress sigma(u). With stiffness-proportional (Kelvin-Voigt) damping b K the
total stress of the equation of motion is sigma(u + b u'), i.e. ``cauchy_stress(u + b * v)``.
"""

from __future__ import annotations

import numpy as np

from .materials import PiecewiseMaterial


class StressEvaluator:
    """Cell stresses and their nodal averages on one :class:`~rothe.fem.elasticity.VectorSpace`.

    The mean basis gradients per cell are computed once (nbf x d x n_cells floats).

    Parameters
    ----------
    space : VectorSpace
    material : Material
    """

    def __init__(self, space, material):
        self.space = space
        if isinstance(material, PiecewiseMaterial):
            cells = material.on_mesh(space.mesh)
            self.lam, self.mu = cells.lam[:, None, None], cells.mu[:, None, None]
        else:
            self.lam = float(material.lam_eff)
            self.mu = float(material.mu)
        # plane stress: sigma_zz = 0, the in-plane law with lam* (rothe.eld.materials)
        self.plane_stress = space.dim == 2 and material.plane == "stress"
        basis = space.grad_basis
        dx = np.asarray(basis.dx)  # (ne, nq)
        vol = dx.sum(axis=1)
        grads = np.stack([b[0].grad for b in basis.basis])  # (nbf, d, ne, nq)
        self._mean_grads = np.einsum("ikeq,eq->ike", grads, dx) / vol[None, None, :]
        self.volumes = vol
        mesh = space.mesh
        self.n_vertices = mesh.p.shape[1]
        self._cell_vertices = np.asarray(mesh.t)  # (d + 1, ne)
        w = np.zeros(self.n_vertices)
        for row in self._cell_vertices:
            w += np.bincount(row, weights=vol, minlength=self.n_vertices)
        self._vertex_volume = w

    def strain(self, u: np.ndarray) -> np.ndarray:
        """Cell-mean strains, shape (n_cells, d, d)."""
        sp_ = self.space
        U = np.asarray(u, dtype=float).reshape(sp_.n_scalar, sp_.dim)
        Ue = U[sp_.element_dofs]  # (nbf, ne, d)
        grad = np.einsum("ike,iec->eck", self._mean_grads, Ue)  # [e, c, k] = d_k u_c
        return 0.5 * (grad + grad.transpose(0, 2, 1))

    def stress(self, u: np.ndarray) -> np.ndarray:
        """Cauchy stress per cell as 3 x 3 tensors, shape (n_cells, 3, 3) (module docstring)."""
        eps = self.strain(u)
        ne, d, _ = eps.shape
        tr = np.trace(eps, axis1=1, axis2=2)
        sig = np.zeros((ne, 3, 3))
        sig[:, :d, :d] = 2.0 * self.mu * eps
        lam_tr = self.lam * tr[:, None, None]
        for k in range(d if self.plane_stress else 3):
            sig[:, k, k] += lam_tr[:, 0, 0]
        return sig

    def nodal(self, cell_values: np.ndarray) -> np.ndarray:
        """Volume-weighted vertex averages: per-cell values (n_cells, ...) -> (n_vertices, ...)."""
        vals = np.asarray(cell_values, dtype=float)
        flat = vals.reshape(vals.shape[0], -1) * self.volumes[:, None]
        out = np.zeros((self.n_vertices, flat.shape[1]))
        for row in self._cell_vertices:
            for c in range(flat.shape[1]):
                out[:, c] += np.bincount(row, weights=flat[:, c], minlength=self.n_vertices)
        out /= self._vertex_volume[:, None]
        return out.reshape((self.n_vertices,) + vals.shape[1:])


def von_mises(sigma: np.ndarray) -> np.ndarray:
    """(3/2 s:s)^{1/2} of 3 x 3 stresses (..., 3, 3), s the deviator.

    Parameters
    ----------
    sigma : ndarray (..., 3, 3)

    Returns
    -------
    ndarray (...)
    """
    sigma = np.asarray(sigma, dtype=float)
    tr = np.trace(sigma, axis1=-2, axis2=-1)
    s = sigma - (tr / 3.0)[..., None, None] * np.eye(3)
    return np.sqrt(1.5 * np.sum(s * s, axis=(-2, -1)))


def cauchy_stress(space, material, u: np.ndarray) -> np.ndarray:
    """Cauchy stress per cell, (n_cells, 3, 3) (one-off use; see :class:`StressEvaluator`).

    Parameters
    ----------
    space : VectorSpace
    material : Material
    u : ndarray
        The displacement (dof vector).

    Returns
    -------
    ndarray (n_cells, 3, 3)
    """
    return StressEvaluator(space, material).stress(u)
