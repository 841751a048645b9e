"""Ground contact for recorded (``wp.Tape``) steps, out of place.

A Warp module of its own: building a module runs Warp's read-then-write analysis on all of its kernels,
and the in-place ground kernels of the gradient-free path (:mod:`._ground`) would be flagged although no
tape ever replays them.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ._ground import coulomb_ground, ground_velocity


@wp.kernel
def ground_contact_out(
    inv_mass: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    height: Any,
    coefficients: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    """:func:`ground_contact` out of place, for recorded (``wp.Tape``) steps: reads (x_in, v_in), writes
    (x_out, v_out); ``coefficients`` = [friction μ, restitution e] so that their gradients can be read.

    Differentiable almost everywhere: the contact set, the sign of the normal velocity and the stick/slip
    switch of Coulomb friction are piecewise, so at a switch the gradient is one-sided (a subgradient).
    """
    i = wp.tid()
    p = x_in[i]
    v = v_in[i]
    floor = height + radius[i]
    if inv_mass[i] != type(height)(0.0) and p[1] < floor:
        x_out[i] = type(p)(p[0], floor, p[2])
        v_out[i] = ground_velocity(v, coefficients[0], coefficients[1])
    else:
        x_out[i] = p
        v_out[i] = v


@wp.kernel
def ground_penalty_friction_out(
    inv_mass: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    height: Any,
    coefficients: wp.array(dtype=Any),
    kappa: Any,
    dt: Any,
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    """:func:`ground_penalty_friction` out of place, for recorded implicit steps: positions pass through,
    tangential speed drops by μ κ d Δt for particles at depth d > 0 (``coefficients`` = [μ, e]).

    A subgradient where a particle enters or leaves the contact set or friction switches stick/slip.
    """
    i = wp.tid()
    p = x_in[i]
    v = v_in[i]
    x_out[i] = p
    d = height + radius[i] - p[1]
    zero = type(height)(0.0)
    if inv_mass[i] != zero and d > zero:
        v_out[i] = coulomb_ground(v, kappa * d * dt, v[1], coefficients[0])
    else:
        v_out[i] = v
