"""The ground plane as a penalty energy: implicit (Newton) steps see contact instead of crushing into it."""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from .._warp import launch
from ..model import Model
from ._base import ModalEnergy


@wp.kernel
def _ground_penalty(
    mass: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    height: Any,
    kappa: Any,
    x_in: wp.array(dtype=Any),
    mode: int,
    scale: Any,
    slots_in: wp.array(dtype=wp.int32),
    value_out: wp.array(dtype=Any),
    grad_out: wp.array(dtype=Any),
    hess_out: wp.array(dtype=Any),
):
    # E_i = ½ κ m_i max(0, h + r_i − y_i)²: κ [1/s²] scales with the mass, so the resting penetration g/κ
    # does not depend on the mesh resolution.
    i = wp.tid()
    if inv_mass[i] == type(height)(0.0):
        return
    d = height + radius[i] - x_in[i][1]
    if d <= type(height)(0.0):
        return
    k = kappa * mass[i]
    if mode == 0:
        wp.atomic_add(value_out, 0, type(k)(0.5) * k * d * d)
    elif mode == 1:
        g = x_in[i] * type(k)(0.0)
        g[1] = -k * d
        wp.atomic_add(grad_out, i, g)
    else:
        h = wp.outer(x_in[i], x_in[i]) * type(k)(0.0)
        h[1, 1] = scale * k
        wp.atomic_add(hess_out, slots_in[i], h)


class GroundPenalty(ModalEnergy):
    """E = Σ ½ κ m_i max(0, h + r_i − y_i)² [J] for the model's ground plane y = h.

    Implicit integrators minimise the incremental potential with this term, so a body landing in one large
    step is stopped by the ground inside Newton rather than pushed through it and flattened by the
    post-step projection (which would invert elements). ``ForceSolver`` adds it automatically for implicit
    integrators when the model has a ground; the post-step response then applies Coulomb friction for the
    penalty's impulse instead of projecting. Add it to an explicit integrator's energies for the same
    contact physics (its force acts inside the step; stable for Δt < 2/√κ, 2 ms at the default κ).

    Args:
        stiffness: κ [1/s²]; the resting penetration under gravity is g/κ (1e6 → 10 µm).
    """

    hessian_changes_each_step = True

    def __init__(self, stiffness: float = 1.0e6) -> None:
        if stiffness <= 0:
            raise ValueError(f"GroundPenalty stiffness must be > 0 1/s², got {stiffness}")
        self.stiffness = float(stiffness)

    def _launch_mode(self, model, x, mode, scale, project, outputs) -> None:
        """Penalty value, gradient, or Hessian blocks scale·κ m_i e_y e_yᵀ (PSD; ``project`` unused)."""
        if model.ground is None:
            return
        launch(
            _ground_penalty,
            model.particle_count,
            [
                model.particle_mass,
                model.particle_inv_mass,
                model.particle_radius,
                model.s(model.ground.height),
                model.s(self.stiffness),
                x,
                mode,
                model.s(scale),
                *outputs,
            ],
            device=model.device,
        )

    def hessian_pattern(self, model: Model) -> tuple[np.ndarray, np.ndarray]:
        """One diagonal block per particle, in particle order."""
        i = np.arange(model.particle_count, dtype=np.int32)
        return i, i.copy()


@wp.kernel
def _damped_ground_implicit(
    mass: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    height: Any,
    kappa: Any,
    damping: Any,
    inv_dt: Any,
    x_ref: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    mode: int,
    scale: Any,
    slots_in: wp.array(dtype=wp.int32),
    value_out: wp.array(dtype=Any),
    grad_out: wp.array(dtype=Any),
    hess_out: wp.array(dtype=Any),
):
    # A particle in contact at the step's start (y⁰ below the surface): Ψ = ½ m (κ + b/h) s² with
    # s = max(κ d − b (y − y⁰)/h, 0)/(κ + b/h), so ∂Ψ/∂y = −m max(κ d − b v, 0), the clamped spring–damper
    # at v = (y − y⁰)/h (s > 0 only below the surface: the force never pulls). Others: the spring alone.
    i = wp.tid()
    zero = type(height)(0.0)
    if inv_mass[i] == zero:
        return
    floor = height + radius[i]
    y = x_in[i][1]
    s = floor - y
    k = kappa
    if x_ref[i][1] < floor:
        k = kappa + damping * inv_dt
        s = (kappa * (floor - y) - damping * (y - x_ref[i][1]) * inv_dt) / k
    if s <= zero:
        return
    k = k * mass[i]
    if mode == 0:
        wp.atomic_add(value_out, 0, type(k)(0.5) * k * s * s)
    elif mode == 1:
        g = x_in[i] * zero
        g[1] = -k * s
        wp.atomic_add(grad_out, i, g)
    else:
        h = wp.outer(x_in[i], x_in[i]) * zero
        h[1, 1] = scale * k
        wp.atomic_add(hess_out, slots_in[i], h)


