"""Body-to-body contact for RigidBodySolver: one Gauss–Seidel pass over every contact of every body.

Contact between two bodies couples their velocities, so the one-thread-per-body solve of
:mod:`pliant.solvers.rigid._contact` no longer applies. With more than one body the step is split in three:

1. per body (:func:`_free_bodies`), the free Newton–Euler update, kept in per-body arrays;
2. one thread (:func:`_coupled_contacts`) gathers each body's ground and collider contacts (the same as the
   per-body path, in the same order) and then the pair contacts: a broad phase over body pairs by bounding
   spheres at the free end poses (O(B²), fine for the few bodies a rigid scene has), and a narrow phase over
   the two bodies' particles, a contact where spheres of different bodies overlap (|x_a − x_b| < r_a + r_b)
   or are closer than min(r_a, r_b) to it (speculative: the pair may close the gap, not overlap).
   A pair contact acts at one point, the middle of the overlap moved back by the pair's mass-weighted free
   step (levers from the centres at which the step takes momentum, c × v and I ω), with the normal n along
   x_a − x_b, so its equal and opposite impulses keep the total momentum and angular momentum exactly.
   Then projected Gauss–Seidel (sequential impulses, the per-body path's normal, restitution and
   smoothed-Coulomb updates, with the relative velocity u_a − u_b, k_n and k_t summed over both bodies)
   over all contacts, sweeps alternating direction, and the split-impulse pass whose pseudo-velocities
   share the leftover overlap by inverse mass.
   Impulses start from zero every step (the solver keeps no state), and a stack's bottom contacts carry the
   weights above through several bodies, which the per-body sweep count leaves far from converged (three
   stacked cubes drift 3 mm over 2 s with 20, 0.15 mm with 100): the contacts of bodies that touch another
   body (only those, so that the others keep their per-body numbers) take ``pair_sweeps`` sweeps (100).
   Gauss–Seidel is sequential, so this is one thread: right for tens of bodies on a CPU; many bodies on a
   GPU would want graph colouring or Jacobi with averaging (not done);
3. per body (:func:`_place_bodies`), the pose from the corrected velocities, the particles placed rigidly.

A body whose contacts touch no other body gets exactly the per-body path's numbers (its contacts update only
its own velocity, in the same order); a body that touches nothing gets the free update.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ...collision import friction_velocity
from ._contact import apply_impulse, contact_response, gather_contacts, tangential_response
from ._motion import advance_rotation, free_motion


@wp.kernel
def _free_bodies(
    offsets: wp.array(dtype=wp.int32),
    members: wp.array(dtype=wp.int32),
    rest: wp.array(dtype=Any),
    rest_center: wp.array(dtype=Any),
    inertia_body: wp.array(dtype=Any),
    mass: wp.array(dtype=Any),
    gravity: Any,
    f_ext: wp.array(dtype=Any),
    dt: Any,
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    b_c_out: wp.array(dtype=Any),
    b_q_out: wp.array(dtype=Any),
    b_R_out: wp.array(dtype=Any),
    b_v_out: wp.array(dtype=Any),
    b_w_out: wp.array(dtype=Any),
    b_im_out: wp.array(dtype=Any),
    b_ii_out: wp.array(dtype=Any),
):
    """Each body's free step: centre c, orientation q, free end rotation R', v, ω, 1/M and world I⁻¹ at R'."""
    b = wp.tid()
    Ib = inertia_body[b]
    M, c, q, v, w, R_new = free_motion(
        offsets[b], offsets[b + 1], members, rest, rest_center[b], Ib, mass, gravity, f_ext, dt, x_in, v_in
    )
    b_c_out[b] = c
    b_q_out[b] = q
    b_R_out[b] = R_new
    b_v_out[b] = v
    b_w_out[b] = w
    b_im_out[b] = type(dt)(1.0) / M
    b_ii_out[b] = R_new * wp.inverse(Ib) * wp.transpose(R_new)


