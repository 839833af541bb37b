"""Linear isotropic elastic materials: density rho and Lamé constants lam, mu (Sec. 2.2.1).

sigma(u) = lam tr(eps(u)) I + 2 mu eps(u). The stiffness K of (2.3) is coercive on the kernel
of the trace (Korn) exactly when mu > 0 and the bulk modulus of the model is positive; both are
checked here, where the values enter.

**2D models** (``plane=``): ``"strain"`` (default; eps_zz = 0, the 2D stiffness uses lam, and
sigma_zz = lam tr eps) or ``"stress"`` (sigma_zz = 0; eliminating eps_zz = -lam/(lam + 2 mu)
tr eps gives the 2D law with the effective constant lam* = 2 lam mu / (lam + 2 mu), i.e. in
terms of E, nu: sigma = E/(1 - nu^2) [(1 - nu) eps + nu tr(eps) I]). ``lam`` is always the
three-dimensional Lamé constant; :attr:`Material.lam_eff` is what the 2D assembly uses.
Positivity: plane strain and 3D need lam > -2 mu / d; plane stress needs the 3D material to be
admissible, lam > -2 mu / 3 (equivalently lam* > -mu).

**Two ways to give the elastic constants** (:func:`material_from`): Young's modulus and
Poisson's ratio (E, nu), or the Lamé constants (lam, mu), with

    lam = E nu / ((1 + nu)(1 - 2 nu)),   mu = E / (2 (1 + nu));
    E = mu (3 lam + 2 mu) / (lam + mu),   nu = lam / (2 (lam + mu)).

One pair at a time: mixing them (E with mu, say) is refused, naming both. A pair given in part
takes its other member from the caller's default material.

**Several materials in one body** (:class:`PiecewiseMaterial`): materials by name, assigned to
regions (the subdomains of the mesh, e.g. gmsh physical groups of the cells read by
:func:`rothe.fem.mesh.load_mesh`, or predicates on the cell centroids). :meth:`
PiecewiseMaterial.on_mesh` gives per-cell arrays lam_c, mu_c, rho_c; the stiffness is assembled
with them (:meth:`rothe.fem.elasticity.VectorSpace.stiffness`) and the mass as
M = int (rho(x)/rho_ref) u . v dx with the reference density rho_ref =
:attr:`PiecewiseMaterial.rho` (default: the largest density), so that rho_ref M is the mass of
the actual density and every formula written with rho M (the schemes, the energy, Lemma 3.2's
bound rho_ref/d0 for a damping stated relative to this M) holds unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import RotheInputError, check_positive, check_real, described, fail
from ..fem.elasticity import lame_from_young

#: the 2D models
PLANES = ("strain", "stress")


@dataclass(frozen=True)
class Material:
    """rho > 0, mu > 0, lam > -2 mu / dim (dim = 2 plane strain, or 3); plane stress in 2D
    (``plane="stress"``) needs lam > -2 mu / 3 (see the module docstring).

    Parameters
    ----------
    rho : float
        Density.
    lam, mu : float
        Lamé constants.
    dim : int
        2 or 3.
    plane : {'strain', 'stress'}
        The 2D model (default plane strain; a 3D material is 'strain').
    """

    rho: float
    lam: float
    mu: float
    dim: int = 2
    plane: str = "strain"

    def __post_init__(self):
        check_positive("rho", self.rho)
        check_positive("mu", self.mu)
        lam = check_real("lam", self.lam)
        if self.dim not in (2, 3):
            raise fail("dim", self.dim, "must be 2 or 3")
        if self.plane not in PLANES:
            raise fail("plane", self.plane, "must be one of " + ", ".join(PLANES))
        if self.dim == 3 and self.plane != "strain":
            raise fail(
                "plane",
                self.plane,
                "must be 'strain' (the default) in 3D: plane stress is a 2D model",
            )
        if self.plane == "stress":
            bound = -2.0 * self.mu / 3.0
            if not lam > bound:
                raise fail(
                    "lam",
                    lam,
                    f"must be > -2 mu / 3 = {bound:g} for plane stress (an admissible 3D material)",
                )
        else:
            bound = -2.0 * self.mu / self.dim
            if not lam > bound:
                raise fail("lam", lam, f"must be > -2 mu / d = {bound:g} (positive bulk modulus)")

    @classmethod
    def from_young(
        cls, E: float, nu: float, rho: float, dim: int = 3, plane: str = "strain"
    ) -> Material:
        """From Young's modulus E > 0 and Poisson ratio -1 < nu < 1/2."""
        lam, mu = lame_from_young(E, nu)
        return cls(rho=rho, lam=lam, mu=mu, dim=dim, plane=plane)

    @property
    def lam_eff(self) -> float:
        """The Lamé constant of the model's stiffness: lam (3D, plane strain) or
        lam* = 2 lam mu / (lam + 2 mu) (plane stress)."""
        if self.plane == "stress":
            return 2.0 * self.lam * self.mu / (self.lam + 2.0 * self.mu)
        return self.lam

    @property
    def young(self) -> tuple[float, float]:
        """(E, nu) of the 3D material: E = mu (3 lam + 2 mu)/(lam + mu), nu = lam/(2 (lam + mu))."""
        lam, mu = self.lam, self.mu
        return mu * (3 * lam + 2 * mu) / (lam + mu), lam / (2 * (lam + mu))

    @property
    def wave_speeds(self) -> tuple[float, float]:
        """(pressure, shear) wave speeds sqrt((lam + 2 mu)/rho), sqrt(mu/rho) of the model
        (lam_eff in plane stress)."""
        return ((self.lam_eff + 2 * self.mu) / self.rho) ** 0.5, (self.mu / self.rho) ** 0.5

    def describe(self) -> dict:
        """rho, lam, mu (and plane unless plane strain), for summaries."""
        out = {"rho": self.rho, "lam": self.lam, "mu": self.mu}
        if self.plane != "strain":  # (plane strain: the keys summaries always had)
            out["plane"] = self.plane
        return out


