"""Body-level contact for RigidBodySolver: sequential impulses over a body's particle contacts.

A rigid body's particles must not be pushed out of the ground or a collider one by one, as the deformable
solvers' post-step responses do: that bends the body, and the next step's polar decomposition turns the
bent shape back into a rigid pose with the wrong momentum (friction then acts on single particles, not on
the body's weight). Here each body, after its free Newton–Euler update, gathers the particles that would
end the step inside the ground (y < height + r) or a collider (φ < r, from
:func:`pliant.collision.collider_sdf`), and solves for the body's velocity change by projected
Gauss–Seidel over those contacts (Catto's sequential impulses, accumulated and clamped per contact):

* normal: λ_n ≥ 0 with the contact's normal velocity ≥ −e u_n⁻ (restitution on the approach speed u_n⁻ < 0,
  the free velocity at the contact, this step's gravity included as in the particle law), and ≥ 0 where
  the approach is slower than 2|g|Δt: a resting contact approaches at |g|Δt every step, and reflecting that
  would make a body hop and creep down a slope between hops;
* friction: :func:`pliant.collision.friction_velocity`, the project's one smoothed Coulomb law, in
  impulse form: a contact's trial tangential velocity ũ_t = u_t − k_t P (its own friction impulse P taken
  out, k_t the mean tangential response, :func:`tangential_response`) and its budget b = μ λ_n k_t, the
  velocity change the largest friction impulse μ λ_n makes. The new impulse is (ũ_t' − ũ_t)/k_t, at most
  μ λ_n: a body sliding on its weight decelerates by exactly μ g cos θ, one inside the cone stays put
  (creeping below the stick velocity ε_v).

Then the penetration the corrected velocities leave at the end of the step (linearised,
pen − Δt (u_n' − u_n⁻)) is removed by a normal-only pseudo-velocity pass (split impulse) that moves the
pose but adds no velocity. The caller re-integrates the pose from the corrected velocities and places the
particles rigidly.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ...collision import collider_sdf, friction_velocity


@wp.func
def contact_response(inv_mass: Any, inv_inertia: Any, r: Any, d: Any):
    """K d [m/s]: the velocity change at lever r [m] of a body (1/M [1/kg], world I⁻¹ [1/(kg m²)]) for an
    impulse d [N s] there."""
    return inv_mass * d + wp.cross(inv_inertia * wp.cross(r, d), r)


@wp.func
def tangential_response(inv_mass: Any, inv_inertia: Any, r: Any, n: Any):
    """k_t [1/kg]: the mean of K's tangential block, ½ (tr K − nᵀ K n), at lever r [m] with normal n.

    Friction takes the contact's response to a tangential impulse as k_t I. Gauss–Seidel's fixed point
    then has each contact's tangential velocity u_t' and impulse P opposite, with u_t' the smoothed law's
    outcome for the trial velocity u_t' − k_t P and |P| ≤ μ λ_n: Coulomb exactly, whatever k_t; with the
    full (anisotropic) K instead, u_t' and P are not opposite, and a body in the cone creeps and yaws.
    k_t lies between K's tangential eigenvalues, so each update contracts.
    """
    zero = inv_mass * type(inv_mass)(0.0)
    one = type(inv_mass)(1.0)
    tr = zero
    for a in range(3):
        e = type(r)(zero, zero, zero)
        e[a] = one
        tr = tr + contact_response(inv_mass, inv_inertia, r, e)[a]
    return type(inv_mass)(0.5) * (tr - wp.dot(n, contact_response(inv_mass, inv_inertia, r, n)))


@wp.func
def add_contact(
    j: int,
    r: Any,
    n: Any,
    pen: Any,
    coef: Any,
    bounce_speed: Any,
    inv_mass: Any,
    inv_inertia: Any,
    v: Any,
    w: Any,
    c_r: wp.array(dtype=Any),
    c_n: wp.array(dtype=Any),
    c_coef: wp.array(dtype=Any),
    c_aux: wp.array(dtype=Any),
):
    """Store contact j: lever r [m], normal n, ``c_coef`` = (μ, ε_v [m/s], pen [m]) from ``coef`` =
    (μ, e, ε_v), ``c_aux`` = (target normal velocity [m/s], 1/k_n [kg], approach speed u_n⁻ [m/s]), with
    u_n⁻ the body's free velocity (v, ω) at the contact; returns j + 1."""
    zero = pen * type(pen)(0.0)
    un = wp.dot(n, v + wp.cross(w, r))
    target = zero
    if un < -bounce_speed:
        target = -coef[1] * un
    kn = wp.dot(n, contact_response(inv_mass, inv_inertia, r, n))
    c_r[j] = r
    c_n[j] = n
    c_coef[j] = type(r)(coef[0], coef[2], pen)
    c_aux[j] = type(r)(target, type(pen)(1.0) / kn, un)
    return j + 1