@wp.func
def add_pair(
    j: int,
    ra: Any,
    rb: Any,
    n: Any,
    pen: Any,
    dt: Any,
    coef: Any,
    bounce_speed: Any,
    ima: Any,
    iia: Any,
    va: Any,
    wa: Any,
    imb: Any,
    iib: Any,
    vb: Any,
    wb: Any,
    c_r: wp.array(dtype=Any),
    c_r2: wp.array(dtype=Any),
    c_n: wp.array(dtype=Any),
    c_coef: wp.array(dtype=Any),
    c_aux: wp.array(dtype=Any),
):
    """Store pair contact j (levers ra, rb [m] of the common point, n from b to a, overlap ``pen`` [m] at
    the free poses, step ``dt`` [s]): as ``add_contact``, with the relative free velocity u_a − u_b and
    k_n = nᵀ(K_a + K_b)n; a speculative contact (pen ≤ 0) only keeps the pair from overlapping at the end."""
    zero = pen * type(pen)(0.0)
    un = wp.dot(n, (va + wp.cross(wa, ra)) - (vb + wp.cross(wb, rb)))
    target = zero
    if pen <= zero:
        # Speculative: apart by −pen at the free poses, the pair may close that gap this step, no more.
        target = un + pen / dt
    elif un < -bounce_speed:
        target = -coef[1] * un
    kn = wp.dot(n, contact_response(ima, iia, ra, n)) + wp.dot(n, contact_response(imb, iib, rb, n))
    c_r[j] = ra
    c_r2[j] = rb
    c_n[j] = n
    c_coef[j] = type(ra)(coef[0], coef[2], pen)
    c_aux[j] = type(ra)(target, type(pen)(1.0) / kn, un)


@wp.func
def relative_velocity(a: int, b: int, r: Any, r2: Any, b_v: wp.array(dtype=Any), b_w: wp.array(dtype=Any)):
    """u_a(r) − u_b(r2) [m/s], or u_a(r) where b < 0 (ground, collider)."""
    u = b_v[a] + wp.cross(b_w[a], r)
    if b >= 0:
        u = u - (b_v[b] + wp.cross(b_w[b], r2))
    return u


@wp.func
def push(
    a: int,
    b: int,
    r: Any,
    r2: Any,
    P: Any,
    b_im: wp.array(dtype=Any),
    b_ii: wp.array(dtype=Any),
    b_v: wp.array(dtype=Any),
    b_w: wp.array(dtype=Any),
):
    """Impulse P [N s] on body a at lever r and −P on body b (if any) at r2."""
    v, w = apply_impulse(b_im[a], b_ii[a], r, P, b_v[a], b_w[a])
    b_v[a] = v
    b_w[a] = w
    if b >= 0:
        vb, wb = apply_impulse(b_im[b], b_ii[b], r2, -P, b_v[b], b_w[b])
        b_v[b] = vb
        b_w[b] = wb