#: the two pairs of elastic constants :func:`material_from` takes
ELASTIC_PAIRS = (("E", "nu"), ("lam", "mu"))


def _young_of(lam: float, mu: float) -> tuple[float, float]:
    """(E, nu) = (mu (3 lam + 2 mu)/(lam + mu), lam/(2 (lam + mu)))."""
    return mu * (3 * lam + 2 * mu) / (lam + mu), lam / (2 * (lam + mu))


def material_from(
    *,
    rho: float,
    E: float | None = None,
    nu: float | None = None,
    lam: float | None = None,
    mu: float | None = None,
    dim: int = 2,
    plane: str = "strain",
    default: dict | None = None,
) -> Material:
    """A :class:`Material` from one of the pairs (E, nu) or (lam, mu) and the density rho.

    (E, nu) gives lam = E nu/((1 + nu)(1 - 2 nu)), mu = E/(2 (1 + nu))
    (:meth:`Material.from_young`); (lam, mu) is taken as it is. Giving members of both pairs
    is refused with one line naming both (``E: got 210, must not be combined with lam: give
    E, nu or lam, mu``).

    Parameters
    ----------
    rho : float
        Density.
    E, nu, lam, mu : float, optional
        One pair, or one member of a pair (the other from ``default``).
    dim : int
        2 or 3.
    plane : {'strain', 'stress'}
        The 2D model.
    default : dict, optional
        The material where no constant is given: ``{"E": .., "nu": ..}`` or
        ``{"lam": .., "mu": ..}``; it also completes a pair given in part (converted by the
        formulas of the module docstring when it is the other pair).

    Returns
    -------
    Material
    """
    given = {k: v for k, v in (("E", E), ("nu", nu), ("lam", lam), ("mu", mu)) if v is not None}
    young = [k for k in ELASTIC_PAIRS[0] if k in given]
    lame = [k for k in ELASTIC_PAIRS[1] if k in given]
    if young and lame:
        a, b = young[0], lame[0]
        raise RotheInputError(
            str(fail(a, given[a], f"must not be combined with {b}: give E, nu or lam, mu")),
            a,
            mentions=(b, "E", "nu", "lam", "mu"),
        )
    default = dict(default or {})
    if not given and not default:
        raise fail("E", None, "must be given with nu, or lam with mu")
    use_young = bool(young) or (not lame and "E" in default)
    if use_young:
        if "E" in default:
            base = (default["E"], default["nu"])
        else:
            base = _young_of(default["lam"], default["mu"]) if default else (None, None)
        values = [given.get(k, d) for k, d in zip(ELASTIC_PAIRS[0], base, strict=True)]
        return Material.from_young(*values, rho, dim=dim, plane=plane)
    if "lam" in default:
        base = (default["lam"], default["mu"])
    else:
        base = lame_from_young(default["E"], default["nu"]) if default else (None, None)
    values = [given.get(k, d) for k, d in zip(ELASTIC_PAIRS[1], base, strict=True)]
    return Material(rho=rho, lam=values[0], mu=values[1], dim=dim, plane=plane)


