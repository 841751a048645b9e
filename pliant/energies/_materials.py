"""Elastic materials: Lamé conversion, the ``Material`` record, and the registry of FEM material models.

A material *model* is a strain-energy density ψ(F; μ, λ) with its stress P = ∂ψ/∂F and stiffness ∂P/∂F,
implemented as generic Warp functions in :mod:`pliant.energies._fem_math`; a :class:`Material` is a model
name plus physical constants (Young's modulus, Poisson's ratio, density).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from ..model import lame_parameters, young_poisson
from . import _fem_math as fm

__all__ = [
    "MATERIAL_MODELS",
    "Material",
    "MaterialModel",
    "get_material_model",
    "lame_parameters",
    "young_poisson",
]


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