@wp.func
def gather_pairs(
    end: int,
    body_count: int,
    offsets: wp.array(dtype=wp.int32),
    members: wp.array(dtype=wp.int32),
    rest: wp.array(dtype=Any),
    rest_center: wp.array(dtype=Any),
    bound: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    dt: Any,
    bounce: Any,
    pair_coef: Any,
    pair_capacity: int,
    b_c: wp.array(dtype=Any),
    b_R: wp.array(dtype=Any),
    b_v: wp.array(dtype=Any),
    b_w: wp.array(dtype=Any),
    b_im: wp.array(dtype=Any),
    b_ii: wp.array(dtype=Any),
    c_r: wp.array(dtype=Any),
    c_n: wp.array(dtype=Any),
    c_coef: wp.array(dtype=Any),
    c_aux: wp.array(dtype=Any),
    c_r2: wp.array(dtype=Any),
    c_ab: wp.array(dtype=wp.vec2i),
    b_touch: wp.array(dtype=wp.int32),
    counts: wp.array(dtype=wp.int32),
):
    """Pair contacts from ``end`` on (at most ``pair_capacity``): broad phase by bounding spheres at the free
    poses, narrow phase over particle spheres; ``counts`` = (contacts, pair contacts wanted)."""
    zero = dt * type(dt)(0.0)
    wanted = int(0)  # noqa: UP018
    limit = end + pair_capacity
    for a in range(body_count):
        ca = b_c[a] + dt * b_v[a]
        for b in range(a + 1, body_count):
            cb = b_c[b] + dt * b_v[b]
            if wp.length(ca - cb) < bound[a] + bound[b]:
                for k in range(offsets[a], offsets[a + 1]):
                    ra = b_R[a] * (rest[k] - rest_center[a])
                    xa = ca + ra
                    for l in range(offsets[b], offsets[b + 1]):
                        rb = b_R[b] * (rest[l] - rest_center[b])
                        d = xa - (cb + rb)
                        dist = wp.length(d)
                        pen = radius[members[k]] + radius[members[l]] - dist
                        # Pairs up to min(r_a, r_b) apart at the free poses are watched (speculative): two
                        # bodies that fall together do not overlap at their free poses, but the lower one
                        # is then stopped (by the ground, a third body) and the upper one must be too.
                        margin = wp.min(radius[members[k]], radius[members[l]])
                        if pen > -margin and dist > zero:
                            wanted += 1
                            if end < limit:
                                n = d / dist
                                # The common point: the middle of the overlap, on the line of centres,
                                # moved back by the pair's mean free step so that the levers reach it
                                # from the centres the momentum is taken at (L = Σ M c × v + I ω keeps).
                                p = ca + ra - (radius[members[k]] - type(dt)(0.5) * pen) * n
                                ma = type(dt)(1.0) / b_im[a]
                                mb = type(dt)(1.0) / b_im[b]
                                p = p - dt * (ma * b_v[a] + mb * b_v[b]) / (ma + mb)
                                add_pair(
                                    end, p - b_c[a], p - b_c[b], n, pen, dt, pair_coef, bounce, b_im[a],
                                    b_ii[a], b_v[a], b_w[a], b_im[b], b_ii[b], b_v[b], b_w[b], c_r, c_r2,
                                    c_n, c_coef, c_aux,
                                )  # fmt: skip
                                c_ab[end] = wp.vec2i(a, b)
                                end += 1
                                b_touch[a] = 2  # paired: its contacts take the extra sweeps
                                b_touch[b] = 2
    counts[0] = end
    counts[1] = wanted
    return end


@wp.func
def solve_all_velocities(
    end: int,
    iterations: int,
    pair_sweeps: int,
    b_touch: wp.array(dtype=wp.int32),
    b_v: wp.array(dtype=Any),
    b_w: wp.array(dtype=Any),
    b_im: wp.array(dtype=Any),
    b_ii: wp.array(dtype=Any),
    c_r: wp.array(dtype=Any),
    c_n: wp.array(dtype=Any),
    c_coef: wp.array(dtype=Any),
    c_aux: wp.array(dtype=Any),
    c_imp: wp.array(dtype=Any),
    c_lam: wp.array(dtype=Any),
    c_r2: wp.array(dtype=Any),
    c_ab: wp.array(dtype=wp.vec2i),
):
    """Sequential impulses over contacts [0, end) on the bodies' (v, ω) in ``b_v``, ``b_w``: ``iterations``
    sweeps over all, up to ``pair_sweeps`` over the contacts of paired bodies (``b_touch`` = 2)."""
    zero = b_im[0] * type(b_im[0])(0.0)
    # Velocities: sequential impulses, sweeps alternating direction (as ._contact.solve_velocities).
    for j in range(end):
        c_lam[j] = zero
        c_imp[j] = b_v[c_ab[j][0]] * zero
    for it in range(wp.max(iterations, pair_sweeps)):
        for jj in range(end):
            j = jj
            if it % 2 == 1:
                j = end - 1 - jj
            a = c_ab[j][0]
            if it >= iterations and b_touch[a] != 2:
                continue
            b = c_ab[j][1]
            r = c_r[j]
            r2 = c_r2[j]
            n = c_n[j]
            aux = c_aux[j]
            lam = c_lam[j]
            u = relative_velocity(a, b, r, r2, b_v, b_w)
            lam_new = wp.max(lam + (aux[0] - wp.dot(n, u)) * aux[1], zero)
            push(a, b, r, r2, (lam_new - lam) * n, b_im, b_ii, b_v, b_w)
            c_lam[j] = lam_new
            u = relative_velocity(a, b, r, r2, b_v, b_w)
            P = c_imp[j]
            kt = tangential_response(b_im[a], b_ii[a], r, n)
            if b >= 0:
                kt = kt + tangential_response(b_im[b], b_ii[b], r2, n)
            trial = (u - wp.dot(u, n) * n) - kt * P
            P_new = (friction_velocity(trial, c_coef[j][0] * lam_new * kt, c_coef[j][1]) - trial) / kt
            if b >= 0 and lam_new == zero:
                P_new = trial * zero  # no friction without a normal impulse (exactly: a watched pair)
            push(a, b, r, r2, P_new - P, b_im, b_ii, b_v, b_w)
            c_imp[j] = P_new