def materials_from(
    constants: dict,
    *,
    regions: dict | None = None,
    dim: int = 2,
    plane: str = "strain",
    rho: float | None = None,
) -> PiecewiseMaterial:
    """Materials by name from their constants: ``{"steel": {"E": 210e9, "nu": 0.3, "rho":
    7800}, "rubber": {"lam": .., "mu": .., "rho": ..}}`` -> a :class:`PiecewiseMaterial` on
    ``regions`` (region -> material name; default: each name is a region of the mesh).

    Each material takes one pair, (E, nu) or (lam, mu), as :func:`material_from`; ``rho`` is the
    density of a material that gives none. A bad entry is one line naming ``materials`` and the
    material: ``materials: got 'steel' with E: got -1, must be > 0``.

    Parameters
    ----------
    constants : dict name -> dict
        The keys of each: E, nu, lam, mu, rho.
    regions : dict, optional
        As in :class:`PiecewiseMaterial`.
    dim : int
    plane : {'strain', 'stress'}
    rho : float, optional

    Returns
    -------
    PiecewiseMaterial
    """
    if not isinstance(constants, dict) or not constants:
        raise fail("materials", constants, "must map at least one name to its constants")
    allowed = ("E", "nu", "lam", "mu", "rho")
    materials = {}
    for name, values in constants.items():
        values = dict(values)
        unknown = [k for k in values if k not in allowed]
        if unknown:
            raise fail(
                "materials",
                described(f"{name!r} with {unknown[0]!r}"),
                "must give E, nu or lam, mu, and rho",
            )
        density = values.pop("rho", rho)
        try:
            if not any(k in values for k in allowed):
                raise fail("E", None, "must be given with nu, or lam with mu")
            materials[name] = material_from(rho=density, dim=dim, plane=plane, **values)
        except RotheInputError as exc:
            raise RotheInputError(f"materials: got {name!r} with {exc}", "materials") from None
    return PiecewiseMaterial(materials, regions=regions)


@dataclass(frozen=True)
class CellMaterial:
    """Per-cell material data on one mesh: arrays (n_cells,) and the reference density."""

    lam: np.ndarray
    mu: np.ndarray
    rho: np.ndarray
    rho_ref: float
    names: np.ndarray  # index into PiecewiseMaterial.names, per cell

    @property
    def density_weight(self) -> np.ndarray:
        """rho_c / rho_ref: the weight of the mass matrix (module docstring)."""
        return self.rho / self.rho_ref


