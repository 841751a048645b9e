"""Lagged, smoothed Coulomb friction for barrier contact against the ground and colliders (IPC, §5).

Per particle i and obstacle c (0 the ground, then each collider) in contact at the start of the step x_t,
the normal force λ_ic = κ |b′(d_ic)| [N] and the contact normal n_ic are frozen ("lagged"); the step's
tangential displacement u = (I − n nᵀ)(x − x_t) [m] then enters the potential as

    D(x) = Σ μ_c λ_ic f₀(|u|),   f₀(y) = y²/ε − y³/(3ε²) + ε/3 (y < ε),  f₀(y) = y (y ≥ ε),   ε = ε_v Δt,

so the friction force μλ f₁(|u|) û, f₁ = f₀′ = 2y/ε − y²/ε² below ε and 1 above, is Coulomb's μλ when the
particle slides faster than the stick velocity ε_v [m/s] and a stiff viscous ramp below it (static friction
up to a creep of ε_v). The Hessian μλ [f₁′ ûûᵀ + (f₁/y)(P − ûûᵀ)] (P = I − nnᵀ) is PSD (f₁′ ≥ 0).

A moving collider (``velocity=``, ``angular_velocity=``) carries its material point at x_t by s_ic, the
rigid displacement over the step (:func:`pliant.collision.rigid_displacement`, also lagged): friction acts
on the motion relative to the surface, u = (I − n nᵀ)(x − x_t − s_ic), i.e. on v − v_s with v_s the surface
velocity v + ω × (p − c) (exactly s_ic/Δt for a translating collider). Static obstacles have s = 0.

Self-contact pairs (point–triangle, edge–edge) closer than d̂ at x_t get the same potential with their
closest-point coefficients c (r = Σ c_k x_k) lagged too: u = (I − nnᵀ) Σ_k c_k (x_k − x_k,t), n = r/|r| at
x_t, so the gradient on point k is c_k μλ f₁ û and the Hessian c cᵀ ⊗ (the 3×3 above), PSD as well.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ..collision import collider_sdf, rigid_displacement
from ._barrier_kernels import write_pair
from ._barrier_math import barrier_d1, edge_edge_params, mat12d, point_triangle_params, to_d, vec12d

wp.set_module_options({"max_unroll": 0})


@wp.kernel(enable_backward=False)
def friction_lag(
    kind: wp.array(dtype=wp.int32),
    pos: wp.array(dtype=Any),
    aux: wp.array(dtype=Any),
    rot: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    mesh: wp.array(dtype=wp.uint64),
    n_colliders: int,
    ground: int,
    height: wp.float64,
    inv_mass: wp.array(dtype=Any),
    dhat: wp.float64,
    kappa: wp.float64,
    # Moving colliders (``moving`` 0: all static, no shift written):
    moving: int,
    vel: wp.array(dtype=Any),
    omega: wp.array(dtype=Any),
    centre: wp.array(dtype=Any),
    h: Any,
    x_in: wp.array(dtype=Any),
    lam_out: wp.array(dtype=wp.float64),
    normal_out: wp.array(dtype=wp.vec3d),
    shift_out: wp.array(dtype=wp.vec3d),
):
    # λ = κ|b′(d)| and n at the step's start, per (particle, obstacle); 0 where out of contact. With moving
    # colliders, the surface's displacement s over the step at x (zero for static ones and the ground).
    i = wp.tid()
    x = x_in[i]
    slots = n_colliders + 1
    for c in range(slots):
        lam_out[i * slots + c] = wp.float64(0.0)
        if moving != 0:
            shift_out[i * slots + c] = wp.vec3d()
            if c > 0:
                k = c - 1
                if wp.length(vel[k]) > h * type(h)(0.0) or wp.length(omega[k]) > h * type(h)(0.0):
                    shift_out[i * slots + c] = to_d(rigid_displacement(vel[k], omega[k], centre[k], h, x))
    if inv_mass[i] == x[0] * type(x[0])(0.0):
        return
    if ground != 0:
        d = wp.float64(x[1]) - height
        if d < dhat and d > wp.float64(0.0):
            lam_out[i * slots] = -kappa * barrier_d1(d, dhat)
            normal_out[i * slots] = wp.vec3d(wp.float64(0.0), wp.float64(1.0), wp.float64(0.0))
    for c in range(n_colliders):
        phi, n, Hphi = collider_sdf(kind[c], pos[c], aux[c], rot[c], radius[c], mesh[c], x)
        d = wp.float64(phi)
        if d < dhat and d > wp.float64(0.0):
            lam_out[i * slots + c + 1] = -kappa * barrier_d1(d, dhat)
            normal_out[i * slots + c + 1] = to_d(n)


@wp.kernel(enable_backward=False)
def friction_terms(
    n_obstacles: int,
    mu: wp.array(dtype=wp.float64),
    lam: wp.array(dtype=wp.float64),
    normal: wp.array(dtype=wp.vec3d),
    x_start: wp.array(dtype=Any),
    moving: int,
    shift: wp.array(dtype=wp.vec3d),
    x_in: wp.array(dtype=Any),
    eps: wp.float64,
    mode: int,
    scale: wp.float64,
    slots_in: wp.array(dtype=wp.int32),
    value_out: wp.array(dtype=Any),
    grad_out: wp.array(dtype=Any),
    hess_out: wp.array(dtype=Any),
):
    # D_i = Σ_c μ_c λ_ic f₀(|P(x − x_t − s_ic)|), its gradient and Hessian (module docstring).
    i = wp.tid()
    x = x_in[i]
    dx = to_d(x) - to_d(x_start[i])
    val = wp.float64(0.0)
    g = wp.vec3d()
    H = wp.mat33d()
    for c in range(n_obstacles):
        k = i * n_obstacles + c
        w = mu[c] * lam[k]
        if w > wp.float64(0.0):
            n = normal[k]
            P = wp.identity(n=3, dtype=wp.float64) - wp.outer(n, n)
            u = P * dx
            if moving != 0:
                u = P * (dx - shift[k])
            y = wp.length(u)
            if y < eps:
                val = val + w * (
                    y * y / eps - y * y * y / (wp.float64(3.0) * eps * eps) + eps / wp.float64(3.0)
                )
                f1_y = wp.float64(2.0) / eps - y / (eps * eps)  # f₁(y)/y
                g = g + w * f1_y * u
                # f₁′ ûûᵀ + (f₁/y)(P − ûûᵀ) = (f₁/y) P − (1/ε²) u uᵀ / y  (f₁′ − f₁/y = −y/ε²)
                Hc = f1_y * P
                if y > wp.float64(0.0):
                    Hc = Hc - wp.outer(u, u) / (eps * eps * y)
                H = H + w * Hc
            else:
                val = val + w * y
                g = g + (w / y) * u
                uh = u / y
                H = H + (w / y) * (P - wp.outer(uh, uh))
    if mode == 0:
        if val != wp.float64(0.0):
            wp.atomic_add(value_out, 0, type(x[0])(val))
    elif mode == 1:
        out = x * type(x[0])(0.0)
        for r in range(3):
            out[r] = type(x[0])(g[r])
        wp.atomic_add(grad_out, i, out)
    else:
        hb = wp.outer(x, x) * type(x[0])(0.0)
        for r in range(3):
            for s in range(3):
                hb[r, s] = type(x[0])(scale * H[r, s])
        wp.atomic_add(hess_out, slots_in[i], hb)


@wp.func
def _friction_3(w: wp.float64, u: wp.vec3d, P: wp.mat33d, eps: wp.float64):
    """(w f₀(|u|), w f₁(|u|) û, w ∇²f₀) of one contact's tangential displacement u [m]."""
    y = wp.length(u)
    if y < eps:
        f1_y = wp.float64(2.0) / eps - y / (eps * eps)
        H = f1_y * P
        if y > wp.float64(0.0):
            H = H - wp.outer(u, u) / (eps * eps * y)
        f0 = y * y / eps - y * y * y / (wp.float64(3.0) * eps * eps) + eps / wp.float64(3.0)
        return w * f0, w * f1_y * u, w * H
    uh = u / y
    return w * y, w * uh, (w / y) * (P - wp.outer(uh, uh))


