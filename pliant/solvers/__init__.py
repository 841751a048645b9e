"""Solvers advance a Model one step: ``step(state_in, state_out, control, dt)``."""

from ._base import Solver
from ._errors import SingularSystemError
from ._fast_cloth import FastMassSpring
from ._force import ForceSolver
from ._frame import FrameStep
from ._rigid import RigidBodySolver
from ._static import StaticStats, solve_static
from ._xpbd import PBD, XPBD

__all__ = [
    "SingularSystemError",
    "StaticStats",
    "solve_static",
    "FastMassSpring",
    "FrameStep",
    "PBD",
    "RigidBodySolver",
    "XPBD",
    "ForceSolver",
    "Solver",
]
