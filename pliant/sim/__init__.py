"""Simulation loop: frames × substeps, recording, divergence detection, checkpoint/resume."""

from ._divergence import DivergenceError, stability_advice
from ._graph import FrameGraphs, fingerprint
from ._simulator import Simulator

__all__ = ["stability_advice", "FrameGraphs", "fingerprint", "DivergenceError", "Simulator"]
