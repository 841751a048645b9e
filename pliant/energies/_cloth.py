"""Spring stiffness of a square cloth lattice from membrane elasticity (E·t, ν)."""

from __future__ import annotations


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
