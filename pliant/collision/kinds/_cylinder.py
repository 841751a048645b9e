"""The capped cylinder: centre ``pos``, axis the local y of ``rot``, ``aux`` = (radius, half height, 0)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
import warp as wp

from ._base import ContactKind, Packed, SceneParam, curved_hessian, rotation_matrix, vec3


@wp.func
def cylinder_sdf(pos: Any, aux: Any, rot: Any, radius: Any, mesh: wp.uint64, p: Any):
    """(φ, ∇φ, ∇²φ) of the capped cylinder: the side's Hessian is a line's, the caps' and the rims' 0
    (exact on the caps, Gauss–Newton on the rims)."""
    zero = radius * type(radius)(0.0)
    one = type(radius)(1.0)
    eye = wp.identity(n=3, dtype=type(radius))
    up = type(p)(zero, one, zero)
    pl = wp.transpose(rot) * (p - pos)
    rho = wp.sqrt(pl[0] * pl[0] + pl[2] * pl[2])
    radial = type(p)(one, zero, zero)
    if rho > zero:
        radial = type(p)(pl[0] / rho, zero, pl[2] / rho)
    dx = rho - aux[0]
    dy = wp.abs(pl[1]) - aux[1]
    axial = up * wp.sign(pl[1])
    H = eye * zero
    nl = axial
    phi = dy
    if dx > zero and dy > zero:  # beyond a rim: the distance to the circle
        l = wp.sqrt(dx * dx + dy * dy)
        nl = (dx * radial + dy * axial) / l
        phi = l
    elif dx > zero:  # beside the side: the distance to the axis less the radius
        nl = radial
        phi = dx
        H = rot * curved_hessian(eye - wp.outer(up, up), radial, rho) * wp.transpose(rot)
    elif dx > dy:  # inside, nearest the side
        nl = radial
        phi = dx
    return phi - radius, rot * nl, H


def pack_cylinder(
    center: Sequence[float], radius: float, half_height: float, rotation: npt.ArrayLike | None = None
) -> Packed:
    """A cylinder of centre ``center`` [m], ``radius`` [m] > 0 and ``half_height`` [m] > 0 along the y axis
    of ``rotation`` (world from cylinder: 3×3 or (x, y, z, w); None: upright)."""
    if not radius > 0:
        raise ValueError(f"cylinder radius must be > 0 m, got {radius}")
    if not half_height > 0:
        raise ValueError(f"cylinder half_height must be > 0 m, got {half_height}")
    c = vec3(center, "cylinder center")
    aux = np.array([radius, half_height, 0.0], dtype=np.float64)
    return Packed(c, aux, rotation_matrix(rotation, "cylinder rotation"), 0.0, c)


def cylinder_floor() -> dict[str, Any]:
    """A disc of radius 50 m and 1 m thick whose top is y = 0."""
    return {"center": (0.0, -0.5, 0.0), "radius": 50.0, "half_height": 0.5}


def draw_cylinder(
    center: Sequence[float], radius: float, half_height: float, rotation: npt.ArrayLike | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """A 32-sided cylinder [m]."""
    import trimesh

    m = trimesh.creation.cylinder(radius=radius, height=2.0 * half_height, sections=32)
    v = m.vertices[:, [0, 2, 1]] * (1.0, 1.0, -1.0)  # trimesh's axis z onto y (a proper rotation)
    return v @ rotation_matrix(rotation).T + np.asarray(center), m.faces


CYLINDER = ContactKind(
    "cylinder",
    5,
    cylinder_sdf,
    pack_cylinder,
    cylinder_floor,
    params=("center", "radius", "half_height", "rotation"),
    scene=(
        SceneParam("center", "vec3", (0.0, 0.0, 0.0), doc="its centre"),
        SceneParam("radius", "length", doc="its radius"),
        SceneParam("half_height", "length", doc="half its length along its axis"),
        SceneParam("rotation", "quaternion", None, "-", "world from cylinder (axis y); absent: upright"),
    ),
    draw=draw_cylinder,
)
