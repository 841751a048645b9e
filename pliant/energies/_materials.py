"""Elastic materials: Lamé conversion, the ``Material`` record, and the registry of FEM material models.

A material *model* is a strain-energy density ψ(F; μ, λ) with its stress P = ∂ψ/∂F and stiffness ∂P/∂F,
implemented as generic Warp functions in :mod:`pliant.energies._fem_math`; a :class:`Material` is a model
name plus physical constants (Young's modulus, Poisson's ratio, density).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import _fem_math as fm

__all__ = [
    "MATERIAL_MODELS",
    "Material",
    "MaterialModel",
    "get_material_model",
    "lame_parameters",
    "young_poisson",
]


def lame_parameters(E: float | np.ndarray, nu: float | np.ndarray) -> tuple[Any, Any]:
    """Lamé parameters from Young's modulus and Poisson's ratio.

    μ = E / (2 (1 + ν)),  λ = E ν / ((1 + ν)(1 − 2ν)).

    Args:
        E: Young's modulus [Pa], > 0; a scalar or an array (e.g. per element).
        nu: Poisson's ratio, in the open interval (−1, 0.5); scalar or array broadcastable with ``E``.

    Returns:
        ``(mu, lam)`` [Pa]: Python floats for scalar inputs, else float64 arrays.

    Raises:
        ValueError: if ``E`` is not finite and positive or ``nu`` is outside (−1, 0.5).
    """
    E_arr = np.asarray(E, dtype=np.float64)
    nu_arr = np.asarray(nu, dtype=np.float64)
    if not np.all(np.isfinite(E_arr) & (E_arr > 0.0)):
        bad = E_arr[~(np.isfinite(E_arr) & (E_arr > 0.0))].ravel()
        raise ValueError(f"E (Young's modulus) must be finite and > 0 [Pa], got {bad[:5].tolist()}")
    if not np.all((nu_arr > -1.0) & (nu_arr < 0.5)):
        bad = nu_arr[~((nu_arr > -1.0) & (nu_arr < 0.5))].ravel()
        raise ValueError(
            f"nu (Poisson's ratio) must lie in the open interval (-1, 0.5), got {bad[:5].tolist()}; "
            "nu = 0.5 (incompressible) makes lam infinite"
        )
    mu = E_arr / (2.0 * (1.0 + nu_arr))
    lam = E_arr * nu_arr / ((1.0 + nu_arr) * (1.0 - 2.0 * nu_arr))
    if mu.ndim == 0:
        return float(mu), float(lam)
    return mu, lam


def young_poisson(mu: float, lam: float) -> tuple[float, float]:
    """Inverse of :func:`lame_parameters`: E = μ (3λ + 2μ) / (λ + μ), ν = λ / (2 (λ + μ)).

    Args:
        mu: Shear modulus [Pa], > 0.
        lam: First Lamé parameter [Pa], with 3λ + 2μ > 0 (positive bulk modulus).

    Returns:
        ``(E, nu)``.
    """
    if not (math.isfinite(mu) and mu > 0.0):
        raise ValueError(f"mu (shear modulus) must be finite and > 0 [Pa], got {mu}")
    if not (math.isfinite(lam) and 3.0 * lam + 2.0 * mu > 0.0):
        raise ValueError(f"lam must satisfy 3 lam + 2 mu > 0 (positive bulk modulus), got lam={lam}, mu={mu}")
    return mu * (3.0 * lam + 2.0 * mu) / (lam + mu), lam / (2.0 * (lam + mu))


@dataclass(frozen=True)
class MaterialModel:
    """One hyperelastic model: generic Warp functions of (F, mu, lam), see :mod:`pliant.energies._fem_math`.

    Attributes:
        name: Registry key.
        description: The energy density formula.
        psi: ``@wp.func`` ψ(F, mu, lam) [J/m³].
        pk1: ``@wp.func`` P(F, mu, lam) = ∂ψ/∂F [Pa].
        dpk1_df: ``@wp.func`` ∂P/∂F, 9×9, column-major vec(F).
        dpk1_df_psd: ``@wp.func`` ∂P/∂F with negative eigenvalues clamped to 0.
        rotation_invariant: ψ(QF) = ψ(F) for rotations Q (False only for linear elasticity).
        uses_svd: P needs a polar decomposition (per-element SVD).
    """

    name: str
    description: str
    psi: Any
    pk1: Any
    dpk1_df: Any
    dpk1_df_psd: Any
    rotation_invariant: bool
    uses_svd: bool


MATERIAL_MODELS: dict[str, MaterialModel] = {
    "linear": MaterialModel(
        "linear",
        "psi = mu eps:eps + lam/2 tr(eps)^2, eps = (F + F^T)/2 - I",
        fm.linear_psi,
        fm.linear_pk1,
        fm.linear_dpk1_df,
        fm.linear_dpk1_df_psd,
        rotation_invariant=False,
        uses_svd=False,
    ),
    "stvk": MaterialModel(
        "stvk",
        "psi = mu E:E + lam/2 tr(E)^2, E = (F^T F - I)/2",
        fm.stvk_psi,
        fm.stvk_pk1,
        fm.stvk_dpk1_df,
        fm.stvk_dpk1_df_psd,
        rotation_invariant=True,
        uses_svd=False,
    ),
    "corotated": MaterialModel(
        "corotated",
        "psi = mu |F - R|^2 + lam/2 (J - 1)^2, F = R S",
        fm.corotated_psi,
        fm.corotated_pk1,
        fm.corotated_dpk1_df,
        fm.corotated_dpk1_df_psd,
        rotation_invariant=True,
        uses_svd=True,
    ),
    "neohookean": MaterialModel(
        "neohookean",
        "psi = mu/2 (I_C - 3) - mu (J - 1) + (lam + mu)/2 (J - 1)^2  (stable neo-Hookean)",
        fm.neohookean_psi,
        fm.neohookean_pk1,
        fm.neohookean_dpk1_df,
        fm.neohookean_dpk1_df_psd,
        rotation_invariant=True,
        uses_svd=False,
    ),
}
"""The FEM material models, by name."""


def get_material_model(name: str) -> MaterialModel:
    """The :class:`MaterialModel` registered as ``name``.

    Raises:
        ValueError: for an unknown name, listing the allowed ones.
    """
    try:
        return MATERIAL_MODELS[name]
    except (KeyError, TypeError):
        allowed = ", ".join(repr(k) for k in MATERIAL_MODELS)
        raise ValueError(f"unknown material model {name!r}; allowed values: {allowed}") from None


@dataclass(frozen=True)
class Material:
    """An elastic solid: a material model and its physical constants.

    The Lamé parameters used by the element functions follow from (E, ν): μ = E/(2(1+ν)),
    λ = Eν/((1+ν)(1−2ν)).

    Attributes:
        name: Material model, one of ``"linear"``, ``"stvk"``, ``"corotated"``, ``"neohookean"``.
        E: Young's modulus [Pa], > 0.
        nu: Poisson's ratio, in (−1, 0.5).
        density: Mass density [kg/m³], > 0.

    Example:
        >>> rubber = Material("neohookean", E=1e6, nu=0.45, density=1100.0)
        >>> round(rubber.mu)
        344828
    """

    name: str
    E: float
    nu: float
    density: float

    def __post_init__(self) -> None:
        get_material_model(self.name)
        lame_parameters(self.E, self.nu)
        if not (math.isfinite(self.density) and self.density > 0.0):
            raise ValueError(f"density must be finite and > 0 [kg/m^3], got {self.density}")

    @property
    def model(self) -> MaterialModel:
        """The registered :class:`MaterialModel`."""
        return get_material_model(self.name)

    @property
    def mu(self) -> float:
        """Shear modulus μ [Pa]."""
        return lame_parameters(self.E, self.nu)[0]

    @property
    def lam(self) -> float:
        """First Lamé parameter λ [Pa]."""
        return lame_parameters(self.E, self.nu)[1]
