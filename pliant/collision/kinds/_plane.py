"""The plane (a half space): through ``pos`` with unit outward normal ``aux``.

The model's ground (``Model.ground``, y = height) is this kind with n = +y: its post-step responses call
this kind's (``collision/_ground.py:ground_response``). A tilted plane, or one that moves, is a collider of
this kind.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import warp as wp

from ._base import AUX_DIRECTION, ContactKind, Packed, SceneParam, vec3


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


def draw_plane(
    point: Sequence[float], normal: Sequence[float] = (0.0, 1.0, 0.0), size: float = 4.0
) -> tuple[np.ndarray, np.ndarray]:
    """A square of side ``size`` [m] of the plane, centred on ``point`` [m] (two triangles facing out)."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    u = np.cross(n, (1.0, 0.0, 0.0) if abs(n[0]) < 0.9 else (0.0, 0.0, 1.0))
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    h = 0.5 * size
    v = np.asarray(point, float) + h * np.array([-u - w, u - w, u + w, -u + w])
    return v, np.array([[0, 2, 1], [0, 3, 2]])


PLANE = ContactKind(
    "plane",
    4,
    plane_sdf,
    pack_plane,
    plane_floor,
    AUX_DIRECTION,
    params=("point", "normal"),
    bounded=False,
    scene=(
        SceneParam("point", "vec3", (0.0, 0.0, 0.0), doc="a point of the plane"),
        SceneParam("normal", "vec3", (0.0, 1.0, 0.0), "-", "its outward normal (solid below)"),
        SceneParam("size", "length", 4.0, doc="side of the square drawn for it", draw_only=True),
    ),
    draw=draw_plane,
)
