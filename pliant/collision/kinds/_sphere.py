"""The sphere: centre ``pos``, radius ``radius``."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import warp as wp

from ._base import ContactKind, Packed, SceneParam, curved_hessian, vec3


@wp.func
def sphere_sdf(pos: Any, aux: Any, rot: Any, radius: Any, mesh: wp.uint64, p: Any):
    """(φ, ∇φ, ∇²φ) of the sphere |p − pos| = radius."""
    zero = radius * type(radius)(0.0)
    one = type(radius)(1.0)
    eye = wp.identity(n=3, dtype=type(radius))
    n = type(p)(zero, one, zero)
    d = p - pos
    l = wp.length(d)
    phi = l - radius
    if l > zero:
        n = d / l
    H = curved_hessian(eye, n, l)
    return phi, n, H


def pack_sphere(center: Sequence[float], radius: float) -> Packed:
    """A sphere of centre ``center`` [m] and ``radius`` [m] > 0."""
    if not radius > 0:
        raise ValueError(f"sphere radius must be > 0 m, got {radius}")
    c = vec3(center, "sphere center")
    return Packed(c, np.zeros(3), np.eye(3), float(radius), c)


def sphere_floor() -> dict[str, Any]:
    """A sphere of radius 10 km whose top is the origin (it drops 1.25 mm at 5 m: flat enough)."""
    return {"center": (0.0, -1.0e4, 0.0), "radius": 1.0e4}


def draw_sphere(center: Sequence[float], radius: float) -> tuple[np.ndarray, np.ndarray]:
    """An icosphere (level 3: 642 vertices) of ``radius`` [m] about ``center`` [m]."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    return m.vertices + np.asarray(center), m.faces


SPHERE = ContactKind(
    "sphere",
    0,
    sphere_sdf,
    pack_sphere,
    sphere_floor,
    params=("center", "radius"),
    scene=(
        SceneParam("center", "vec3", (0.0, 0.0, 0.0), doc="its centre"),
        SceneParam("radius", "length", doc="its radius"),
    ),
    draw=draw_sphere,
)
