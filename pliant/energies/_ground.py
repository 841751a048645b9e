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
