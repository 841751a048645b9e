"""Simulation loop: frames × substeps, recording, divergence detection, checkpoint/resume."""

from ._simulator import DivergenceError, Simulator

__all__ = ["DivergenceError", "Simulator"]
