"""Material constants that the model builder and the energies both need (pure NumPy, below both layers):
Lamé parameters from (E, ν) and the cloth lattice's spring stiffness from the membrane stiffness E·t.
``pliant.energies`` re-exports them (``pl.energies.lame_parameters``, ``pl.energies.cloth_spring_stiffness``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["cloth_spring_stiffness", "lame_parameters", "young_poisson"]


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


def cloth_spring_stiffness(youngs_modulus_thickness: float, poisson: float = 0.3) -> tuple[float, float]:
    """Structural and shear spring stiffness [N/m] of a square lattice with the membrane stiffness E·t.

    A square cell with axis springs k_s and both diagonals k_d stores, under a uniform small strain ε,
    W = ½(k_s + k_d)(ε_xx² + ε_yy²) + k_d ε_xx ε_yy + 2 k_d ε_xy² per unit area, i.e. the membrane
    moduli C11 = k_s + k_d, C12 = k_d, G = k_d — independent of the cell size. We match the shear modulus
    G = E t / (2(1 + ν)) and C11 = E t / (1 − ν²); C12 then equals νE t/(1 − ν²) exactly only for ν = 1/3
    (the lattice's own Poisson ratio), and within 17% for ν = 0.3. Bend springs are not counted.

    Args:
        youngs_modulus_thickness: membrane stiffness E·t [N/m] (Young's modulus [Pa] × thickness [m]).
        poisson: Poisson ratio ν in (−1, 0.5).

    Returns:
        (k_structural, k_shear) [N/m].
    """
    if youngs_modulus_thickness <= 0:
        raise ValueError(f"youngs_modulus_thickness must be > 0 N/m, got {youngs_modulus_thickness}")
    if not -1.0 < poisson < 0.5:
        raise ValueError(f"poisson must be in (-1, 0.5), got {poisson}")
    et = float(youngs_modulus_thickness)
    k_shear = et / (2.0 * (1.0 + poisson))
    k_structural = et / (1.0 - poisson**2) - k_shear
    return k_structural, k_shear
