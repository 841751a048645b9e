"""Solvers advance a Model one step: ``step(state_in, state_out, control, dt)``.

One sub-package per solver (``force``, ``fast_mass_spring``, ``xpbd``, ``rigid``) and the minimisers'
library that implicit steps call (``minimizers``), on top of the shared pieces here (``_base``: the Solver
interface; ``_post``: the post-step stages; ``_errors``; ``_frame``). docs/design.md, "solvers/", draws
the layers.
"""

from ._base import Solver
from ._errors import SingularSystemError
from ._frame import FrameStep
from .fast_mass_spring import FastMassSpring
from .force import ForceSolver
from .minimizers import MinimizerOptions, StaticStats, solve_static
from .rigid import RigidBodySolver
from .xpbd import PBD, XPBD

__all__ = [
    "SingularSystemError",
    "StaticStats",
    "solve_static",
    "FastMassSpring",
    "FrameStep",
    "MinimizerOptions",
    "PBD",
    "RigidBodySolver",
    "XPBD",
    "ForceSolver",
    "Solver",
]
