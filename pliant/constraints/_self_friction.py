"""Coulomb friction in XPBD's self-contact constraints (particle–particle, point–triangle).

Position-based friction as Macklin et al. ("Unified particle physics", 2014) and Müller's PBD: each time a
contact's projection removes a penetration d = −C > 0, the relative tangential displacement of the two sides
over the step, Δx_t = [(p_a − x_a) − (p_b − x_b)]_t, is cut back (stuck below the budget, slid by the rest
above it). The cut is the project's one law (:mod:`pliant.collision._friction`, by the registry of
:mod:`pliant.collision._friction_laws`) applied to the velocity v_t = Δx_t/Δt: Δt (v_t' − v_t) =
(s'/s − 1) Δx_t. The budget is the step's, as the ground's λ: μ times the depths the contact removed so far
this step (Σ d, the part holding the weight included), less the friction it already applied, in b = that/Δt.
A per-sweep budget μ d alone would waste what the first sweep's (the particle's own weight) leaves over,
before the weight the body's springs bring in later sweeps pulls sideways. With the step's budget a
slider decelerates by exactly μ g and a contact inside the cone keeps its place (slower than the stick
velocity ε_v); v = (p − x)/Δt carries the friction into the velocities.
A particle–particle contact's budget is its particle's (pooled over its pairs: the pairs are not listed).

The correction is split by inverse mass (generalised to the triangle's barycentric point for the
point–triangle contact: W = w_q + Σ b_k² w_k), so that it conserves momentum. μ = 0 launches the
frictionless kernels of :mod:`._contact` (bit for bit what they always did).
"""

from __future__ import annotations

import math
from typing import Any

import warp as wp

from ..collision import friction_law_code, friction_law_scale
from ..model import STICK_VELOCITY, Model
from ._base import ProjectionContext
from ._contact_math import plane_barycentric, point_triangle_c, point_triangle_grad


class SelfFriction:
    """Validated friction settings of a self-contact constraint: μ, the stick velocity ε_v [m/s] and the
    law's kernel code."""

    def __init__(self, owner: str, friction: float, stick_velocity: float | None, friction_law: str) -> None:
        if not (math.isfinite(friction) and friction >= 0):
            raise ValueError(f"{owner}: friction must be a finite μ >= 0, got {friction}")
        eps = STICK_VELOCITY if stick_velocity is None else float(stick_velocity)
        if not (math.isfinite(eps) and eps >= 0):
            raise ValueError(f"{owner}: stick_velocity must be >= 0 m/s (or omitted), got {stick_velocity}")
        self.friction = float(friction)
        self.stick_velocity = eps
        self.law = friction_law_code(friction_law)

    def bind(self, model: Model, n: int) -> None:
        """Allocate the budget of ``n`` contacts (or particles): the depth [m] each removed this step and the
        friction [m] it applied (empty without friction)."""
        self.model = model
        n = n if self.friction > 0 else 0
        self.depth = wp.zeros(n, dtype=model.scalar, device=model.device)
        self.used = wp.zeros(n, dtype=model.scalar, device=model.device)
        self.x_start: wp.array | None = None

    def begin_step(self, ctx: ProjectionContext, x: wp.array) -> None:
        """Keep the step's start positions ``x`` [m] (the displacement's reference); zero the budget."""
        self.x_start = x
        if self.friction > 0:
            ctx.call(self.depth.zero_)
            ctx.call(self.used.zero_)

    def args(self, dt: float, p: wp.array) -> list:
        """The friction kernels' arguments between the contact's and the outputs, for the step of ``dt`` [s]
        and the predicted positions ``p`` [m] (read-only, so before the budget the kernels update)."""
        m = self.model
        return [
            m.s(self.friction),
            self.law,
            m.s(self.stick_velocity),
            m.s(dt),
            self.x_start,
            p,
            self.depth,
            self.used,
        ]


@wp.func
def tangential_correction(rel: Any, n: Any, budget: Any, law: int, stick: Any, dt: Any):
    """The change (s'/s − 1) Δx_t [m] of the relative displacement ``rel`` [m] over the step, tangential to
    the unit normal ``n``, for what is left of the step's budget, ``budget`` [m] (μ times the normal
    correction so far less the friction already applied), by the law ``law`` (stick velocity [m/s])."""
    dxt = rel - wp.dot(rel, n) * n
    scale = friction_law_scale(law, wp.length(dxt) / dt, budget / dt, stick)
    return (scale - type(budget)(1.0)) * dxt


