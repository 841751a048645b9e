"""The closed triangle mesh: a ``wp.Mesh`` (float32 BVH) in its own frame, placed at ``pos`` with ``rot``.

The BVH holds the vertices as given; a point is queried in the mesh's frame, rotᵀ(p − pos), so that a
moving mesh needs no refit. A static mesh has pos = 0 and rot = I, for which the query point and the normal
are the world's exactly (1·x + 0·y + 0·z = x in floating point).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
import warp as wp

from ._base import ContactKind, Packed, SceneParam


@wp.func
def mesh_sdf(pos: Any, aux: Any, rot: Any, radius: Any, mesh: wp.uint64, p: Any):
    """(φ, ∇φ, ∇²φ) of the mesh by a closest-point query (sign from the winding; ∇²φ = 0: exact on faces,
    Gauss–Newton elsewhere)."""
    zero = radius * type(radius)(0.0)
    one = type(radius)(1.0)
    eye = wp.identity(n=3, dtype=type(radius))
    n = type(p)(zero, one, zero)
    H = eye * zero
    phi = zero
    pm = wp.transpose(rot) * (p - pos)
    pf = wp.vec3f(wp.float32(pm[0]), wp.float32(pm[1]), wp.float32(pm[2]))
    qr = wp.mesh_query_point(mesh, pf, wp.float32(1.0e6))
    if qr.result:
        cpf = wp.mesh_eval_position(mesh, qr.face, qr.u, qr.v)
        cp = type(p)(type(zero)(cpf[0]), type(zero)(cpf[1]), type(zero)(cpf[2]))
        d = pm - cp
        l = wp.length(d)
        s = type(zero)(qr.sign)
        phi = s * l - radius
        if l > type(zero)(1.0e-9):
            n = rot * (s * d / l)
        else:
            nf = wp.mesh_eval_face_normal(mesh, qr.face)
            n = rot * type(p)(type(zero)(nf[0]), type(zero)(nf[1]), type(zero)(nf[2]))
    else:
        phi = type(zero)(1.0e6)
    return phi, n, H


def pack_mesh() -> Packed:
    """A mesh's device values: its own frame (the vertices are given in world coordinates)."""
    return Packed(np.zeros(3), np.zeros(3), np.eye(3), 0.0, np.zeros(3))


def mesh_floor() -> dict[str, Any]:
    """A 20 m × 1 m × 20 m closed box mesh (12 outward-wound triangles) whose top face is y = 0."""
    lo, hi = np.array([-10.0, -1.0, -10.0]), np.array([10.0, 0.0, 10.0])
    corners = np.array([[(lo, hi)[(k >> a) & 1][a] for a in range(3)] for k in range(8)])
    quads = [(0, 2, 6, 4), (1, 5, 7, 3), (0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6)]
    faces = [t for a, b, c, d in quads for t in ((a, c, b), (a, d, c))]
    return {"vertices": corners, "faces": np.array(faces)}


def mesh_from_scene(
    path: tuple[np.ndarray, np.ndarray],
    scale: npt.ArrayLike = (1.0, 1.0, 1.0),
    origin: npt.ArrayLike = (0.0, 0.0, 0.0),
) -> dict[str, Any]:
    """The scene's surface (read as (vertices, faces)) scaled, then moved to ``origin`` [m]."""
    v, f = path
    return {"vertices": np.asarray(v, float) * np.asarray(scale) + np.asarray(origin), "faces": np.asarray(f)}


def draw_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh itself."""
    return vertices, faces


MESH = ContactKind(
    "mesh",
    3,
    mesh_sdf,
    pack_mesh,
    mesh_floor,
    params=("vertices", "faces"),
    scene=(
        SceneParam("path", "surface", unit="-", doc="a closed, outward-wound surface file"),
        SceneParam("scale", "scale3", (1.0, 1.0, 1.0), "-", "factors applied to its vertices"),
        SceneParam("origin", "vec3", (0.0, 0.0, 0.0), doc="translation after scaling"),
    ),
    draw=draw_mesh,
    from_scene=mesh_from_scene,
)
