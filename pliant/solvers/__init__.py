"""Solvers advance a Model one step: ``step(state_in, state_out, control, dt)``."""

from ._base import Solver
from ._force import ForceSolver

__all__ = ["ForceSolver", "Solver"]
