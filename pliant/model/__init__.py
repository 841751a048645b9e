"""Model / State / Control and the validating ModelBuilder."""

from ._builder import ModelBuilder
from ._mass import tet_consistent_mass, tet_lumped_mass, triangle_lumped_mass
from ._model import STICK_VELOCITY, Control, Ground, Model, State

__all__ = [
    "STICK_VELOCITY",
    "Control",
    "Ground",
    "Model",
    "ModelBuilder",
    "State",
    "tet_consistent_mass",
    "tet_lumped_mass",
    "triangle_lumped_mass",
]
