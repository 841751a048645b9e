"""Symplectic Euler (semi-implicit Euler), the lecture's mass-spring update with the sign corrected."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import warp as wp

from .._warp import launch
from ._base import Integrator, System, damping_rate_array, second_order_split
from ._problems import ODEProblem, SecondOrderODE


@wp.func
def symplectic_particle(w: Any, x: Any, v: Any, a: Any, dt: Any, delta: Any):
    """One particle's symplectic Euler step from its acceleration a [m/s²] (w = 1/m): v¹ = δ(v + Δt a),
    x¹ = x + Δt v¹; a particle of infinite mass (w = 0) keeps v and moves with it. Returns (x¹, v¹).
    Shared by these kernels and FastMassSpring's fused steps."""
    v1 = delta * (v + dt * a)
    if w == type(dt)(0.0):
        v1 = v
    return x + dt * v1, v1


@wp.kernel
def _symplectic_update(
    inv_mass: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    a_in: wp.array(dtype=Any),
    dt: Any,
    delta: Any,
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    i = wp.tid()
    x, v = symplectic_particle(inv_mass[i], x_in[i], v_in[i], a_in[i], dt, delta)
    v_out[i] = v
    x_out[i] = x


@wp.kernel
def _symplectic_update_rate(
    inv_mass: wp.array(dtype=Any),
    rate: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    a_in: wp.array(dtype=Any),
    dt: Any,
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    # Recorded steps: δ = exp(−cΔt) read from an array so that the tape carries ∂/∂c.
    i = wp.tid()
    x, v = symplectic_particle(inv_mass[i], x_in[i], v_in[i], a_in[i], dt, wp.exp(-rate[0] * dt))
    v_out[i] = v
    x_out[i] = x


class SymplecticEuler(Integrator):
    """v_{t+1} = δ(v_t + Δt F(x_t, v_t)/m);  x_{t+1} = x_t + Δt v_{t+1}.

    The lecture's slide writes x_{t+1} = x_t − Δt v_{t+1}; the sign is a slip (it would run time backwards
    in x). First order, symplectic: on the undamped oscillator it is stable for ωΔt < 2 and keeps the energy
    within O(Δt) of its start without drift.
    """

    order: ClassVar[int] = 1
    symplectic: ClassVar[bool] = True

    def step_ode(
        self, problem: ODEProblem | SecondOrderODE, t: float, dt: float, y: np.ndarray
    ) -> np.ndarray:
        """One step on y = concat(v, x) of a SecondOrderODE."""
        if not isinstance(problem, SecondOrderODE):
            raise TypeError("SymplecticEuler needs a SecondOrderODE (positions and velocities kept apart)")
        x, v = second_order_split(problem, y)
        v1 = v + dt * np.asarray(problem.acceleration(t, x, v))
        x1 = x + dt * v1
        return np.concatenate([v1, x1])

    def step_system(self, system: System, t, dt, x_in, v_in, x_out, v_out) -> None:
        """Fused velocity-then-position update on Warp arrays (δ applied as in the lecture)."""
        m = system.model
        (a,) = self._buffers(system, 1)
        system.acceleration(t, x_in, v_in, a)
        rate = damping_rate_array(system)
        if rate is not None:
            launch(
                _symplectic_update_rate,
                m.particle_count,
                [m.particle_inv_mass, rate, x_in, v_in, a, m.s(dt), x_out, v_out],
                device=m.device,
            )
            return
        launch(
            _symplectic_update,
            m.particle_count,
            [m.particle_inv_mass, x_in, v_in, a, m.s(dt), m.s(system.velocity_damping(dt)), x_out, v_out],
            device=m.device,
        )