@wp.kernel(enable_backward=False)
def self_friction_lag(
    quads: wp.array(dtype=wp.vec4i),
    edge_edge: wp.array(dtype=wp.int32),
    x_in: wp.array(dtype=Any),
    dhat: wp.float64,
    kappa: wp.float64,
    coef_out: wp.array(dtype=wp.vec4d),
    lam_out: wp.array(dtype=wp.float64),
    normal_out: wp.array(dtype=wp.vec3d),
):
    # Per self-contact pair at the step's start: closest-point coefficients c, λ = κ|b′(d)|, n = r/|r|.
    k = wp.tid()
    q = quads[k]
    x0 = to_d(x_in[q[0]])
    x1 = to_d(x_in[q[1]])
    x2 = to_d(x_in[q[2]])
    x3 = to_d(x_in[q[3]])
    if edge_edge[k] == 0:
        c0, e1, e2, b1, b2, m = point_triangle_params(x0, x1, x2, x3)
    else:
        c0, e1, e2, b1, b2, m = edge_edge_params(x0, x1, x2, x3)
    c = c0 + b1 * e1 + b2 * e2
    r = c[0] * x0 + c[1] * x1 + c[2] * x2 + c[3] * x3
    d = wp.length(r)
    lam_out[k] = wp.float64(0.0)
    coef_out[k] = c
    normal_out[k] = wp.vec3d()
    if d > wp.float64(0.0) and d < dhat:
        lam_out[k] = -kappa * barrier_d1(d, dhat)
        normal_out[k] = r / d


