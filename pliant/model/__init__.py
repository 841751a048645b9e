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
from ._materials import cloth_spring_stiffness, lame_parameters, young_poisson
from ._model import GROUND_DAMPING_RATIO, GROUND_STIFFNESS, STICK_VELOCITY, Control, Ground, Model, State
from ._parameters import (
    BENDING_STIFFNESS,
    SPRING_DAMPING,
    SPRING_REST_LENGTH,
    SPRING_STIFFNESS,
    TET_LAM,
    TET_MU,
    Found,
    Getter,
    Parameter,
    RegistryView,
    constraint_array,
    declares,
    parameter,
    registry,
    solver_array,
)
from ._worlds import PARAMETERS as WORLD_PARAMETERS
from ._worlds import write_range

__all__ = [
    "cloth_spring_stiffness",
    "lame_parameters",
    "young_poisson",
    "GROUND_DAMPING_RATIO",
    "GROUND_STIFFNESS",
    "BENDING_STIFFNESS",
    "SPRING_DAMPING",
    "SPRING_REST_LENGTH",
    "SPRING_STIFFNESS",
    "TET_LAM",
    "TET_MU",
    "Found",
    "Getter",
    "Parameter",
    "RegistryView",
    "constraint_array",
    "declares",
    "parameter",
    "registry",
    "solver_array",
    "WORLD_PARAMETERS",
    "write_range",
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
