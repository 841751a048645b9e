"""What every force-based solver does after integrating: kinematic targets, ground, contact handlers."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import warp as wp

from .._warp import launch
from ..collision import ground_contact, ground_penalty_friction
from ..model import Control, Model, State


@wp.kernel
def apply_kinematic(
    indices: wp.array(dtype=wp.int32),
    targets: wp.array(dtype=Any),
    inv_dt: Any,
    x_in: wp.array(dtype=Any),
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    """Put kinematic particles on their targets, with the velocity that got them there."""
    k = wp.tid()
    i = indices[k]
    x_out[i] = targets[k]
    v_out[i] = (targets[k] - x_in[i]) * inv_dt


@wp.func
def drag_force(target: Any, stiffness: Any, max_force: Any, x: Any):
    """The drag handle's force [N]: a zero-length spring k (target − x) from the particle to the cursor,
    its magnitude capped at ``max_force`` [N] (beyond |target − x| = max_force / k it pulls with max_force:
    the force of the energy k r²/2 inside that radius r, max_force (|d| − r/2) outside)."""
    f = stiffness * (target - x)
    n = wp.length(f)
    if n > max_force:
        f = f * (max_force / n)
    return f


@wp.func
def drag_hessian(target: Any, stiffness: Any, max_force: Any, x: Any):
    """The Hessian [N/m] of the capped drag energy (``drag_force``'s): k I inside the radius, and outside
    (max_force / |d|)(I − n nᵀ), the capped spring's transverse stiffness (positive semi-definite)."""
    d = x - target
    dist = wp.length(d)
    eye = wp.identity(n=3, dtype=type(stiffness))
    if stiffness * dist <= max_force:
        return stiffness * eye
    u = d / dist
    return (max_force / dist) * (eye - wp.outer(u, u))


@wp.kernel
def add_drag_force(
    index: int,
    target: Any,
    stiffness: Any,
    max_force: Any,
    x_in: wp.array(dtype=Any),
    f_io: wp.array(dtype=Any),
):
    """The drag handle (pulls without a jump, with a bounded force), added to the force of the particle it
    holds."""
    f_io[index] = f_io[index] + drag_force(target, stiffness, max_force, x_in[index])


def finish_step(
    model: Model,
    control: Control | None,
    state_in: State,
    state_out: State,
    dt: float,
    *,
    contact: bool,
    collisions: Sequence[Any] = (),
    ground_penalty: float | None = None,
) -> None:
    """Kinematic targets, then the ground response (when ``contact``), then each contact handler.

    ``ground_penalty``: κ [1/s²] of a :class:`~pliant.energies.GroundPenalty` the step already minimised;
    the ground response is then friction for the penalty's impulse instead of a projection.
    """
    m = model
    if control is not None and control.kinematic_indices.shape[0]:
        launch(
            apply_kinematic,
            control.kinematic_indices.shape[0],
            [
                control.kinematic_indices,
                control.kinematic_targets,
                m.s(1.0 / dt),
                state_in.particle_q,
                state_out.particle_q,
                state_out.particle_qd,
            ],
            device=m.device,
        )
    if contact and m.ground is not None and ground_penalty is not None:
        g = m.ground
        launch(
            ground_penalty_friction,
            m.particle_count,
            [
                m.particle_inv_mass,
                m.particle_radius,
                m.s(g.height),
                m.s(g.friction),
                m.s(ground_penalty),
                m.s(dt),
                state_out.particle_q,
                state_out.particle_qd,
            ],
            device=m.device,
        )
    elif contact and m.ground is not None:
        g = m.ground
        launch(
            ground_contact,
            m.particle_count,
            [
                m.particle_inv_mass,
                m.particle_radius,
                m.s(g.height),
                m.s(g.friction),
                m.s(g.restitution),
                state_out.particle_q,
                state_out.particle_qd,
            ],
            device=m.device,
        )
    for c in collisions:
        c.apply(m, state_in, state_out, dt)


def check_collisions(collisions: Sequence[Any]) -> list[Any]:
    """The handlers as a list, each checked for ``apply(model, state_in, state_out, dt)``."""
    out = list(collisions)
    for c in out:
        if not callable(getattr(c, "apply", None)):
            raise TypeError(
                f"collisions must have apply(model, state_in, state_out, dt), got {type(c).__name__}"
            )
    return out
