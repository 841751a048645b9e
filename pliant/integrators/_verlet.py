"""Velocity Verlet (leapfrog in its synchronised form): second order and symplectic."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from .._warp import grad_enabled
from ._base import Integrator, System, second_order_split
from ._explicit import is_damped, scale_velocity
from ._ops import lincomb
from ._problems import ODEProblem, SecondOrderODE


class VelocityVerlet(Integrator):
    """x₁ = x₀ + Δt v₀ + ½Δt² a₀;  v₁ = v₀ + ½Δt (a₀ + a₁).

    Second order and symplectic (for velocity-independent forces it is the Störmer–Verlet / leapfrog
    scheme, stable for ωΔt < 2 with the energy oscillating within O(Δt²) of its start, without drift).
    Velocity-dependent forces (dashpots) are evaluated at the predicted velocity v₀ + Δt a₀, which keeps
    the second order; the method is then no longer exactly symplectic, as the damped system is not either.
    Costs two force evaluations per step (none is reused, so that dissipation stays consistent).

    Reference: L. Verlet, Phys. Rev. 159, 98 (1967); Hairer, Lubich, Wanner, "Geometric numerical
    integration illustrated by the Störmer–Verlet method", Acta Numerica 12 (2003).

    Example::

        sol = pl.integrators.VelocityVerlet().solve(pl.integrators.harmonic_oscillator(), (1.0, 0.0),
                                                    t_end=10.0, dt=0.1)
    """

    order: ClassVar[int] = 2
    explicit: ClassVar[bool] = True
    symplectic: ClassVar[bool] = True

    def step_ode(
        self, problem: ODEProblem | SecondOrderODE, t: float, dt: float, y: np.ndarray
    ) -> np.ndarray:
        """One step on y = concat(v, x) of a SecondOrderODE."""
        if not isinstance(problem, SecondOrderODE):
            raise TypeError("VelocityVerlet needs a SecondOrderODE (positions and velocities kept apart)")
        x, v = second_order_split(problem, y)
        a0 = np.asarray(problem.acceleration(t, x, v))
        x1 = x + dt * v + 0.5 * dt * dt * a0
        a1 = np.asarray(problem.acceleration(t + dt, x1, v + dt * a0))
        v1 = v + 0.5 * dt * (a0 + a1)
        return np.concatenate([v1, x1])

    def step_system(self, system: System, t, dt, x_in, v_in, x_out, v_out) -> None:
        """Velocity Verlet on Warp arrays (δ applied to v₁ as in the lecture)."""
        m = system.model
        a0, a1, vp = self._buffers(system, 3)
        system.acceleration(t, x_in, v_in, a0)
        lincomb(m, x_out, x_in, [(dt, v_in), (0.5 * dt * dt, a0)])
        lincomb(m, vp, v_in, [(dt, a0)])
        system.acceleration(t + dt, x_out, vp, a1)
        damped = is_damped(system, dt)
        # Recorded steps scale δ out of place (a tape cannot replay v ← δv).
        v_end = self._buffers(system, 1)[0] if damped and grad_enabled(m) else v_out
        lincomb(m, v_end, v_in, [(0.5 * dt, a0), (0.5 * dt, a1)])
        scale_velocity(system, dt, v_end, v_out)


#: Leapfrog is the staggered form of the same method; pliant computes it synchronised.
Leapfrog = VelocityVerlet
