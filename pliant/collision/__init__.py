"""Contact: ground plane (more colliders and the hash-grid broad phase follow)."""

from ._collider_sdf import collider_sdf
from ._colliders import Colliders
from ._ground import ground_contact, ground_penalty_friction
from ._hashgrid import ParticleGrid, TriangleBVH, triangle_closest_point
from ._selfcollision import SelfCollision, closest_point_triangle

__all__ = [
    "Colliders",
    "SelfCollision",
    "closest_point_triangle",
    "collider_sdf",
    "ParticleGrid",
    "TriangleBVH",
    "ground_contact",
    "ground_penalty_friction",
    "triangle_closest_point",
]
