"""The friction-law registry: one ``wp.func`` per law, one line per law in :data:`FRICTION_LAWS`.

A law maps the trial tangential speed s [m/s], the friction budget b = μ Δv_n [m/s] and the stick velocity
ε_v [m/s] to the factor s'/s the tangential velocity is multiplied by (:mod:`._friction` states the
contract: s' ≤ s, s' = 0 at s = 0, s' = s − b in slip). :func:`friction_law_scale` unrolls this table at
code generation, so the ground's ``friction_law`` and a collider set's pick any entry by name (every
post-step response: the ground's projection, penalty friction and compliant contact, XPBD's ground, the
colliders; the barrier keeps IPC's own lagged friction); ``tests/test_contact_registry.py`` runs each on
the incline. For the default law the arithmetic is the one the kernels always had, bit for bit.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import warp as wp

from ._friction import friction_scale


@wp.func
def exact_coulomb_scale(speed: Any, budget: Any, stick_velocity: Any):
    """Unsmoothed Coulomb whatever ε_v: stopped if s ≤ b, (s − b)/s otherwise (a kink at s = b)."""
    return friction_scale(speed, budget, stick_velocity * type(stick_velocity)(0.0))


@dataclass(frozen=True)
class FrictionLaw:
    """One entry of :data:`FRICTION_LAWS`: ``scale`` is a ``wp.func`` (s, b, ε_v) → s'/s, ``code`` its
    integer in kernels (unique)."""

    name: str
    code: int
    scale: Callable[..., object]
    doc: str


#: name → law. "coulomb": the smoothed Coulomb law (C¹ through stick/slip, :mod:`._friction`), every
#: contact's default; "coulomb_exact": the same with ε_v = 0 (exact stick, a kink at the switch).
#: ``Ground.friction_law`` and ``Colliders(friction_law=)`` name one.
FRICTION_LAWS: dict[str, FrictionLaw] = {
    law.name: law
    for law in (
        FrictionLaw("coulomb", 0, friction_scale, "smoothed Coulomb (stick velocity ε_v)"),
        FrictionLaw("coulomb_exact", 1, exact_coulomb_scale, "unsmoothed Coulomb (ε_v ignored)"),
    )
}
_LAWS = tuple(FRICTION_LAWS.values())


def friction_law_code(name: str) -> int:
    """The kernel code of the law ``name``, or a ValueError listing the registered ones."""
    law = FRICTION_LAWS.get(name)
    if law is None:
        raise ValueError(f"friction_law must be one of {sorted(FRICTION_LAWS)}, got {name!r}")
    return law.code


@wp.func
def friction_law_scale(law: int, speed: Any, budget: Any, stick_velocity: Any):
    """s'/s of the registered law of code ``law`` (0 for an unknown code: the contact sticks)."""
    scale = speed * type(speed)(0.0)
    for k in range(wp.static(len(_LAWS))):
        if law == wp.static(_LAWS[k].code):
            scale = wp.static(_LAWS[k].scale)(speed, budget, stick_velocity)
    return scale


@wp.func
def friction_law_velocity(law: int, vt: Any, budget: Any, stick_velocity: Any):
    """The tangential velocity v_t' [m/s] after the law ``law``: ṽ_t scaled by :func:`friction_law_scale`."""
    return vt * friction_law_scale(law, wp.length(vt), budget, stick_velocity)
