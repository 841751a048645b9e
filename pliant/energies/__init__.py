"""Potential energies (value, gradient, Hessian) and dissipation terms."""

from ._air import AirDrag, air_drag_force
from ._base import Energy
from ._cloth import cloth_spring_stiffness
from ._colliders import ColliderPenalty
from ._fem import Corotated, LinearElastic, NeoHookean, StVK, TetElasticity
from ._gravity import Gravity, GravityFromArray
from ._ground import GroundPenalty
from ._handles import ControlPoints
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
    "Corotated",
    "LinearElastic",
    "NeoHookean",
    "StVK",
    "TetElasticity",
    "AirDrag",
    "ColliderPenalty",
    "ControlPoints",
    "air_drag_force",
    "MATERIAL_MODELS",
    "Material",
    "MaterialModel",
    "get_material_model",
    "lame_parameters",
    "young_poisson",
    "Dashpots",
    "Energy",
    "Gravity",
    "GravityFromArray",
    "GroundPenalty",
    "Springs",
    "cloth_spring_stiffness",
    "dashpot_force",
    "mass_spring",
    "spring_energy",
    "spring_gradient",
    "spring_hessian",
]
