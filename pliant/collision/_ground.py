"""Ground-plane contact as a velocity-level response with Coulomb friction and restitution."""

from __future__ import annotations

from typing import Any

import warp as wp


@wp.func
def coulomb_ground(v: Any, dvn: Any, vn_new: Any, friction: Any):
    """v with normal component vn_new and its tangential part slowed by μ·dvn (stopped if that is more).

    Coulomb: the tangential impulse is bounded by μ times the normal one, so a block sliding on the ground
    decelerates by exactly μg and stops after v²/(2μg).
    """
    zero = friction * type(friction)(0.0)
    speed_t = wp.length(type(v)(v[0], zero, v[2]))
    scale = zero
    if speed_t > zero:
        scale = wp.max(speed_t - friction * dvn, zero) / speed_t
    return type(v)(v[0] * scale, vn_new, v[2] * scale)


@wp.func
def ground_velocity(v: Any, friction: Any, restitution: Any):
    """Velocity after hitting the ground: normal part reflected (×e) if approaching, Coulomb friction."""
    zero = friction * type(friction)(0.0)
    vn = v[1]
    vn_new = wp.max(vn, zero)
    if vn < zero:
        vn_new = -restitution * vn
    return coulomb_ground(v, vn_new - vn, vn_new, friction)


@wp.kernel
def ground_contact(
    inv_mass: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    height: Any,
    friction: Any,
    restitution: Any,
    x_io: wp.array(dtype=Any),
    v_io: wp.array(dtype=Any),
):
    """Push particles above y = height + r, reflect the normal velocity (×e), Coulomb friction on v_t."""
    i = wp.tid()
    if inv_mass[i] == type(height)(0.0):
        return
    p = x_io[i]
    floor = height + radius[i]
    if p[1] >= floor:
        return
    v_io[i] = ground_velocity(v_io[i], friction, restitution)
    x_io[i] = type(p)(p[0], floor, p[2])


@wp.kernel
def ground_penalty_friction(
    inv_mass: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    height: Any,
    friction: Any,
    kappa: Any,
    dt: Any,
    x_io: wp.array(dtype=Any),
    v_io: wp.array(dtype=Any),
):
    """Coulomb friction for the normal impulse a ground penalty κ m d gave over the step (implicit steps).

    Inside the incremental potential the penalty holds a resting particle at the depth d = g/κ where it
    balances the weight; projecting it back to y = height + r after every step (``ground_contact``) would
    undo that equilibrium and leave Newton a residual of h·g per step. So particles keep their position
    and the normal velocity the potential gave them, and their tangential speed drops by μ κ d Δt (the
    impulse bound). Even a particle that went deep is not moved: moving one vertex of an element after the
    step's inversion-safe minimisation can invert the element; the penalty pushes it out in the next step.
    """
    i = wp.tid()
    if inv_mass[i] == type(height)(0.0):
        return
    p = x_io[i]
    d = height + radius[i] - p[1]
    zero = type(height)(0.0)
    if d <= zero:
        return
    v = v_io[i]
    v_io[i] = coulomb_ground(v, kappa * d * dt, v[1], friction)
