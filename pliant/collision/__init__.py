"""Contact: ground plane, colliders (one file per kind: :mod:`.kinds`), friction laws, self-collision and
the broad phases they use."""

from ._collider_kernels import rigid_displacement
from ._collider_sdf import collider_sdf
from ._colliders import ColliderMotion, Colliders
from ._friction import friction_velocity
from ._friction_laws import (
    FRICTION_LAWS,
    FrictionLaw,
    friction_law_code,
    friction_law_scale,
    friction_law_velocity,
)
from ._ground import (
    ground_coefficients,
    ground_particle,
    ground_penalty_friction,
    ground_response,
    respond_to_ground,
)
from ._hashgrid import ParticleGrid, TriangleBVH, triangle_closest_point
from ._selfcollision import SelfCollision, closest_point_triangle
from ._step_bound import StepBound
from .kinds import CONTACT_KINDS, ContactKind

__all__ = [
    "CONTACT_KINDS",
    "ColliderMotion",
    "Colliders",
    "ContactKind",
    "FRICTION_LAWS",
    "FrictionLaw",
    "friction_law_code",
    "friction_law_scale",
    "friction_law_velocity",
    "friction_velocity",
    "SelfCollision",
    "StepBound",
    "closest_point_triangle",
    "collider_sdf",
    "ParticleGrid",
    "TriangleBVH",
    "ground_coefficients",
    "ground_particle",
    "ground_penalty_friction",
    "ground_response",
    "respond_to_ground",
    "rigid_displacement",
    "triangle_closest_point",
]
