"""Simulation loop: frames × substeps, recording, divergence detection, checkpoint/resume."""

from ._divergence import DivergenceError
from ._simulator import Simulator

__all__ = ["DivergenceError", "Simulator"]