@wp.kernel
def project_particle_friction(
    grid: wp.uint64,
    inv_mass: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    query_radius: Any,
    mu: Any,
    law: int,
    stick: Any,
    dt: Any,
    x_start: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    depth_io: wp.array(dtype=Any),
    used_io: wp.array(dtype=Any),
    delta_out: wp.array(dtype=Any),
    count_out: wp.array(dtype=wp.int32),
):
    # _project_particle_collision of ._contact plus friction: thread i writes only particle i, and its
    # share of each pair's correction is the mirror image of j's (n and Δx_t change sign exactly). The
    # budget is the particle's: μ times the depths its contacts removed this step, less what it used.
    i = wp.tid()
    wi = inv_mass[i]
    zero = type(wi)(0.0)
    if wi == zero:
        return
    xi = p_in[i]
    ri = radius[i]
    acc = xi * zero
    n_hit = wp.int32(0)
    depth = depth_io[i]
    used = used_io[i]
    for j in wp.hash_grid_query(grid, xi, query_radius):
        if j != i:
            wj = inv_mass[j]
            d = xi - p_in[j]
            l = wp.length(d)
            c = l - ri - radius[j]
            if c < zero and l > zero:
                n = d / l
                share = wi / (wi + wj)
                rel = (xi - x_start[i]) - (p_in[j] - x_start[j])
                depth = depth - c
                f = tangential_correction(rel, n, wp.max(mu * depth - used, zero), law, stick, dt)
                used = used + wp.length(f)
                acc = acc - share * c * n + share * f
                n_hit += wp.int32(1)
    if n_hit > 0:
        delta_out[i] = delta_out[i] + acc
        count_out[i] = count_out[i] + n_hit
        depth_io[i] = depth
        used_io[i] = used


@wp.kernel
def project_point_triangle_friction(
    tri_indices: wp.array2d(dtype=wp.int32),
    inv_mass: wp.array(dtype=Any),
    thickness: Any,
    capacity: int,
    contact_count: wp.array(dtype=wp.int32),
    contact_particle: wp.array(dtype=wp.int32),
    contact_tri: wp.array(dtype=wp.int32),
    contact_side: wp.array(dtype=Any),
    mu: Any,
    law: int,
    stick: Any,
    dt: Any,
    x_start: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    depth_io: wp.array(dtype=Any),
    used_io: wp.array(dtype=Any),
    delta_out: wp.array(dtype=Any),
    count_out: wp.array(dtype=wp.int32),
):
    # _project_point_triangle of ._contact plus friction between q and the triangle's point under it; the
    # contact's budget is μ times the depths it removed this step, less the friction it applied.
    k = wp.tid()
    if k >= wp.min(contact_count[0], capacity):
        return
    q = contact_particle[k]
    t = contact_tri[k]
    i1 = tri_indices[t, 0]
    i2 = tri_indices[t, 1]
    i3 = tri_indices[t, 2]
    xq = p_in[q]
    x1 = p_in[i1]
    x2 = p_in[i2]
    x3 = p_in[i3]
    side = contact_side[k]
    zero = type(thickness)(0.0)
    c = point_triangle_c(xq, x1, x2, x3, side, thickness)
    if c >= zero:
        return
    gq, g1, g2, g3 = point_triangle_grad(xq, x1, x2, x3, side)
    wq = inv_mass[q]
    w1 = inv_mass[i1]
    w2 = inv_mass[i2]
    w3 = inv_mass[i3]
    wgs = wq * wp.dot(gq, gq) + w1 * wp.dot(g1, g1) + w2 * wp.dot(g2, g2) + w3 * wp.dot(g3, g3)
    if wgs == zero:
        return
    dl = -c / wgs
    dq = (wq * dl) * gq
    d1 = (w1 * dl) * g1
    d2 = (w2 * dl) * g2
    d3 = (w3 * dl) * g3
    b = plane_barycentric(xq, x1, x2, x3)
    big_w = wq + b[0] * b[0] * w1 + b[1] * b[1] * w2 + b[2] * b[2] * w3
    if wp.length(gq) > zero and big_w > zero:
        # gq = s n̂: the contact normal. The relative displacement of q against the point b of the triangle.
        n = wp.normalize(gq)
        rel = (xq - x_start[q]) - (
            b[0] * (x1 - x_start[i1]) + b[1] * (x2 - x_start[i2]) + b[2] * (x3 - x_start[i3])
        )
        depth = depth_io[k] - c
        rel_f = tangential_correction(rel, n, wp.max(mu * depth - used_io[k], zero), law, stick, dt)
        depth_io[k] = depth
        used_io[k] = used_io[k] + wp.length(rel_f)
        f = rel_f / big_w
        dq = dq + wq * f
        d1 = d1 - (b[0] * w1) * f
        d2 = d2 - (b[1] * w2) * f
        d3 = d3 - (b[2] * w3) * f
    wp.atomic_add(delta_out, q, dq)
    wp.atomic_add(delta_out, i1, d1)
    wp.atomic_add(delta_out, i2, d2)
    wp.atomic_add(delta_out, i3, d3)
    wp.atomic_add(count_out, q, 1)
    wp.atomic_add(count_out, i1, 1)
    wp.atomic_add(count_out, i2, 1)
    wp.atomic_add(count_out, i3, 1)
