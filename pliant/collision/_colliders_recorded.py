"""Collider contact for recorded (``wp.Tape``) steps, out of place and one collider per launch.

A Warp module of its own, like :mod:`._ground_recorded`: building a module runs Warp's read-then-write
analysis on all of its kernels, and the in-place response of the gradient-free path would be flagged.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ._collider_sdf import collider_contact


@wp.kernel
def collider_response_out(
    c: int,
    kind: wp.array(dtype=wp.int32),
    pos: wp.array(dtype=Any),
    aux: wp.array(dtype=Any),
    rot: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    mesh: wp.array(dtype=wp.uint64),
    friction: wp.array(dtype=Any),
    restitution: wp.array(dtype=Any),
    particle_inv_mass: wp.array(dtype=Any),
    particle_radius: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    """Collider ``c``'s response (:func:`collider_contact`): reads (x_in, v_in), writes (x_out, v_out)."""
    i = wp.tid()
    zero = particle_radius[i] * type(particle_radius[i])(0.0)
    if particle_inv_mass[i] == zero:
        x_out[i] = x_in[i]
        v_out[i] = v_in[i]
    else:
        x, v = collider_contact(
            kind[c],
            pos[c],
            aux[c],
            rot[c],
            radius[c],
            mesh[c],
            friction[c],
            restitution[c],
            particle_radius[i],
            x_in[i],
            v_in[i],
        )
        x_out[i] = x
        v_out[i] = v
