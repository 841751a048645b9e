"""The Solver contract shared by every model (Newton's / warp.sim's convention)."""

from __future__ import annotations

import abc

from ..model import Control, Model, State


class Solver(abc.ABC):
    """Advances a Model one step: ``step(state_in, state_out, control, dt)``; never writes ``state_in``."""

    def __init__(self, model: Model) -> None:
        self.model = model

    @abc.abstractmethod
    def step(self, state_in: State, state_out: State, control: Control | None, dt: float) -> None:
        """Advance ``state_in`` by ``dt`` [s] into ``state_out``."""

    def describe(self) -> dict:
        """Name and options, recorded in trajectory metadata and benchmark lines."""
        return {"solver": type(self).__name__}
