"""The colliders' kernels: the response after a step, the rigid motion of moving colliders, the query.

Kept apart from :class:`~pliant.collision.Colliders` (the Python side: parameters, arrays, launches) so
that each file stays short; both sit above :mod:`._collider_sdf`, whose functions the kernels call.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ._collider_sdf import collider_contact, collider_sdf, surface_velocity
from .kinds import AUX_DIRECTION, AUX_POINT, CONTACT_KINDS

_KINDS = tuple(CONTACT_KINDS.values())


@wp.kernel
def collider_response(
    first: int,
    end: int,
    # Colliders:
    kind: wp.array(dtype=wp.int32),
    pos: wp.array(dtype=Any),
    aux: wp.array(dtype=Any),
    rot: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    mesh: wp.array(dtype=wp.uint64),
    centre: wp.array(dtype=Any),
    vel: wp.array(dtype=Any),
    omega: wp.array(dtype=Any),
    friction: wp.array(dtype=Any),
    restitution: wp.array(dtype=Any),
    kappa: wp.array(dtype=Any),
    damping: wp.array(dtype=Any),
    law: int,
    stick_velocity: Any,
    dt: Any,
    step_dt: Any,
    # Model:
    particle_inv_mass: wp.array(dtype=Any),
    particle_radius: wp.array(dtype=Any),
    # State in:
    x_start: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    # Out:
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    """Colliders ``first`` to ``end`` − 1 in turn (:func:`collider_contact`): reads (x_in, v_in), writes
    every particle's (x_out, v_out), which may be the inputs (an in-place update).

    Recorded steps launch one collider at a time (``end`` = ``first`` + 1), which runs no loop: Warp's
    adjoint re-runs a dynamic loop's body with the values its variables hold after the loop, so x and v
    carried through the colliders in a loop would get a wrong gradient. The gradient-free step launches all
    colliders at once and carries x and v through them in registers.
    """
    i = wp.tid()
    x = x_in[i]
    v = v_in[i]
    x0 = x_start[i]
    r = particle_radius[i]
    eps = stick_velocity
    if particle_inv_mass[i] != r * type(r)(0.0):
        if end == first + 1:
            k = first
            vs = surface_velocity(vel[k], omega[k], centre[k], x)
            x, v = collider_contact(
                kind[k],
                pos[k],
                aux[k],
                rot[k],
                radius[k],
                mesh[k],
                vs,
                friction[k],
                restitution[k],
                kappa[k],
                damping[k],
                law,
                eps,
                dt,
                step_dt,
                r,
                x,
                v,
                x0,
            )
        else:
            for c in range(first, end):
                vs = surface_velocity(vel[c], omega[c], centre[c], x)
                x, v = collider_contact(
                    kind[c],
                    pos[c],
                    aux[c],
                    rot[c],
                    radius[c],
                    mesh[c],
                    vs,
                    friction[c],
                    restitution[c],
                    kappa[c],
                    damping[c],
                    law,
                    eps,
                    dt,
                    step_dt,
                    r,
                    x,
                    v,
                    x0,
                )
    x_out[i] = x
    v_out[i] = v


@wp.func
def _rotation(w: Any, h: Any):
    """exp([ω]× h): the rotation by the angle |ω| h about ω (Rodrigues)."""
    eye = wp.identity(n=3, dtype=type(h))
    angle = wp.length(w) * h
    if angle == h * type(h)(0.0):
        return eye
    u = wp.normalize(w)
    K = wp.skew(u)
    return eye + wp.sin(angle) * K + (type(h)(1.0) - wp.cos(angle)) * (K * K)


@wp.kernel
def _advance(
    kind: wp.array(dtype=wp.int32),
    vel: wp.array(dtype=Any),
    omega: wp.array(dtype=Any),
    h: Any,
    pos_io: wp.array(dtype=Any),
    aux_io: wp.array(dtype=Any),
    rot_io: wp.array(dtype=Any),
    centre_io: wp.array(dtype=Any),
):
    """Move each collider rigidly over h [s]: its centre by v h, its geometry rotated by ω h about it."""
    c = wp.tid()
    R = _rotation(omega[c], h)
    c0 = centre_io[c]
    c1 = c0 + h * vel[c]
    pos_io[c] = c1 + R * (pos_io[c] - c0)
    rot_io[c] = R * rot_io[c]
    for k in range(wp.static(len(_KINDS))):
        if kind[c] == wp.static(_KINDS[k].code):
            if wp.static(_KINDS[k].aux_motion == AUX_POINT):
                aux_io[c] = c1 + R * (aux_io[c] - c0)
            if wp.static(_KINDS[k].aux_motion == AUX_DIRECTION):
                aux_io[c] = R * aux_io[c]
    centre_io[c] = c1


@wp.func
def rigid_displacement(vel: Any, omega: Any, centre: Any, h: Any, p: Any):
    """How far [m] a rigidly moving collider carries its material point at p over h [s]: the same motion as
    :func:`_advance` (centre by v h, rotation exp(ω h) about it), c + v h + R (p − c) − p."""
    R = _rotation(omega, h)
    return centre + h * vel + R * (p - centre) - p


@wp.kernel
def _collider_query(
    kind: wp.array(dtype=wp.int32),
    pos: wp.array(dtype=Any),
    aux: wp.array(dtype=Any),
    rot: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    mesh: wp.array(dtype=wp.uint64),
    x_in: wp.array(dtype=Any),
    phi_out: wp.array(dtype=Any),
    n_out: wp.array(dtype=Any),
):
    i = wp.tid()
    best = radius[0] * type(radius[0])(0.0) + type(radius[0])(1.0e30)
    for c in range(kind.shape[0]):
        phi, n, H = collider_sdf(kind[c], pos[c], aux[c], rot[c], radius[c], mesh[c], x_in[i])
        if phi < best:
            best = phi
            n_out[i] = n
    phi_out[i] = best