@wp.kernel(enable_backward=False)
def self_friction_terms(
    quads: wp.array(dtype=wp.vec4i),
    coef: wp.array(dtype=wp.vec4d),
    lam: wp.array(dtype=wp.float64),
    normal: wp.array(dtype=wp.vec3d),
    pair_keys: wp.array(dtype=wp.int64),
    n_particles: int,
    x_start_in: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    mu: wp.float64,
    eps: wp.float64,
    mode: int,
    scale: wp.float64,
    slots_in: wp.array(dtype=wp.int32),
    value_out: wp.array(dtype=Any),
    grad_out: wp.array(dtype=Any),
    hess_out: wp.array(dtype=Any),
):
    # D_k = μ λ_k f₀(|P Σ c_j (x_j − x_j,t)|) per lagged self-contact pair (module docstring).
    k = wp.tid()
    w = mu * lam[k]
    if w <= wp.float64(0.0):
        return
    q = quads[k]
    c = coef[k]
    n = normal[k]
    rel = wp.vec3d()
    for j in range(4):
        rel = rel + c[j] * (to_d(x_in[q[j]]) - to_d(x_start_in[q[j]]))
    P = wp.identity(n=3, dtype=wp.float64) - wp.outer(n, n)
    val, g3, H3 = _friction_3(w, P * rel, P, eps)
    g = vec12d()
    H = mat12d()
    for a in range(4):
        for i in range(3):
            g[3 * a + i] = c[a] * g3[i]
            for b in range(4):
                for j in range(3):
                    H[3 * a + i, 3 * b + j] = c[a] * c[b] * H3[i, j]
    like = x_in[q[0]]
    write_pair(
        q,
        val,
        g,
        H,
        wp.float64(1.0),
        mode,
        scale,
        like,
        pair_keys,
        n_particles,
        slots_in,
        value_out,
        grad_out,
        hess_out,
    )
