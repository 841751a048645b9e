"""Potential energies (value, gradient, Hessian) and dissipation terms."""

from .._subclasses import registered_subclasses
from ._air import AirDrag, air_drag_force
from ._barrier import BarrierContact
from ._base import Energy, axpy
from ._cloth import cloth_spring_stiffness
from ._colliders import ColliderPenalty
from ._fem import Corotated, LinearElastic, NeoHookean, StVK, TetElasticity
from ._gravity import Gravity, GravityFromArray
from ._ground import DampedGroundPenalty, GroundPenalty, ground_penalty
from ._handles import ControlPoints
from ._materials import (
    MATERIAL_MODELS,
    Material,
    MaterialModel,
    get_material_model,
    lame_parameters,
    young_poisson,
)
from ._spring import (
    Dashpots,
    Springs,
    dashpot_force,
    dashpot_force_axis,
    spring_energy,
    spring_gradient,
    spring_gradient_axis,
    spring_hessian,
)


def mass_spring(*, dashpots: bool = True, gravity: bool = True) -> list[Energy]:
    """The lecture's mass-spring system: Hooke springs, dashpots along the spring axis, gravity."""
    terms: list[Energy] = [Springs()]
    if dashpots:
        terms.append(Dashpots())
    if gravity:
        terms.append(Gravity())
    return terms


def registered_energies() -> tuple[type[Energy], ...]:
    """Every concrete, public :class:`Energy` class that exists now, sorted by name.

    Found by walking :class:`Energy`'s subclasses (so a user's or a test's energy is found once its class is
    created); abstract and private (leading ``_``) classes are left out. ``tests/test_energy_contracts.py``
    checks each one's gradient and Hessian against finite differences on its example model.
    """
    return registered_subclasses(Energy)


#: pliant's own energies (:func:`registered_energies` at import), one class each.
ALL_ENERGIES: tuple[type[Energy], ...] = registered_energies()

__all__ = [
    "dashpot_force_axis",
    "spring_gradient_axis",
    "ALL_ENERGIES",
    "Corotated",
    "LinearElastic",
    "NeoHookean",
    "StVK",
    "TetElasticity",
    "AirDrag",
    "BarrierContact",
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
    "axpy",
    "Gravity",
    "GravityFromArray",
    "GroundPenalty",
    "DampedGroundPenalty",
    "ground_penalty",
    "Springs",
    "cloth_spring_stiffness",
    "dashpot_force",
    "mass_spring",
    "registered_energies",
    "spring_energy",
    "spring_gradient",
    "spring_hessian",
]