@wp.kernel
def _damped_ground_force(
    mass: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    height: Any,
    kappa: Any,
    damping: Any,
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    f_out: wp.array(dtype=Any),
):
    # The explicit force m max(κ d − b v_n, 0) e_y of a particle d below the surface.
    i = wp.tid()
    zero = type(height)(0.0)
    d = height + radius[i] - x_in[i][1]
    if inv_mass[i] == zero or d <= zero:
        return
    f = x_in[i] * zero
    f[1] = mass[i] * wp.max(kappa * d - damping * v_in[i][1], zero)
    wp.atomic_add(f_out, i, f)


class DampedGroundPenalty(GroundPenalty):
    """Compliant ground contact with a damper: the force m max(κ d − b v_n, 0) [N] on a particle d [m]
    below the ground plane (spring κ [1/s²], damper b [1/s]; MuJoCo's solref (τ, ζ): κ = 1/(τζ)²,
    b = 2/τ).

    Explicit integrators call :meth:`force`. Implicit ones call :meth:`begin_step` and minimise, for a
    particle in contact at the start of the step, ½ m (κ + b/h) s², s = max(κ d − b (y − y⁰)/h, 0)/(κ + b/h)
    (a convex quadratic whose gradient is that force at v = (y − y⁰)/h: backward Euler on the clamped
    spring–damper), and the spring alone for the others (the damper starts the step after contact, so a
    landing particle is not braked above the surface). At rest it sits g/κ deep, as without a damper.

    Args:
        stiffness: κ [1/s²] > 0.
        damping: b [1/s] >= 0 (2ζ√κ for damping ratio ζ).
    """

    dissipative = True

    def __init__(self, stiffness: float = 1.0e6, damping: float = 0.0) -> None:
        super().__init__(stiffness)
        if not damping >= 0:
            raise ValueError(f"DampedGroundPenalty damping must be >= 0 1/s, got {damping}")
        self.damping = float(damping)
        self._x_ref: wp.array | None = None
        self._inv_dt = 0.0

    def _head(self, model: Model) -> list:
        g = model.ground
        assert g is not None  # bound only to a model with a ground
        return [
            model.particle_mass,
            model.particle_inv_mass,
            model.particle_radius,
            model.s(g.height),
            model.s(self.stiffness),
            model.s(self.damping),
        ]

    def force(self, model: Model, x: wp.array, v: wp.array, out: wp.array) -> None:
        """Add the clamped spring–damper forces [N] at (x, v) into ``out``."""
        if model.ground is not None:
            launch(
                _damped_ground_force,
                model.particle_count,
                [*self._head(model), x, v, out],
                device=model.device,
            )

    def begin_step(self, model: Model, x: wp.array, v: wp.array, dt: float) -> None:
        """Freeze the positions x⁰ [m] at the start of the step of ``dt`` [s] (which particles the damper
        acts on, and its reference)."""
        if model.requires_grad:
            self._x_ref = x  # differentiable: the step's own input array, which the step never overwrites
        else:
            if (
                self._x_ref is None
                or self._x_ref.shape[0] != model.particle_count
                or self._x_ref.requires_grad
            ):
                self._x_ref = wp.zeros(model.particle_count, dtype=model.vec3, device=model.device)
            wp.copy(self._x_ref, x)
        self._inv_dt = 1.0 / dt

    def _launch_mode(self, model, x, mode, scale, project, outputs) -> None:
        """Ψ of the current step, its gradient or its diagonal Hessian blocks (PSD; ``project`` unused)."""
        if model.ground is None:
            return
        if self._x_ref is None:
            raise RuntimeError("DampedGroundPenalty.begin_step must be called before the implicit potential")
        launch(
            _damped_ground_implicit,
            model.particle_count,
            [*self._head(model), model.s(self._inv_dt), self._x_ref, x, mode, model.s(scale), *outputs],
            device=model.device,
        )


def ground_penalty(stiffness: float, damping: float = 0.0) -> GroundPenalty:
    """The ground's energy term for implicit steps: :class:`GroundPenalty` κ [1/s²], or with a damper
    b [1/s] > 0 :class:`DampedGroundPenalty`."""
    return DampedGroundPenalty(stiffness, damping) if damping > 0 else GroundPenalty(stiffness)
