"""The capsule: the segment ``pos``–``aux`` thickened by ``radius``."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import warp as wp

from ._base import AUX_POINT, ContactKind, Packed, SceneParam, curved_hessian, vec3


@wp.func
def capsule_sdf(pos: Any, aux: Any, rot: Any, radius: Any, mesh: wp.uint64, p: Any):
    """(φ, ∇φ, ∇²φ) of the capsule: the distance to the segment pos–aux, less the radius."""
    zero = radius * type(radius)(0.0)
    one = type(radius)(1.0)
    eye = wp.identity(n=3, dtype=type(radius))
    n = type(p)(zero, one, zero)
    ab = aux - pos
    t = wp.clamp(wp.dot(p - pos, ab) / wp.dot(ab, ab), zero, one)
    d = p - (pos + t * ab)
    l = wp.length(d)
    phi = l - radius
    if l > zero:
        n = d / l
    P = eye
    if t > zero and t < one:
        u = ab / wp.length(ab)
        P = eye - wp.outer(u, u)
    H = curved_hessian(P, n, l)
    return phi, n, H


def pack_capsule(a: Sequence[float], b: Sequence[float], radius: float) -> Packed:
    """A capsule around the segment ``a``–``b`` [m] (distinct ends), of ``radius`` [m] > 0."""
    pa, pb = vec3(a, "capsule a"), vec3(b, "capsule b")
    if not radius > 0:
        raise ValueError(f"capsule radius must be > 0 m, got {radius}")
    if np.linalg.norm(pb - pa) == 0:
        raise ValueError("capsule ends a and b coincide; give two different points (or use a sphere)")
    return Packed(pa, pb, np.eye(3), float(radius), 0.5 * (pa + pb))


def capsule_floor() -> dict[str, Any]:
    """A capsule of radius 10 km along x whose top line is y = 0, z = 0."""
    return {"a": (-50.0, -1.0e4, 0.0), "b": (50.0, -1.0e4, 0.0), "radius": 1.0e4}


def draw_capsule(a: Sequence[float], b: Sequence[float], radius: float) -> tuple[np.ndarray, np.ndarray]:
    """A 16 × 16 capsule [m] around the segment a–b."""
    import trimesh

    pa, pb = np.asarray(a, float), np.asarray(b, float)
    d = pb - pa
    m = trimesh.creation.capsule(height=float(np.linalg.norm(d)), radius=radius, count=[16, 16])
    rot = trimesh.geometry.align_vectors(np.array([0.0, 0.0, 1.0]), d / np.linalg.norm(d))[:3, :3]
    return m.vertices @ rot.T + 0.5 * (pa + pb), m.faces  # trimesh's capsule is centred at the origin


CAPSULE = ContactKind(
    "capsule",
    2,
    capsule_sdf,
    pack_capsule,
    capsule_floor,
    AUX_POINT,
    params=("a", "b", "radius"),
    scene=(
        SceneParam("a", "vec3", doc="one end of its axis segment"),
        SceneParam("b", "vec3", doc="the other end"),
        SceneParam("radius", "length", doc="its radius"),
    ),
    draw=draw_capsule,
)
