"""Model / State / Control and the validating ModelBuilder."""

from ._builder import ModelBuilder
from ._mass import (
    MASS_DISTRIBUTIONS,
    distribute_mass,
    distribute_mass_grad,
    tet_consistent_mass,
    tet_lumped_mass,
    triangle_lumped_mass,
)
from ._model import STICK_VELOCITY, Control, Ground, Model, State

__all__ = [
    "MASS_DISTRIBUTIONS",
    "STICK_VELOCITY",
    "Control",
    "Ground",
    "Model",
    "ModelBuilder",
    "State",
    "distribute_mass",
    "distribute_mass_grad",
    "tet_consistent_mass",
    "tet_lumped_mass",
    "triangle_lumped_mass",
]
