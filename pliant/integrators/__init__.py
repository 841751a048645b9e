"""Time integrators of A dy/dt = f(y): the same objects advance NumPy ODEs and physical models."""

from .._subclasses import registered_subclasses
from ._base import Integrator, Solution, System
from ._dopri import DormandPrince
from ._explicit import RK2, RK4, ExplicitRK, ForwardEuler, Heun, Midpoint, scale_velocity
from ._implicit import BDF2, BackwardEuler, ImplicitMidpoint, ImplicitOptions, ImplicitOptionsLike
from ._ops import lincomb
from ._problems import ODEProblem, SecondOrderODE, harmonic_oscillator, lecture_oscillator
from ._symplectic import SymplecticEuler, symplectic_particle
from ._verlet import Leapfrog, VelocityVerlet


def registered_integrators() -> tuple[type[Integrator], ...]:
    """Every integrator class that exists now and can be made without arguments, sorted by name.

    Found by walking :class:`Integrator`'s subclasses, so an integrator defined anywhere (a user's, a
    test's) is found once its class is created; classes whose constructor needs arguments (the generic
    :class:`ExplicitRK`, which needs a tableau) and private ones (a leading ``_``) are left out.
    ``tests/test_integrator_contracts.py`` checks each one's declared order, its momentum conservation and
    its flags.
    """
    import inspect

    def no_required_arguments(cls: type) -> bool:
        params = list(inspect.signature(cls).parameters.values())
        return all(p.default is not p.empty or p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD) for p in params)

    return registered_subclasses(Integrator, no_required_arguments)


#: pliant's own integrators (:func:`registered_integrators` at import), one class each.
ALL_INTEGRATORS: tuple[type[Integrator], ...] = registered_integrators()

__all__ = [
    "scale_velocity",
    "lincomb",
    "symplectic_particle",
    "ALL_INTEGRATORS",
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
    "ImplicitOptionsLike",
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
    "registered_integrators",
]
