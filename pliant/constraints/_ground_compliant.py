"""Compliant ground contact for XPBD's ``Ground`` constraint (``Ground.contact_stiffness`` set).

The normal spring κ [1/s²] per unit mass is XPBD compliance α = 1/(κ m_i) = w_i/κ, so that a particle
resting under gravity g sits g/κ deep once the iterations converge (α̃λ = −C with λ/Δt² = m g). The damper
b = 2ζ√κ [1/s] is Macklin et al.'s (2016, eq. 26) constraint damping: the damping force m b Ċ along
∇C = n gives γ = α̃ (m b) Δt = b/(κΔt), applied to ∇C·(x − x⁰) = C(x) − C(x⁰) (the plane is linear) for
particles already in contact at the start of the step (x⁰); a landing particle is not braked above the
surface. λ stays ≥ 0, so the force never pulls. The velocity pass keeps the normal velocity the compliant
solve gave (the damper is the restitution) and applies Coulomb friction for the normal impulse w λ/Δt, as the
hard ``Ground`` does: the same law as the force solvers' compliant ground (:mod:`pliant.collision._ground`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import warp as wp

from ..collision import friction_law_velocity
from ._base import ProjectionContext
from ._contact_math import ground_c, ground_grad

if TYPE_CHECKING:
    from ._contact import Ground


def check_compliance(stiffness: float | None, damping_ratio: float | None) -> None:
    """ValueError unless ``stiffness`` κ [1/s²] is None or > 0 and ``damping_ratio`` ζ None or >= 0."""
    if stiffness is not None and not (math.isfinite(stiffness) and stiffness > 0):
        raise ValueError(f"Ground: stiffness must be > 0 1/s² (or omitted), got {stiffness}")
    if damping_ratio is not None and not (math.isfinite(damping_ratio) and damping_ratio >= 0):
        raise ValueError(f"Ground: damping_ratio must be >= 0 (or omitted), got {damping_ratio}")


@wp.kernel
def _project_ground_compliant(
    inv_mass: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    normal: Any,
    d: Any,
    inv_kappa_dt2: Any,
    gamma: Any,
    x_start: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    lam_in: wp.array(dtype=Any),
    p_out: wp.array(dtype=Any),
    lam_out: wp.array(dtype=Any),
):
    # Compliant contact as XPBD compliance α = 1/(κ m) = w/κ (α̃ = α/Δt²) with Macklin's damping
    # γ = α̃ (m b) Δt = b/(κ Δt) on ∇C·(x − x⁰) = C(x) − C(x⁰) (the plane is linear), for particles in
    # contact at the step's start; λ ≥ 0 (the force never pulls). Outputs as _project_ground's.
    i = wp.tid()
    w = inv_mass[i]
    x = p_in[i]
    lam = lam_in[i]
    zero = type(w)(0.0)
    if w != zero:
        c = ground_c(x, normal, d, radius[i])
        if c < zero:
            alpha = w * inv_kappa_dt2
            c0 = ground_c(x_start[i], normal, d, radius[i])
            g = zero
            if c0 < zero:
                g = gamma
            dl = -(c + alpha * lam + g * (c - c0)) / ((type(w)(1.0) + g) * w + alpha)
            dl = wp.max(dl, -lam)
            lam = lam + dl
            x = x + (w * dl) * ground_grad(x, normal)
    p_out[i] = x
    lam_out[i] = lam


@wp.kernel
def _ground_velocity_compliant(
    inv_mass: wp.array(dtype=Any),
    normal: Any,
    friction: Any,
    law: int,
    stick_velocity: Any,
    dt: Any,
    lam_in: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    p_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    # Coulomb friction for the compliant normal impulse w λ/Δt; the normal velocity is kept. Every thread
    # writes its particle's outputs (in place, or fresh arrays in a recorded step).
    i = wp.tid()
    lam = lam_in[i]
    v = v_in[i]
    p = p_in[i]
    if lam <= type(lam)(0.0):
        p_out[i] = p
        v_out[i] = v
        return
    vn = wp.dot(v, normal)
    vt = v - vn * normal
    vt_new = friction_law_velocity(law, vt, friction * inv_mass[i] * lam / dt, stick_velocity)
    p_out[i] = p + dt * (vt_new - vt)
    v_out[i] = vt_new + vn * normal


def project_compliant(ground: Ground, ctx: ProjectionContext, p: wp.array, dt: float) -> wp.array:
    """One sweep of the compliant ground over positions ``p`` [m] in a step of ``dt`` [s]; returns the
    positions written (``p`` itself, or a fresh array in a differentiable step), λ updated likewise."""
    m = ground.model
    p_out, lam_out = (
        (ctx.fresh(p), ctx.fresh(ground._multipliers())) if ctx.requires_grad else (p, ground.lam)
    )
    x0 = p if ground._x_start is None else ground._x_start
    kappa = ground.contact_stiffness
    assert kappa is not None  # called only for a compliant ground
    ctx.launch(
        _project_ground_compliant,
        ground.count,
        [
            m.particle_inv_mass,
            m.particle_radius,
            m.vec3(*ground.normal),
            m.s(ground.offset),
            m.s(1.0 / (kappa * dt * dt)),
            m.s(ground.damping / (kappa * dt)),
            x0,
            p,
            ground.lam,
            p_out,
            lam_out,
        ],
    )
    ground.lam = lam_out
    return p_out


def compliant_velocity(
    ground: Ground, ctx: ProjectionContext, p: wp.array, v: wp.array, dt: float
) -> tuple[wp.array, wp.array]:
    """The velocity pass of the compliant ground: friction for its impulse, moving ``p`` [m] by Δt Δv_t;
    returns (p, v) written (themselves, or fresh arrays in a differentiable step)."""
    m = ground.model
    p_out, v_out = (ctx.fresh(p), ctx.fresh(v)) if ctx.requires_grad else (p, v)
    ctx.launch(
        _ground_velocity_compliant,
        ground.count,
        [
            m.particle_inv_mass,
            m.vec3(*ground.normal),
            m.s(ground.friction),
            ground.friction_law,
            m.s(ground.stick_velocity),
            m.s(dt),
            ground.lam,
            p,
            v,
            p_out,
            v_out,
        ],
    )
    return p_out, v_out
