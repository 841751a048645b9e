"""The contact-kind registry: one file per kind, one line per kind in :data:`CONTACT_KINDS`.

A new kind is a file giving a :class:`ContactKind` (its ``wp.func`` signed distance, its ``pack``, its scene
keys and its drawing) and its line below: scene files name it with no other change (``pliant.scene``
builds its ``[[colliders]]`` schema from the declaration). :func:`pliant.collision.collider_sdf` unrolls
this table at code generation, so every response (the projection after a step, compliant contact, the
penalty and barrier energies, XPBD's post-step pass) handles the new kind, and
``tests/test_contact_registry.py`` walks it: every kind implements every interface, and rests or slides on
a 1:2 incline as Coulomb says in every solver family.
The table is read when the first kernel is generated: register before the first step.
"""

from __future__ import annotations

from ._base import (
    AUX_DIRECTION,
    AUX_FIXED,
    AUX_POINT,
    REQUIRED,
    SCENE_TYPES,
    ContactKind,
    Packed,
    SceneParam,
    rotation_matrix,
    vec3,
)
from ._box import BOX
from ._capsule import CAPSULE
from ._mesh import MESH
from ._plane import PLANE
from ._sphere import SPHERE

#: name → kind; each kind's ``code`` is its value in the device arrays.
CONTACT_KINDS: dict[str, ContactKind] = {k.name: k for k in (SPHERE, BOX, CAPSULE, MESH, PLANE)}

__all__ = [
    "AUX_DIRECTION",
    "AUX_FIXED",
    "AUX_POINT",
    "CONTACT_KINDS",
    "ContactKind",
    "Packed",
    "REQUIRED",
    "SCENE_TYPES",
    "SceneParam",
    "rotation_matrix",
    "vec3",
]
