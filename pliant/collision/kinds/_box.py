"""The box: centre ``pos``, half extents ``aux``, rotation ``rot`` (world from box), rounded by ``radius``."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
import warp as wp

from ._base import ContactKind, Packed, SceneParam, curved_hessian, rotation_matrix, vec3


@wp.func
def box_sdf(pos: Any, aux: Any, rot: Any, radius: Any, mesh: wp.uint64, p: Any):
    """(φ, ∇φ, ∇²φ) of the rounded box; inside, the nearest face's distance (∇²φ = 0)."""
    zero = radius * type(radius)(0.0)
    one = type(radius)(1.0)
    eye = wp.identity(n=3, dtype=type(radius))
    n = type(p)(zero, one, zero)
    H = eye * zero
    phi = zero
    pl = wp.transpose(rot) * (p - pos)
    q = type(p)(wp.abs(pl[0]) - aux[0], wp.abs(pl[1]) - aux[1], wp.abs(pl[2]) - aux[2])
    qmax = wp.max(q[0], wp.max(q[1], q[2]))
    if qmax > zero:
        qp = type(p)(wp.max(q[0], zero), wp.max(q[1], zero), wp.max(q[2], zero))
        rho = wp.length(qp)
        nl = type(p)(wp.sign(pl[0]) * qp[0], wp.sign(pl[1]) * qp[1], wp.sign(pl[2]) * qp[2]) / rho
        P = eye * zero
        for a in range(3):
            if q[a] > zero:
                P[a, a] = one
        n = rot * nl
        H = rot * curved_hessian(P, nl, rho) * wp.transpose(rot)
        phi = rho - radius
    else:
        axis = 0
        if q[1] >= q[0] and q[1] >= q[2]:
            axis = 1
        elif q[2] >= q[0] and q[2] >= q[1]:
            axis = 2
        nl = type(p)(zero, zero, zero)
        nl[axis] = wp.sign(pl[axis])
        n = rot * nl
        phi = qmax - radius
    return phi, n, H


def pack_box(
    center: Sequence[float],
    half_extents: Sequence[float],
    rotation: npt.ArrayLike | None = None,
    rounding: float = 0.0,
) -> Packed:
    """A box of centre ``center`` [m], ``half_extents`` [m] > 0, world-from-box ``rotation`` (3×3 or
    (x, y, z, w); None: axis aligned), its surface offset outwards by ``rounding`` [m] >= 0."""
    he = vec3(half_extents, "box half_extents")
    if np.any(he <= 0):
        raise ValueError(f"box half_extents must be > 0 m, got {half_extents}")
    if not rounding >= 0:
        raise ValueError(f"box rounding must be >= 0 m, got {rounding}")
    c = vec3(center, "box center")
    return Packed(c, he, rotation_matrix(rotation), float(rounding), c)


def box_floor() -> dict[str, Any]:
    """A 100 m × 1 m × 100 m slab whose top face is y = 0."""
    return {"center": (0.0, -0.5, 0.0), "half_extents": (50.0, 0.5, 50.0)}


def draw_box(
    center: Sequence[float],
    half_extents: Sequence[float],
    rotation: npt.ArrayLike | None = None,
    rounding: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The box's 8 corners and 12 triangles [m] (its rounding is not drawn)."""
    import trimesh

    m = trimesh.creation.box(extents=2.0 * np.asarray(half_extents))
    return m.vertices @ rotation_matrix(rotation).T + np.asarray(center), m.faces


BOX = ContactKind(
    "box",
    1,
    box_sdf,
    pack_box,
    box_floor,
    params=("center", "half_extents", "rotation", "rounding"),
    scene=(
        SceneParam("center", "vec3", (0.0, 0.0, 0.0), doc="its centre"),
        SceneParam("half_extents", "size3", doc="half its side lengths along its own axes"),
        SceneParam("rotation", "quaternion", None, "-", "world from box; absent: axis aligned"),
        SceneParam("rounding", "nonneg", 0.0, doc="outward offset of its surface (rounded edges)"),
    ),
    draw=draw_box,
)
