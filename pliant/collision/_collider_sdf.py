"""The colliders' signed distances and contact response as Warp functions (no kernels, no Python state).

One collider of a registered kind (:data:`pliant.collision.kinds.CONTACT_KINDS`: sphere, box, capsule,
mesh, plane) is a signed distance φ(p) [m] (negative inside) with its gradient n = ∇φ and Hessian ∇²φ
[1/m]. :func:`collider_sdf` unrolls the registry at code generation, so a new kind reaches every caller:
the colliders' kernels (:mod:`._colliders`), the penalty energy and the barrier, which all sit above.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ._friction_laws import friction_law_scale
from .kinds import CONTACT_KINDS

_KINDS = tuple(CONTACT_KINDS.values())


@wp.func
def collider_sdf(kind: int, pos: Any, aux: Any, rot: Any, radius: Any, mesh: wp.uint64, p: Any):
    """(φ [m], n = ∇φ, ∇²φ [1/m]) of one collider at p; see :class:`Colliders` for the parameters.
    An unregistered ``kind`` reads φ = 0, n = +y."""
    zero = radius * type(radius)(0.0)
    phi = zero
    n = type(p)(zero, type(radius)(1.0), zero)
    H = wp.identity(n=3, dtype=type(radius)) * zero
    for k in range(wp.static(len(_KINDS))):
        if kind == wp.static(_KINDS[k].code):
            phi, n, H = wp.static(_KINDS[k].sdf)(pos, aux, rot, radius, mesh, p)
    return phi, n, H


@wp.func
def surface_velocity(vel: Any, omega: Any, centre: Any, p: Any):
    """The velocity [m/s] of a rigidly moving collider's material point at p: v + ω × (p − c)."""
    return vel + wp.cross(omega, p - centre)


@wp.func
def collider_contact(
    kind: int,
    pos: Any,
    aux: Any,
    rot: Any,
    radius: Any,
    mesh: wp.uint64,
    vs: Any,
    friction: Any,
    restitution: Any,
    kappa: Any,
    damping: Any,
    law: int,
    stick_velocity: Any,
    dt: Any,
    step_dt: Any,
    particle_radius: Any,
    x: Any,
    v: Any,
    x_start: Any,
):
    """One collider's velocity-level response for one particle: (x, v) → (x', v'), relative to the
    surface's velocity ``vs`` (zero for a static collider).

    Hard contact (κ = 0): pushed out along n, the relative normal velocity reflected with restitution e,
    the relative tangential velocity through the friction law for the normal change Δv_n
    (:mod:`._friction_laws`; smoothed Coulomb: stopped if |v_t| ≤ μ·Δv_n, cut by μ·Δv_n otherwise), and x
    moved by ``dt`` Δv_t (friction acts inside the step, so a sticking particle stays put).

    Compliant contact (κ > 0 [1/s²], the ground's law): a = max(κ d − b v_n, 0) per unit mass by backward
    Euler on the step's end state (``step_dt`` the step, ``dt`` = β Δt its ∂x/∂v), so a resting particle
    sits g/κ deep; the damper b [1/s] acts on particles in contact at ``x_start``; restitution is the
    damper's; friction for the velocity change Δt·a.
    """
    zero = particle_radius * type(particle_radius)(0.0)
    phi, n, H = collider_sdf(kind, pos, aux, rot, radius, mesh, x)
    pen = particle_radius - phi
    x_new = x
    v_new = v
    if pen > zero:
        vr = v - vs
        vn = wp.dot(vr, n)
        vt = vr - vn * n
        if kappa > zero:
            num = kappa * pen
            den = type(kappa)(1.0) + kappa * step_dt * dt
            if damping > zero:
                phi0, n0, H0 = collider_sdf(kind, pos, aux, rot, radius, mesh, x_start)
                if phi0 < particle_radius:
                    num = num - damping * vn
                    den = den + damping * step_dt
            dv = step_dt * wp.max(num, zero) / den
            speed = wp.length(vt)
            vt_new = vt * friction_law_scale(law, speed, friction * dv, stick_velocity)
            x_new = x + (dt * dv) * n + dt * (vt_new - vt)
            v_new = vt_new + (vn + dv) * n + vs
        else:
            vn_new = wp.max(vn, zero)
            if vn < zero:
                vn_new = -restitution * vn
            speed = wp.length(vt)
            vt_new = vt * friction_law_scale(law, speed, friction * (vn_new - vn), stick_velocity)
            x_new = x + pen * n + dt * (vt_new - vt)
            v_new = vt_new + vn_new * n + vs
    return x_new, v_new
