"""Ground-plane contact as a velocity-level response with Coulomb friction and restitution, or (a
compliant ground, ``Ground.stiffness`` set) a normal spring–damper solved by backward Euler after the step.

Both are the ``plane`` contact kind's (:func:`ground_response` calls the colliders' ``collider_contact``
with n = +y): one home for the arithmetic, the same trajectories bit for bit at height 0 (y − 0 is y, and
y + (r − y) is r for y in [r/2, 2r]) and to round-off otherwise. Implicit steps that minimised a ground
penalty get friction for its impulse instead (:func:`ground_penalty_friction`), which no collider has.

One kernel per response serves every step: it reads (x_in, v_in) and writes every particle of (x_out,
v_out). A gradient-free step passes the same arrays as input and output (an in-place update: each thread
touches only its own particle); a step that ``wp.Tape`` records passes fresh outputs, so that no array is
written after a recorded launch read it (:func:`respond_to_ground` takes the outputs as arguments).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import warp as wp

from .._warp import grad_enabled, launch
from ._collider_sdf import collider_contact
from ._friction_laws import friction_law_code, friction_law_scale
from .kinds import CONTACT_KINDS

#: The ground is this kind (n = +y): its hard and compliant responses are the colliders' own.
_PLANE = wp.constant(CONTACT_KINDS["plane"].code)

if TYPE_CHECKING:
    from ..model import Model


@wp.func
def coulomb_ground(v: Any, dvn: Any, vn_new: Any, friction: Any, law: int, stick_velocity: Any):
    """v with normal component vn_new and its tangential part after the friction law ``law``
    (:data:`~pliant.collision.FRICTION_LAWS`) for the normal velocity change dvn [m/s] (smoothed Coulomb:
    stopped if |v_t| ≤ μ·dvn, slowed by μ·dvn otherwise, smoothed below the stick velocity ε_v).

    Coulomb: the tangential impulse is bounded by μ times the normal one, so a block sliding on the ground
    decelerates by exactly μg and stops after v²/(2μg).
    """
    zero = friction * type(friction)(0.0)
    scale = friction_law_scale(law, wp.length(type(v)(v[0], zero, v[2])), friction * dvn, stick_velocity)
    return type(v)(v[0] * scale, vn_new, v[2] * scale)


@wp.func
def friction_shift(p: Any, v: Any, v_new: Any, dt: Any):
    """p moved by Δt times the tangential velocity change v_new − v: friction acts inside the step, whose
    position p = x + Δt v already used the trial velocity (a sticking particle stays where it was)."""
    return type(p)(p[0] + dt * (v_new[0] - v[0]), p[1], p[2] + dt * (v_new[2] - v[2]))


@wp.func
def ground_particle(
    x: Any,
    v: Any,
    x_start: Any,
    inv_mass: Any,
    radius: Any,
    height: Any,
    friction: Any,
    restitution: Any,
    law: int,
    stick_velocity: Any,
    shift_dt: Any,
    kappa: Any,
    damping: Any,
    dt: Any,
):
    """One particle's ground response (x, v) → (x', v'): the ``plane`` kind through y = ``height``, n = +y,
    by :func:`~pliant.collision._collider_sdf.collider_contact` (see :func:`ground_response`); a particle of
    zero inverse mass, or above the ground, comes back unchanged. The fused FastMassSpring frame calls it
    too, so the two paths are one arithmetic."""
    zero = height * type(height)(0.0)
    if inv_mass != zero:
        n = type(x)(zero, type(height)(1.0), zero)
        eye = wp.identity(n=3, dtype=type(height))
        return collider_contact(
            _PLANE,
            type(x)(zero, height, zero),
            n,
            eye,
            zero,
            wp.uint64(0),
            n * zero,
            friction,
            restitution,
            kappa,
            damping,
            law,
            stick_velocity,
            shift_dt,
            dt,
            radius,
            x,
            v,
            x_start,
        )
    return x, v


@wp.kernel
def ground_response(
    inv_mass: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    height: Any,
    coefficients: wp.array(dtype=Any),
    law: int,
    stick_velocity: Any,
    shift_dt: Any,
    kappa: Any,
    damping: Any,
    dt: Any,
    x_start: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    """The ground's response after a step of Δt = ``dt``: the ``plane`` kind (through y = height, n = +y)
    through :func:`~pliant.collision._collider_sdf.collider_contact`, the colliders' own response.

    Hard (κ = 0): particles pushed above y = height + r, the normal velocity reflected (×e), the friction
    law on v_t, the position moved by ``shift_dt`` Δv_t. Compliant (κ > 0 [1/s²]): the spring–damper
    a = max(κ d − b v_n, 0) / (1 + κ β Δt² + b Δt) by backward Euler on the trial depth d (β Δt =
    ``shift_dt``), so a particle resting under gravity g sits exactly g/κ deep; the damper b [1/s] acts on
    particles in contact at ``x_start``; restitution is the damper's; friction for the change Δt·a.
    ``coefficients`` = [μ, e] (an array, so that their gradients can be read). Every particle's output is
    written (the outputs may be the inputs). Differentiable almost everywhere (the contact set and the
    sign of v_n are piecewise: one-sided gradients at a switch; friction is C¹ through ε_v).
    """
    i = wp.tid()
    x, v = ground_particle(
        x_in[i],
        v_in[i],
        x_start[i],
        inv_mass[i],
        radius[i],
        height,
        coefficients[0],
        coefficients[1],
        law,
        stick_velocity,
        shift_dt,
        kappa,
        damping,
        dt,
    )
    x_out[i] = x
    v_out[i] = v


@wp.kernel
def ground_penalty_friction(
    inv_mass: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    height: Any,
    coefficients: wp.array(dtype=Any),
    law: int,
    stick_velocity: Any,
    shift_dt: Any,
    kappa: Any,
    damping: Any,
    impulse_dt: Any,
    point: Any,
    x_start: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    """Coulomb friction for the normal impulse a ground penalty κ m d gave over the step (implicit steps).

    Inside the incremental potential the penalty holds a resting particle at the depth d = g/κ where it
    balances the weight; projecting it back to y = height + r after every step (``ground_response``) would
    undo that equilibrium and leave Newton a residual of h·g per step. So particles keep their height and
    the normal velocity the potential gave them. The penalty acted at x_θ = x₁ + (1 − θ)(x₀ − x₁)
    (θ = ``point``: 1 for backward Euler, ½ for the implicit midpoint rule; x₀ = ``x_start``) over
    ``impulse_dt``, so the tangential speed drops by at most μ κ d(x_θ) ``impulse_dt`` (the impulse bound;
    ``coefficients`` = [μ, e]; stopped below it), and the position by ``shift_dt`` times that change
    (:func:`friction_shift`: it only takes back part of this step's own tangential motion). Even a
    particle that went deep is not lifted: moving one vertex of an element along the normal after the
    step's inversion-safe minimisation can invert the element; the penalty pushes it out in the next step.
    With ``damping`` b > 0 [1/s] (a :class:`~pliant.energies.DampedGroundPenalty`, compliant contact's
    spring–damper) the impulse is max(κ d − b v_n, 0) ``impulse_dt`` per unit mass for a particle in contact
    at the step's start (v_n the step's end velocity), κ d ``impulse_dt`` for one entering; b = 0 leaves the
    undamped arithmetic as it is. A subgradient where a particle enters or leaves the contact set; friction
    is C¹ (ε_v).
    """
    i = wp.tid()
    p = x_in[i]
    v = v_in[i]
    one = type(height)(1.0)
    floor = height + radius[i]
    # x₁ + (1 − θ)(x₀ − x₁): exactly x₁ for θ = 1.
    d = floor - (p[1] + (one - point) * (x_start[i][1] - p[1]))
    zero = type(height)(0.0)
    if inv_mass[i] != zero and d > zero:
        a = kappa * d
        if damping > zero and x_start[i][1] < floor:
            a = wp.max(a - damping * v[1], zero)
        v_new = coulomb_ground(v, a * impulse_dt, v[1], coefficients[0], law, stick_velocity)
        x_out[i] = friction_shift(p, v, v_new, shift_dt)
        v_out[i] = v_new
    else:
        x_out[i] = p
        v_out[i] = v


def ground_coefficients(model: Model) -> wp.array:
    """[friction μ, restitution e] of ``model.ground`` as the device array the ground kernels read, with
    ``requires_grad`` on a differentiable model (its ``.grad`` then holds ∂loss/∂μ, ∂loss/∂e)."""
    g = model.ground
    if g is None:
        raise ValueError("the model has no ground plane: ModelBuilder.add_ground() first")
    friction_law_code(g.friction_law)  # an unknown law fails here, at set-up
    rg = grad_enabled(model)
    return wp.array([g.friction, g.restitution], dtype=model.scalar, device=model.device, requires_grad=rg)


def respond_to_ground(
    model: Model,
    coefficients: wp.array,
    dt: float,
    x_in: wp.array,
    v_in: wp.array,
    x_out: wp.array,
    v_out: wp.array,
    *,
    penalty: float | None = None,
    penalty_damping: float = 0.0,
    x_start: wp.array | None = None,
    point: float = 1.0,
    impulse: float = 1.0,
    shift: float = 1.0,
) -> None:
    """The ground response after a step of ``dt`` [s]: reads (x_in, v_in), writes (x_out, v_out).

    Args:
        model: the Model (``model.ground`` set).
        coefficients: [μ, e] (:func:`ground_coefficients`).
        dt: the step [s].
        x_in: positions [m] after the step.
        v_in: velocities [m/s] after the step.
        x_out: positions [m] written (``x_in`` itself for an in-place update).
        v_out: velocities [m/s] written (``v_in`` itself for an in-place update).
        penalty: κ [1/s²] of a :class:`~pliant.energies.GroundPenalty` the step already minimised: the
            response is then friction for the penalty's impulse instead of a projection. Without one, a
            compliant ``model.ground`` (``stiffness`` set) gets :func:`ground_response`'s spring–damper.
        penalty_damping: b [1/s] of that penalty's damper (:class:`~pliant.energies.DampedGroundPenalty`).
        x_start: positions [m] at the start of the step (needed with a penalty and ``point`` < 1, and by
            compliant contact's damper).
        point: θ [-]: the step's forces act at x₀ + θ(x₁ − x₀) (the integrator's ``contact_point``).
        impulse: [-]: they act over ``impulse``·Δt (``contact_impulse``).
        shift: [-]: x₁ moves by ``shift``·Δt per unit change of v₁ (``contact_shift``), and so by
            ``shift``·Δt·Δv_t for friction's change Δv_t.
    """
    m = model
    if m.ground is None:
        raise ValueError("the model has no ground plane: ModelBuilder.add_ground() first")
    g = m.ground
    law = friction_law_code(g.friction_law)
    common = [m.particle_inv_mass, m.particle_radius, m.s(g.height), coefficients, law, m.s(g.stick_velocity)]
    common.append(m.s(shift * dt))
    if penalty is not None:
        if point != 1.0 and x_start is None:
            raise ValueError("respond_to_ground: a penalty with point < 1 needs x_start (the step's x₀)")
        x0 = x_in if x_start is None else x_start
        args = [*common, m.s(penalty), m.s(penalty_damping), m.s(impulse * dt), m.s(point), x0]
        kernel = ground_penalty_friction
    else:
        if g.compliant and x_start is None and g.damping > 0:
            raise ValueError(
                "respond_to_ground: compliant contact with a damper needs x_start (the step's x₀)"
            )
        x0 = x_in if x_start is None else x_start
        kappa, damping = (g.stiffness, g.damping) if g.compliant else (0.0, 0.0)
        args = [*common, m.s(kappa or 0.0), m.s(damping), m.s(dt), x0]
        kernel = ground_response
    launch(kernel, m.particle_count, [*args, x_in, v_in, x_out, v_out], device=m.device)
