"""The ground plane as a penalty energy: implicit (Newton) steps see contact instead of crushing into it."""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from ..model import Model
from ._base import Energy


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
        grad_out[i] = grad_out[i] + g
    else:
        h = wp.outer(x_in[i], x_in[i]) * type(k)(0.0)
        h[1, 1] = scale * k
        hess_out[i] = hess_out[i] + h


class GroundPenalty(Energy):
    """E = Σ ½ κ m_i max(0, h + r_i − y_i)² [J] for the model's ground plane y = h.

    Implicit integrators minimise the incremental potential with this term, so a body landing in one large
    step is stopped by the ground inside Newton rather than pushed through it and flattened by the
    post-step projection (which would invert elements). ``ForceSolver`` adds it automatically for implicit
    integrators when the model has a ground; the post-step response still applies friction and restitution.

    Args:
        stiffness: κ [1/s²]; the resting penetration under gravity is g/κ (1e5 → 0.1 mm).
    """

    def __init__(self, stiffness: float = 1.0e5) -> None:
        if stiffness <= 0:
            raise ValueError(f"GroundPenalty stiffness must be > 0 1/s², got {stiffness}")
        self.stiffness = float(stiffness)
        self._dummy: dict[str, Any] = {}

    def _launch(self, model: Model, x: wp.array, mode: int, out: wp.array, scale: float = 1.0) -> None:
        if model.ground is None:
            return
        key = (model.device, model.dtype)
        if key not in self._dummy:
            self._dummy[key] = (
                wp.zeros(1, dtype=model.scalar, device=model.device),
                wp.zeros(1, dtype=model.vec3, device=model.device),
                wp.zeros(1, dtype=model.mat33, device=model.device),
            )
        ds, dv, dm = self._dummy[key]
        wp.launch(
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
                out if mode == 0 else ds,
                out if mode == 1 else dv,
                out if mode == 2 else dm,
            ],
            device=model.device,
        )

    def value(self, model: Model, x: wp.array, out: wp.array) -> None:
        """Add the penalty energy [J] into ``out[0]``."""
        self._launch(model, x, 0, out)

    def gradient(self, model: Model, x: wp.array, out: wp.array) -> None:
        """Add ∂E/∂x [N] into ``out``."""
        self._launch(model, x, 1, out)

    def hessian_pattern(self, model: Model) -> tuple[np.ndarray, np.ndarray]:
        """One diagonal block per particle, in particle order."""
        i = np.arange(model.particle_count, dtype=np.int32)
        return i, i.copy()

    def hessian(self, model, x, slots, values, *, project_psd: bool = True, scale: float = 1.0) -> None:
        """Add scale·κ m_i e_y e_yᵀ for penetrating particles (PSD) into ``values[slots[i]]``."""
        if model.ground is None:
            return
        self._launch_hessian(model, x, slots, values, scale)

    def _launch_hessian(self, model, x, slots, values, scale) -> None:
        # Blocks are written in particle order: scatter through the slots into the matrix values.
        buf = getattr(self, "_hbuf", None)
        if buf is None or buf.shape[0] != model.particle_count or buf.dtype != model.mat33:
            buf = wp.zeros(model.particle_count, dtype=model.mat33, device=model.device)
            self._hbuf = buf
        buf.zero_()
        self._launch(model, x, 2, buf, scale)
        wp.launch(_scatter_blocks, model.particle_count, [slots, buf, values], device=model.device)


@wp.kernel
def _scatter_blocks(
    slots: wp.array(dtype=wp.int32), blocks: wp.array(dtype=Any), values: wp.array(dtype=Any)
):
    i = wp.tid()
    wp.atomic_add(values, slots[i], blocks[i])
