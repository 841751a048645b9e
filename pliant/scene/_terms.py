"""The energies and constraints a scene file can add by name (``[[energies]]`` / ``[[constraints]]``).

Adding a new energy or constraint to scene files is one line here (or one ``register_energy`` call next
to the class): ``register_energy("name", lambda model, **options: MyEnergy(**options))``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ._registry import register_constraint, register_energy

if TYPE_CHECKING:
    from ..constraints import ParticleCollision
    from ..energies import AirDrag
    from ..model import Model


def air_drag(
    model: Model, *, coefficient: float = 0.0, quadratic: float = 0.0, wind: list | None = None
) -> AirDrag:
    """``pl.energies.AirDrag``: linear ``coefficient`` [N s/m], ``quadratic`` [N s²/m²], ``wind`` [m/s]."""
    from ..energies import AirDrag

    return AirDrag(coefficient, quadratic=quadratic, wind=wind if wind is not None else (0.0, 0.0, 0.0))


def particle_collision(
    model: Model, *, cell_size: float | None = None, friction: float = 0.0
) -> ParticleCollision:
    """``pl.constraints.ParticleCollision`` (particle–particle contact by the particles' radii; hash-grid
    ``cell_size`` [m], Coulomb ``friction`` μ between particles)."""
    from ..constraints import ParticleCollision

    return ParticleCollision(cell_size=cell_size, friction=friction)


def register_builtin_terms() -> None:
    """Register the built-in ``[[energies]]`` and ``[[constraints]]`` kinds."""
    register_energy("air_drag", air_drag)
    register_constraint("particle_collision", particle_collision)
