"""Air drag on every particle: F = −c (v − w) − c₂ |v − w| (v − w), a dissipative term."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import warp as wp

from .._warp import launch
from ..model import Model
from ._base import ModalEnergy


@wp.func
def air_drag_force(v: Any, wind: Any, c: Any, c2: Any):
    """F = −(c + c₂|u|) u with u = v − w the velocity relative to the air [N]."""
    u = v - wind
    return -(c + c2 * wp.length(u)) * u


@wp.kernel
def _air_force(
    particle_inv_mass: wp.array(dtype=Any),
    wind: Any,
    c: Any,
    c2: Any,
    v_in: wp.array(dtype=Any),
    f_out: wp.array(dtype=Any),
):
    i = wp.tid()
    if particle_inv_mass[i] != c * type(c)(0.0):
        wp.atomic_add(f_out, i, air_drag_force(v_in[i], wind, c, c2))


@wp.kernel
def _air_implicit(
    particle_inv_mass: wp.array(dtype=Any),
    wind: Any,
    c: Any,
    c2: Any,
    speed: wp.array(dtype=Any),
    x_ref: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    inv_dt: Any,
    mode: int,
    scale: Any,
    slots_in: wp.array(dtype=wp.int32),
    value_out: wp.array(dtype=Any),
    grad_out: wp.array(dtype=Any),
    hess_out: wp.array(dtype=Any),
):
    # R(x) = (c + c₂|uⁿ|)/(2h) |x − xⁿ − h w|²: h²∇R = h(c + c₂|uⁿ|)(v − w) at v = (x − xⁿ)/h, i.e. the drag
    # force with the quadratic coefficient frozen at the step's start (a linearly implicit drag).
    i = wp.tid()
    zero = c * type(c)(0.0)
    if particle_inv_mass[i] == zero:
        return
    g = (c + c2 * speed[i]) * inv_dt
    r = x_in[i] - x_ref[i] - wind / inv_dt
    if mode == 0:
        wp.atomic_add(value_out, 0, type(c)(0.5) * g * wp.dot(r, r))
    elif mode == 1:
        wp.atomic_add(grad_out, i, g * r)
    else:
        wp.atomic_add(hess_out, slots_in[i], (scale * g) * wp.identity(n=3, dtype=type(c)))


@wp.kernel
def _air_begin(wind: Any, v_in: wp.array(dtype=Any), speed_out: wp.array(dtype=Any)):
    i = wp.tid()
    speed_out[i] = wp.length(v_in[i] - wind)


class AirDrag(ModalEnergy):
    """Air drag per particle: F = −c u − c₂|u| u with u = v − w (wind w) [N].

    Linear drag c [N s/m] models slow, viscous air; quadratic drag c₂ [N s²/m²] ≈ ½ ρ C_d A per particle
    models fast motion. Unlike the lecture's δ, which scales every velocity, drag acts per particle and
    does not depend on mass. Explicit integrators call :meth:`force`; implicit ones see the Rayleigh
    potential R = (c + c₂|uⁿ|)/(2h)|x − xⁿ − h w|² after :meth:`begin_step`.

    Args:
        coefficient: linear drag c [N s/m] per particle.
        quadratic: quadratic drag c₂ [N s²/m²] per particle.
        wind: air velocity w [m/s].
    """

    dissipative = True

    def __init__(
        self, coefficient: float = 0.0, *, quadratic: float = 0.0, wind: Sequence[float] = (0.0, 0.0, 0.0)
    ) -> None:
        if coefficient < 0 or quadratic < 0:
            raise ValueError(f"drag coefficients must be >= 0, got c={coefficient}, c2={quadratic}")
        w = np.asarray(wind, dtype=np.float64).reshape(-1)
        if w.shape != (3,):
            raise ValueError(f"wind must be 3 numbers [m/s], got {wind!r}")
        self.coefficient = float(coefficient)
        self.quadratic = float(quadratic)
        self.wind = w
        self._speed: wp.array | None = None
        self._x_ref: wp.array | None = None
        self._inv_dt = 0.0

    def _args(self, model: Model) -> list:
        return [
            model.particle_inv_mass,
            model.vec3(*self.wind),
            model.s(self.coefficient),
            model.s(self.quadratic),
        ]

    def force(self, model: Model, x: wp.array, v: wp.array, out: wp.array) -> None:
        """Add the drag forces [N] at velocities ``v`` into ``out``."""
        launch(_air_force, model.particle_count, [*self._args(model), v, out], device=model.device)

    def begin_step(self, model: Model, x: wp.array, v: wp.array, dt: float) -> None:
        """Freeze xⁿ and the relative speeds |uⁿ| for the implicit potential of this step of ``dt`` [s]."""
        if self._speed is None or self._x_ref is None or self._speed.shape[0] != model.particle_count:
            d = model.device
            self._speed = wp.zeros(model.particle_count, dtype=model.scalar, device=d)
            self._x_ref = wp.zeros(model.particle_count, dtype=model.vec3, device=d)
        wp.copy(self._x_ref, x)
        self._inv_dt = 1.0 / dt
        launch(
            _air_begin, model.particle_count, [model.vec3(*self.wind), v, self._speed], device=model.device
        )

    def _launch_mode(self, model, x, mode, scale, project, outputs) -> None:
        """R(x) of the current step; its Hessian is scale·(c + c₂|uⁿ|)/h·I (``project`` is unused)."""
        if self._speed is None:
            raise RuntimeError("AirDrag.begin_step must be called before the implicit potential is used")
        launch(
            _air_implicit,
            model.particle_count,
            [
                *self._args(model),
                self._speed,
                self._x_ref,
                x,
                model.s(self._inv_dt),
                mode,
                model.s(scale),
                *outputs,
            ],
            device=model.device,
        )

    def hessian_pattern(self, model: Model) -> tuple[np.ndarray, np.ndarray]:
        """One diagonal block per particle."""
        i = np.arange(model.particle_count, dtype=np.int32)
        return i, i.copy()