@wp.func
def solve_all_positions(
    end: int,
    body_count: int,
    iterations: int,
    pair_sweeps: int,
    b_touch: wp.array(dtype=wp.int32),
    dt: Any,
    b_v: wp.array(dtype=Any),
    b_w: wp.array(dtype=Any),
    b_im: wp.array(dtype=Any),
    b_ii: wp.array(dtype=Any),
    c_r: wp.array(dtype=Any),
    c_n: wp.array(dtype=Any),
    c_coef: wp.array(dtype=Any),
    c_aux: wp.array(dtype=Any),
    c_lam: wp.array(dtype=Any),
    c_r2: wp.array(dtype=Any),
    c_ab: wp.array(dtype=wp.vec2i),
    b_vp: wp.array(dtype=Any),
    b_wq: wp.array(dtype=Any),
):
    """Split impulse: pseudo-velocities ``b_vp``, ``b_wq`` for the overlap the corrected velocities leave
    (sweeps as in :func:`solve_all_velocities`)."""
    zero = dt * type(dt)(0.0)
    # As ._contact.solve_positions, over every body's contacts.
    for b in range(body_count):
        b_vp[b] = b_v[b] * zero
        b_wq[b] = b_w[b] * zero
    for j in range(end):
        aux = c_aux[j]
        u = relative_velocity(c_ab[j][0], c_ab[j][1], c_r[j], c_r2[j], b_v, b_w)
        left = c_coef[j][2] - dt * (wp.dot(c_n[j], u) - aux[2])
        c_lam[j] = zero
        c_aux[j] = type(aux)(wp.max(left, zero) / dt, aux[1], aux[2])
    for it in range(wp.max(iterations, pair_sweeps)):
        for j in range(end):
            a = c_ab[j][0]
            if it >= iterations and b_touch[a] != 2:
                continue
            b = c_ab[j][1]
            n = c_n[j]
            lam = c_lam[j]
            u = relative_velocity(a, b, c_r[j], c_r2[j], b_vp, b_wq)
            lam_new = wp.max(lam + (c_aux[j][0] - wp.dot(n, u)) * c_aux[j][1], zero)
            push(a, b, c_r[j], c_r2[j], (lam_new - lam) * n, b_im, b_ii, b_vp, b_wq)
            c_lam[j] = lam_new


