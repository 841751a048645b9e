"""Model / State / Control and the validating ModelBuilder."""

from ._builder import ModelBuilder
from ._model import Control, Ground, Model, State

__all__ = ["Control", "Ground", "Model", "ModelBuilder", "State"]