@dataclass(frozen=True)
class PiecewiseMaterial:
    """Several materials in one body, by name, on regions of the mesh.

    Parameters
    ----------
    materials : dict name -> Material
        All of the same ``dim`` and ``plane``.
    regions : dict region -> material name, optional
        A region is a subdomain name of the mesh (``mesh.subdomains``: gmsh physical groups of
        the cells, meshio cell sets) or a callable ``inside(x) -> bool array`` of the cell
        centroids x (d, n_cells). Default: each material name is itself a region name.
        Every cell must be in exactly one region (or in several with the same material).
    reference_density : float, optional
        rho_ref of the mass matrix (default: the largest density).

    ``rho`` is rho_ref, so a PiecewiseMaterial can stand where a :class:`Material`'s density
    is used as the factor of M (module docstring); ``lam`` and ``mu`` are None (they are
    per-cell: :meth:`on_mesh`).
    """

    materials: dict
    regions: dict | None = None
    reference_density: float | None = None
    names: tuple = field(init=False)

    def __post_init__(self):
        if not isinstance(self.materials, dict) or not self.materials:
            raise fail("materials", self.materials, "must map at least one name to a Material")
        for name, m in self.materials.items():
            if not isinstance(m, Material):
                raise fail(f"materials[{name!r}]", type(m).__name__, "must be a rothe.eld.Material")
        first = next(iter(self.materials.values()))
        for name, m in self.materials.items():
            if (m.dim, m.plane) != (first.dim, first.plane):
                raise fail(
                    f"materials[{name!r}]",
                    described(f"dim {m.dim}, plane {m.plane!r}"),
                    f"must match the other materials (dim {first.dim}, plane {first.plane!r})",
                )
        regions = {n: n for n in self.materials} if self.regions is None else dict(self.regions)
        if not regions:
            raise fail("regions", regions, "must assign at least one region")
        for region, name in regions.items():
            if not (isinstance(region, str) or callable(region)):
                raise fail("regions", region, "keys must be subdomain names or callables")
            if name not in self.materials:
                label = region if isinstance(region, str) else getattr(region, "__name__", "?")
                raise fail(
                    "regions",
                    described(f"{label!r} -> {name!r}"),
                    "must map each region to one of the materials: "
                    + ", ".join(map(str, self.materials)),
                )
        object.__setattr__(self, "regions", regions)
        object.__setattr__(self, "names", tuple(self.materials))
        if self.reference_density is not None:
            check_positive("reference_density", self.reference_density)

    @property
    def dim(self) -> int:
        return next(iter(self.materials.values())).dim

    @property
    def plane(self) -> str:
        return next(iter(self.materials.values())).plane

    @property
    def rho(self) -> float:
        """rho_ref (module docstring)."""
        if self.reference_density is not None:
            return float(self.reference_density)
        return max(m.rho for m in self.materials.values())

    lam = None
    mu = None

    def on_mesh(self, mesh) -> CellMaterial:
        """Per-cell lam_eff, mu, rho (n_cells,) on ``mesh``; one-line errors for a region the
        mesh does not have, cells in no region, and cells in regions of different materials."""
        p, t = np.asarray(mesh.p), np.asarray(mesh.t)
        ne = t.shape[1]
        subdomains = getattr(mesh, "subdomains", None) or {}
        which = np.full(ne, -1, dtype=np.int64)
        index = {n: k for k, n in enumerate(self.names)}
        centroids = None
        for region, name in self.regions.items():
            if callable(region):
                if centroids is None:
                    centroids = p[:, t].mean(axis=1)
                cells = np.flatnonzero(np.asarray(region(centroids), dtype=bool).reshape(-1))
                label = getattr(region, "__name__", "callable")
            else:
                if region not in subdomains:
                    known = ", ".join(sorted(subdomains)) or "(the mesh has no subdomains)"
                    if all(r == n for r, n in self.regions.items()):  # (no regions given)
                        raise fail(
                            "materials",
                            region,
                            f"must be one of the mesh's subdomains: {known} (a material without "
                            "a region fills the cell group of its name)",
                        )
                    raise fail("regions", region, f"must be one of the mesh's subdomains: {known}")
                cells = np.asarray(subdomains[region], dtype=np.int64)
                label = region
            k = index[name]
            clash = cells[(which[cells] >= 0) & (which[cells] != k)]
            if clash.size:
                other = self.names[which[clash[0]]]
                x = ", ".join(f"{v:.4g}" for v in p[:, t[:, clash[0]]].mean(axis=1))
                raise fail(
                    "regions",
                    label,
                    f"must not overlap a region of another material: "
                    f"{clash.size} cells (the first at ({x})) are both {name!r} and "
                    f"{other!r}",
                )
            which[cells] = k
        missing = np.flatnonzero(which < 0)
        if missing.size:
            x = ", ".join(f"{v:.4g}" for v in p[:, t[:, missing[0]]].mean(axis=1))
            regions = ", ".join(
                r if isinstance(r, str) else getattr(r, "__name__", "callable")
                for r in self.regions
            )
            raise RotheInputError(
                f"materials: got {missing.size} of {ne} cells in no region with a material (the "
                f"first at ({x})), every cell must be in one of the regions {regions}",
                "materials",
            )
        mats = [self.materials[n] for n in self.names]
        lam = np.array([m.lam_eff for m in mats])[which]
        mu = np.array([m.mu for m in mats])[which]
        rho = np.array([m.rho for m in mats])[which]
        return CellMaterial(lam=lam, mu=mu, rho=rho, rho_ref=self.rho, names=which)

    def describe(self) -> dict:
        """The materials, the regions and the reference density, for summaries."""
        return {
            "materials": {n: m.describe() for n, m in self.materials.items()},
            "regions": {
                (r if isinstance(r, str) else getattr(r, "__name__", "callable")): n
                for r, n in self.regions.items()
            },
            "rho_ref": self.rho,
        }


def pressure_wave_speed(material) -> float:
    """The fastest pressure wave speed c_p = sqrt((lam + 2 mu)/rho) of ``material`` (of its
    materials for a piecewise one)."""
    parts = getattr(material, "materials", None)
    if parts:
        return max(m.wave_speeds[0] for m in parts.values())
    return float(material.wave_speeds[0])
