"""Time integrators of A dy/dt = f(y): the same objects advance NumPy ODEs and physical models."""

from ._base import Integrator, Solution, System
from ._explicit import RK2, RK4, ExplicitRK, ForwardEuler, Heun, Midpoint
from ._problems import ODEProblem, SecondOrderODE, harmonic_oscillator, lecture_oscillator
from ._symplectic import SymplecticEuler

__all__ = [
    "RK2",
    "RK4",
    "ExplicitRK",
    "ForwardEuler",
    "Heun",
    "Integrator",
    "Midpoint",
    "ODEProblem",
    "SecondOrderODE",
    "Solution",
    "SymplecticEuler",
    "System",
    "harmonic_oscillator",
    "lecture_oscillator",
]