@wp.kernel
def _coupled_contacts(
    body_count: int,
    offsets: wp.array(dtype=wp.int32),
    members: wp.array(dtype=wp.int32),
    rest: wp.array(dtype=Any),
    rest_center: wp.array(dtype=Any),
    bound: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    dt: Any,
    gravity: Any,
    iterations: int,
    pair_sweeps: int,
    surfaces: int,
    ground: int,
    ground_height: Any,
    ground_coef: Any,
    pair_coef: Any,
    pair_capacity: int,
    col_count: int,
    col_kind: wp.array(dtype=wp.int32),
    col_pos: wp.array(dtype=Any),
    col_aux: wp.array(dtype=Any),
    col_rot: wp.array(dtype=Any),
    col_radius: wp.array(dtype=Any),
    col_mesh: wp.array(dtype=wp.uint64),
    col_coef: wp.array(dtype=Any),
    b_c_in: wp.array(dtype=Any),
    b_R_in: wp.array(dtype=Any),
    b_im_in: wp.array(dtype=Any),
    b_ii_in: wp.array(dtype=Any),
    b_v_io: wp.array(dtype=Any),
    b_w_io: wp.array(dtype=Any),
    c_r_out: wp.array(dtype=Any),
    c_n_out: wp.array(dtype=Any),
    c_coef_out: wp.array(dtype=Any),
    c_aux_out: wp.array(dtype=Any),
    c_imp_out: wp.array(dtype=Any),
    c_lam_out: wp.array(dtype=Any),
    c_r2_out: wp.array(dtype=Any),
    c_ab_out: wp.array(dtype=wp.vec2i),
    b_vp_out: wp.array(dtype=Any),
    b_wq_out: wp.array(dtype=Any),
    b_touch_out: wp.array(dtype=wp.int32),
    counts_out: wp.array(dtype=wp.int32),
):
    """Gather, then solve, every contact (module docstring); ``counts_out`` = (contacts, pair contacts
    wanted)."""
    # Restitution above twice gravity's step speed, as in the per-body path (_solver._rigid_step).
    bounce = type(dt)(2.0) * dt * wp.length(gravity)
    end = int(0)  # noqa: UP018 (a dynamic Warp variable, not a constant)
    for b in range(body_count):
        b_touch_out[b] = 0
        c_new = b_c_in[b] + dt * b_v_io[b]
        if surfaces != 0:
            start = end
            end = gather_contacts(
                start, offsets[b], offsets[b + 1], members, rest, rest_center[b], radius, c_new, b_R_in[b],
                ground, ground_height, ground_coef, bounce, col_count, col_kind, col_pos, col_aux, col_rot,
                col_radius, col_mesh, col_coef, b_im_in[b], b_ii_in[b], b_v_io[b], b_w_io[b], c_r_out,
                c_n_out, c_coef_out, c_aux_out,
            )  # fmt: skip
            for j in range(start, end):
                c_ab_out[j] = wp.vec2i(b, -1)
                b_touch_out[b] = 1
    end = gather_pairs(
        end, body_count, offsets, members, rest, rest_center, bound, radius, dt, bounce, pair_coef,
        pair_capacity, b_c_in, b_R_in, b_v_io, b_w_io, b_im_in, b_ii_in, c_r_out, c_n_out, c_coef_out,
        c_aux_out, c_r2_out, c_ab_out, b_touch_out, counts_out,
    )  # fmt: skip
    solve_all_velocities(
        end, iterations, pair_sweeps, b_touch_out, b_v_io, b_w_io, b_im_in, b_ii_in, c_r_out, c_n_out,
        c_coef_out, c_aux_out, c_imp_out, c_lam_out, c_r2_out, c_ab_out,
    )  # fmt: skip
    solve_all_positions(
        end, body_count, iterations, pair_sweeps, b_touch_out, dt, b_v_io, b_w_io, b_im_in, b_ii_in, c_r_out,
        c_n_out, c_coef_out, c_aux_out, c_lam_out, c_r2_out, c_ab_out, b_vp_out, b_wq_out,
    )  # fmt: skip


@wp.kernel
def _place_bodies(
    offsets: wp.array(dtype=wp.int32),
    members: wp.array(dtype=wp.int32),
    rest: wp.array(dtype=Any),
    rest_center: wp.array(dtype=Any),
    dt: Any,
    b_c: wp.array(dtype=Any),
    b_q: wp.array(dtype=Any),
    b_R: wp.array(dtype=Any),
    b_v: wp.array(dtype=Any),
    b_w: wp.array(dtype=Any),
    b_vp: wp.array(dtype=Any),
    b_wq: wp.array(dtype=Any),
    b_touch: wp.array(dtype=wp.int32),
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    """The end pose from the corrected velocities (plus the split impulse's), the particles placed rigidly."""
    b = wp.tid()
    v = b_v[b]
    w = b_w[b]
    c_new = b_c[b] + dt * v
    R_new = b_R[b]
    if b_touch[b] != 0:
        c_new = b_c[b] + dt * (v + b_vp[b])
        R_new = advance_rotation(b_q[b], w + b_wq[b], dt)
    cb = rest_center[b]
    for k in range(offsets[b], offsets[b + 1]):
        i = members[k]
        r = R_new * (rest[k] - cb)
        x_out[i] = c_new + r
        v_out[i] = v + wp.cross(w, r)