@wp.func
def gather_contacts(
    start: int,
    a0: int,
    a1: int,
    members: wp.array(dtype=wp.int32),
    rest: wp.array(dtype=Any),
    rest_center: Any,
    radius: wp.array(dtype=Any),
    center: Any,
    rotation: Any,
    ground: int,
    ground_height: Any,
    ground_coef: Any,
    bounce_speed: Any,
    col_count: int,
    col_kind: wp.array(dtype=wp.int32),
    col_pos: wp.array(dtype=Any),
    col_aux: wp.array(dtype=Any),
    col_rot: wp.array(dtype=Any),
    col_radius: wp.array(dtype=Any),
    col_mesh: wp.array(dtype=wp.uint64),
    col_coef: wp.array(dtype=Any),
    inv_mass: Any,
    inv_inertia: Any,
    v: Any,
    w: Any,
    c_r: wp.array(dtype=Any),
    c_n: wp.array(dtype=Any),
    c_coef: wp.array(dtype=Any),
    c_aux: wp.array(dtype=Any),
):
    """The body's contacts at its free end-of-step pose (member k at ``center`` + R (p̄_k − c̄)), stored
    from ``start`` on; returns the index after the last. ``ground_coef`` and ``col_coef`` are (μ, e, ε_v)."""
    j = start
    zero = ground_height * type(ground_height)(0.0)
    up = type(center)(zero, type(zero)(1.0), zero)
    for k in range(a0, a1):
        i = members[k]
        r = rotation * (rest[k] - rest_center)
        x = center + r
        if ground != 0:
            pen = ground_height + radius[i] - x[1]
            if pen > zero:
                j = add_contact(
                    j, r, up, pen, ground_coef, bounce_speed, inv_mass, inv_inertia,
                    v, w, c_r, c_n, c_coef, c_aux,
                )  # fmt: skip
        for s in range(col_count):
            phi, n, H = collider_sdf(
                col_kind[s], col_pos[s], col_aux[s], col_rot[s], col_radius[s], col_mesh[s], x
            )
            pen = radius[i] - phi
            if pen > zero:
                j = add_contact(
                    j, r, n, pen, col_coef[s], bounce_speed, inv_mass, inv_inertia,
                    v, w, c_r, c_n, c_coef, c_aux,
                )  # fmt: skip
    return j


@wp.func
def apply_impulse(inv_mass: Any, inv_inertia: Any, r: Any, P: Any, v: Any, w: Any):
    """(v, ω) after an impulse P [N s] at lever r [m]."""
    return v + inv_mass * P, w + inv_inertia * wp.cross(r, P)


@wp.func
def solve_velocities(
    start: int,
    end: int,
    iterations: int,
    inv_mass: Any,
    inv_inertia: Any,
    v: Any,
    w: Any,
    c_r: wp.array(dtype=Any),
    c_n: wp.array(dtype=Any),
    c_coef: wp.array(dtype=Any),
    c_aux: wp.array(dtype=Any),
    c_imp: wp.array(dtype=Any),
    c_lam: wp.array(dtype=Any),
):
    """Sequential impulses over contacts [start, end): per contact the normal impulse (accumulated λ_n ≥ 0
    towards the target normal velocity), then friction by the smoothed Coulomb law for the updated λ_n
    (module docstring); ``iterations`` sweeps. Returns the body's (v [m/s], ω [rad/s])."""
    zero = inv_mass * type(inv_mass)(0.0)
    for j in range(start, end):
        c_lam[j] = zero
        c_imp[j] = v * zero
    for it in range(iterations):
        for jj in range(start, end):
            # Sweeps alternate direction (symmetric Gauss–Seidel): a one-way order favours the first
            # contacts, and a symmetric landing would come out lopsided.
            j = jj
            if it % 2 == 1:
                j = start + end - 1 - jj
            r = c_r[j]
            n = c_n[j]
            coef = c_coef[j]
            aux = c_aux[j]
            lam = c_lam[j]
            lam_new = wp.max(lam + (aux[0] - wp.dot(n, v + wp.cross(w, r))) * aux[1], zero)
            v, w = apply_impulse(inv_mass, inv_inertia, r, (lam_new - lam) * n, v, w)
            c_lam[j] = lam_new
            # Friction: the trial tangential velocity is this contact's with its own impulse P taken out,
            # through the isotropic k_t (the fixed point is then exact smoothed Coulomb: module docstring).
            u = v + wp.cross(w, r)
            P = c_imp[j]
            kt = tangential_response(inv_mass, inv_inertia, r, n)
            trial = (u - wp.dot(u, n) * n) - kt * P
            P_new = (friction_velocity(trial, coef[0] * lam_new * kt, coef[1]) - trial) / kt
            v, w = apply_impulse(inv_mass, inv_inertia, r, P_new - P, v, w)
            c_imp[j] = P_new
    return v, w


@wp.func
def solve_positions(
    start: int,
    end: int,
    iterations: int,
    dt: Any,
    inv_mass: Any,
    inv_inertia: Any,
    v: Any,
    w: Any,
    c_r: wp.array(dtype=Any),
    c_n: wp.array(dtype=Any),
    c_coef: wp.array(dtype=Any),
    c_aux: wp.array(dtype=Any),
    c_lam: wp.array(dtype=Any),
):
    """Split impulse: pseudo-velocities (v_p [m/s], ω_p [rad/s]) that remove, over one step, the penetration
    pen − Δt (u_n' − u_n⁻) that the corrected velocities (v, ω) leave (normal only, λ_p ≥ 0)."""
    zero = inv_mass * type(inv_mass)(0.0)
    vp = v * zero
    wq = w * zero
    for j in range(start, end):
        r = c_r[j]
        n = c_n[j]
        aux = c_aux[j]
        left = c_coef[j][2] - dt * (wp.dot(n, v + wp.cross(w, r)) - aux[2])
        c_lam[j] = zero
        c_aux[j] = type(r)(wp.max(left, zero) / dt, aux[1], aux[2])
    for _it in range(iterations):
        for j in range(start, end):
            r = c_r[j]
            n = c_n[j]
            aux = c_aux[j]
            lam = c_lam[j]
            lam_new = wp.max(lam + (aux[0] - wp.dot(n, vp + wp.cross(wq, r))) * aux[1], zero)
            vp, wq = apply_impulse(inv_mass, inv_inertia, r, (lam_new - lam) * n, vp, wq)
            c_lam[j] = lam_new
    return vp, wq
