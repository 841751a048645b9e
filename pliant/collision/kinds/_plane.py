"""The plane (a half space): through ``pos`` with unit outward normal ``aux``.

The model's ground (``Model.ground``, y = height) is this kind with n = +y; its responses keep their own
kernels (``collision/_ground.py``), written for that normal, so that the golden trajectories stay bit for
bit. A tilted plane, or one that moves, is a collider of this kind.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import warp as wp

from ._base import AUX_DIRECTION, ContactKind, Packed, vec3


@wp.func
def plane_sdf(pos: Any, aux: Any, rot: Any, radius: Any, mesh: wp.uint64, p: Any):
    """(φ, ∇φ, ∇²φ) of the half space below the plane: φ = n·(p − pos) − radius, ∇²φ = 0."""
    zero = radius * type(radius)(0.0)
    eye = wp.identity(n=3, dtype=type(radius))
    return wp.dot(aux, p - pos) - radius, aux, eye * zero


def pack_plane(point: Sequence[float], normal: Sequence[float] = (0.0, 1.0, 0.0)) -> Packed:
    """The plane through ``point`` [m] with outward ``normal`` (non-zero; normalised here)."""
    p = vec3(point, "plane point")
    n = vec3(normal, "plane normal")
    norm = float(np.linalg.norm(n))
    if norm == 0:
        raise ValueError("plane normal must be non-zero, got (0, 0, 0)")
    return Packed(p, n / norm, np.eye(3), 0.0, p)


def plane_floor() -> dict[str, Any]:
    """The plane y = 0."""
    return {"point": (0.0, 0.0, 0.0), "normal": (0.0, 1.0, 0.0)}


PLANE = ContactKind(
    "plane", 4, plane_sdf, pack_plane, plane_floor, AUX_DIRECTION, params=("point", "normal"), bounded=False
)
