"""The one Coulomb friction law every post-step contact response applies (ground, colliders, XPBD).

A contact response after a step of Δt sees a particle's trial tangential velocity ṽ_t (speed s = |ṽ_t|)
and the normal velocity change Δv_n it applied this step: the whole of it, including the part that
cancels this step's gravity, so that a resting particle's friction budget b = μ Δv_n is μ g cos θ Δt.
Coulomb's law in impulse form: the tangential velocity change is at most b, so

* stick (s ≤ b): v_t' = 0;
* slip (s > b): |v_t'| = s − b, along ṽ_t (a block sliding on the ground decelerates by exactly μ g).

The friction impulse acts inside the step, so each response moves the particle by Δt (v_t' − ṽ_t) as
well: the step's position x + Δt ṽ already used ṽ_t, and without the correction a sticking particle would
still advance by Δt ṽ_t every step (gravity's Δt² g sin θ on its own, more where a body's weight rests on a
few contact particles): a steady creep down any slope.

Smoothing, as IPC's (Li et al. 2020): friction is evaluated at the end velocity, with the magnitude
μ Δv_n f₁(|v_t'|), f₁(u) = 2u/ε_v − u²/ε_v² below the stick velocity ε_v and 1 above. The law is then C¹
in ṽ_t and μ (differentiable through the stick/slip switch), exact Coulomb slip wherever |v_t'| ≥ ε_v
(the same expression as unsmoothed, bit for bit), and static friction is a viscous ramp: a contact under
a tangential load inside the cone slides slower than ε_v [m/s] (about ε_v s/(2b) well inside it).
ε_v = 0 is exact Coulomb, with a kink at s = b. The default ε_v is :data:`pliant.model.STICK_VELOCITY`.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ..model import STICK_VELOCITY

__all__ = ["STICK_VELOCITY", "friction_scale", "friction_velocity", "tangential_change"]


@wp.func
def friction_scale(speed: Any, budget: Any, stick_velocity: Any):
    """s'/s: the factor the tangential velocity ṽ_t (speed s [m/s]) is multiplied by, for the friction
    budget b = μ Δv_n [m/s] and stick velocity ε_v [m/s] (see the module docstring).

    Slip (s ≥ b + ε_v): (s − b)/s. Below: the root of s = s' + b f₁(s') in s' < ε_v, written without
    dividing by s or b (finite at s = 0, exact 0 for ε_v = 0): 2ε_v / (ε_v + 2b + √((ε_v + 2b)² − 4 b s)).
    """
    zero = speed * type(speed)(0.0)
    if speed >= budget + stick_velocity:
        if speed > zero:
            return wp.max(speed - budget, zero) / speed
        return zero
    c = stick_velocity + type(speed)(2.0) * budget
    # (ε + 2b)² − 4bs ≥ ε² > 0 for s < b + ε: the square root is of a positive number.
    root = wp.sqrt(wp.max(c * c - type(speed)(4.0) * budget * speed, zero))
    if c + root > zero:
        return type(speed)(2.0) * stick_velocity / (c + root)
    return zero


@wp.func
def friction_velocity(vt: Any, budget: Any, stick_velocity: Any):
    """The tangential velocity v_t' [m/s] after friction: ṽ_t scaled by :func:`friction_scale`."""
    return vt * friction_scale(wp.length(vt), budget, stick_velocity)


@wp.func
def tangential_change(vrel: Any, n: Any, dvn: Any, friction: Any, stick_velocity: Any):
    """Δv_t [m/s]: the change of the relative tangential velocity of vrel (normal n) by the smoothed Coulomb
    law for the relative normal velocity change dvn [m/s] (budget μ dvn); self-contact's friction on both
    sides of a pair (``SelfCollision``, ``StepBound``)."""
    vt = vrel - wp.dot(vrel, n) * n
    one = friction * type(friction)(0.0) + type(friction)(1.0)
    return vt * (friction_scale(wp.length(vt), friction * dvn, stick_velocity) - one)
