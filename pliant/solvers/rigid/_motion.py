"""A rigid body's free Newton–Euler step from its particles, shared by RigidBodySolver's two paths."""

from __future__ import annotations

from typing import Any

import warp as wp

from ...constraints import polar_rotation


@wp.func
def skew(a: Any):
    """[a]× with [a]× b = a × b."""
    z = type(a[0])(0.0)
    return type(wp.outer(a, a))(z, -a[2], a[1], a[2], z, -a[0], -a[1], a[0], z)


@wp.func
def gyroscopic_step(I: Any, w: Any, dt: Any):
    """One Newton step on I(ω' − ω) + Δt ω' × Iω' = 0 (implicit gyroscopic term, Catto 2015), body frame."""
    f = dt * wp.cross(w, I * w)
    J = I + dt * (skew(w) * I - skew(I * w))
    return w - wp.inverse(J) * f


@wp.func
def advance_rotation(q: Any, w: Any, dt: Any):
    """R of q ← normalize(q + ½Δt [ω, 0] q) for the world angular velocity ω [rad/s]."""
    half = type(dt)(0.5) * dt
    dq = type(q)(w[0], w[1], w[2], dt * type(dt)(0.0)) * q
    q = wp.normalize(
        type(q)(q[0] + half * dq[0], q[1] + half * dq[1], q[2] + half * dq[2], q[3] + half * dq[3])
    )
    return wp.quat_to_matrix(q)


@wp.func
def free_motion(
    a0: int,
    a1: int,
    members: wp.array(dtype=wp.int32),
    rest: wp.array(dtype=Any),
    cb: Any,
    Ib: Any,
    mass: wp.array(dtype=Any),
    gravity: Any,
    f_ext: wp.array(dtype=Any),
    dt: Any,
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
):
    """The free step of the body of members [a0, a1) (rest positions ``rest``, rest centre ``cb`` [m], body
    inertia ``Ib`` [kg m²]): returns its mass M [kg], centre c [m], orientation q, velocity v [m/s], angular
    velocity ω [rad/s] after the step's forces, and the free end rotation R'."""
    zero = dt * type(dt)(0.0)
    # Body state from the particles: centre, rotation (polar part of A, exact for a rigid arrangement),
    # linear momentum, angular momentum, and the forces.
    M = zero
    c = gravity * zero
    p = gravity * zero
    F = gravity * zero
    for k in range(a0, a1):
        i = members[k]
        M = M + mass[i]
        c = c + mass[i] * x_in[i]
        p = p + mass[i] * v_in[i]
        F = F + mass[i] * gravity + f_ext[i]
    c = c / M
    A = wp.outer(c, c) * zero
    L = c * zero
    tau = c * zero
    for k in range(a0, a1):
        i = members[k]
        r = x_in[i] - c
        A = A + mass[i] * wp.outer(r, rest[k] - cb)
        L = L + mass[i] * wp.cross(r, v_in[i])
        tau = tau + wp.cross(r, f_ext[i])
    R = polar_rotation(A)
    # Newton: symplectic Euler for the centre.
    v = p / M + dt * F / M
    # Euler: ω from L = R I_b Rᵀ ω, torque impulse, implicit gyroscopic term in the body frame.
    wb = wp.inverse(Ib) * (wp.transpose(R) * L)
    wb = wb + dt * (wp.inverse(Ib) * (wp.transpose(R) * tau))
    wb = gyroscopic_step(Ib, wb, dt)
    w = R * wb
    # Orientation: q ← normalize(q + ½Δt [ω, 0] q).
    q = wp.quat_from_matrix(R)
    return M, c, q, v, w, advance_rotation(q, w, dt)
