"""Time integrators of A dy/dt = f(y): the same objects advance NumPy ODEs and physical models."""

from ._base import Integrator, Solution, System
from ._dopri import DormandPrince
from ._explicit import RK2, RK4, ExplicitRK, ForwardEuler, Heun, Midpoint
from ._implicit import BDF2, BackwardEuler, ImplicitMidpoint, ImplicitOptions
from ._problems import ODEProblem, SecondOrderODE, harmonic_oscillator, lecture_oscillator
from ._symplectic import SymplecticEuler
from ._verlet import Leapfrog, VelocityVerlet

__all__ = [
    "BDF2",
    "RK2",
    "RK4",
    "BackwardEuler",
    "DormandPrince",
    "ExplicitRK",
    "ForwardEuler",
    "Heun",
    "ImplicitMidpoint",
    "ImplicitOptions",
    "Integrator",
    "Leapfrog",
    "Midpoint",
    "ODEProblem",
    "SecondOrderODE",
    "Solution",
    "SymplecticEuler",
    "System",
    "VelocityVerlet",
    "harmonic_oscillator",
    "lecture_oscillator",
]
