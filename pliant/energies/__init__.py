"""Potential energies (value, gradient, Hessian) and dissipation terms."""

from ._base import Energy
from ._cloth import cloth_spring_stiffness
from ._gravity import Gravity
from ._materials import (
    MATERIAL_MODELS,
    Material,
    MaterialModel,
    get_material_model,
    lame_parameters,
    young_poisson,
)
from ._spring import Dashpots, Springs, dashpot_force, spring_energy, spring_gradient, spring_hessian


def mass_spring(*, dashpots: bool = True, gravity: bool = True) -> list[Energy]:
    """The lecture's mass-spring system: Hooke springs, dashpots along the spring axis, gravity."""
    terms: list[Energy] = [Springs()]
    if dashpots:
        terms.append(Dashpots())
    if gravity:
        terms.append(Gravity())
    return terms


__all__ = [
    "MATERIAL_MODELS",
    "Material",
    "MaterialModel",
    "get_material_model",
    "lame_parameters",
    "young_poisson",
    "Dashpots",
    "Energy",
    "Gravity",
    "Springs",
    "cloth_spring_stiffness",
    "dashpot_force",
    "mass_spring",
    "spring_energy",
    "spring_gradient",
    "spring_hessian",
]
