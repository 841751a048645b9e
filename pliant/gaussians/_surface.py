"""Deterministic Gaussians generated from a simulated object's surface, and a ring of cameras around it.

Used where a scene carries no Gaussians of its own (synthetic image observations, ``pliant observe
--cameras``, and the photometric fit that must render the same object): the same inputs always give the same
Gaussians, so observation and fit agree without any file passing between them.

- Surfaces (cloth, tet-mesh surfaces): one flat Gaussian per triangle at its centroid (or three, at the
  barycentric points (2/3, 1/6, 1/6) and permutations), its two large axes in the triangle's plane and a
  thin one along the normal, bound with the ``"triangles"`` binding (it stretches and turns with the
  triangle).
- No triangles (ropes, point clouds): one isotropic Gaussian per particle, bound by skinning (``"lbs"``).

The colours are a smooth procedural texture of the rest position, RGB_j = 0.5 + 0.35 sin(2π p·a_j / λ + φ_j)
with three fixed directions a_j and λ half the object's size, so that the images carry texture: motion
inside the silhouette changes the pixels, not only the outline.
"""

from __future__ import annotations

import math

import numpy as np

from ._bind import Binding, bind
from ._camera import Camera
from ._gaussians import Gaussians, _matrix_quats

#: Directions and phases of the procedural texture (fixed: observation and fit must agree).
_TEXTURE_DIRS = np.array([[0.8, 0.15, 0.58], [-0.3, 0.9, 0.31], [0.45, -0.4, -0.8]])
_TEXTURE_PHASE = np.array([0.3, 1.9, 4.1])

#: Background (RGB in [0, 1]) behind generated surface Gaussians in synthetic and fitted images.
GENERATED_BACKGROUND = (0.0, 0.0, 0.0)


def texture(points: np.ndarray, size: float) -> np.ndarray:
    """Procedural RGB in [0.15, 0.85] at rest positions ``points`` [m], shape [N, 3], for an object of
    extent ``size`` [m]."""
    lam = 0.5 * max(float(size), 1e-9)
    return 0.5 + 0.35 * np.sin(2.0 * math.pi * (points @ _TEXTURE_DIRS.T) / lam + _TEXTURE_PHASE)


def triangle_splats(
    rest_positions: np.ndarray, triangles: np.ndarray, *, size: float, per_triangle: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat Gaussians on surface triangles: their means, scales and rotations (the one generator of
    per-triangle splats, for scenes' ``[gaussians] generate = "mesh"`` and for :func:`surface_gaussians`).

    Each Gaussian's two large axes lie in its triangle's plane (the first along the edge v₀v₁) with standard
    deviation ``size`` · √(2·area) / √per_triangle (√(2·area) is a leg of a right isosceles triangle), and a
    thin one (5 %) along the normal: a surface, not a volume.

    Args:
        rest_positions: Particle positions [m], shape [P, 3].
        triangles: Triangles [F, 3] (particle indices).
        size: In-plane standard deviation relative to √(2·area) (dimensionless).
        per_triangle: 1 (at the centroid) or 3 (at the barycentric points (2/3, 1/6, 1/6) and permutations).

    Returns:
        (means [F·per_triangle, 3] [m], scales [F·per_triangle, 3] [m], quaternions wxyz [F·per_triangle, 4]).

    Raises:
        ValueError: a bad ``per_triangle``, or degenerate (zero-area) triangles.
    """
    if per_triangle not in (1, 3):
        raise ValueError(f"per_triangle must be 1 or 3, got {per_triangle}")
    v = np.asarray(rest_positions, dtype=np.float64)[np.asarray(triangles, dtype=np.int64).reshape(-1, 3)]
    e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    n = np.cross(e1, e2)
    area2 = np.linalg.norm(n, axis=1)  # twice the area
    if np.any(area2 <= 0.0):
        raise ValueError(f"{int(np.sum(area2 <= 0.0))} surface triangles are degenerate (zero area)")
    n /= area2[:, None]
    u = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
    R = np.stack([u, np.cross(n, u), n], axis=2)  # columns: in-plane u, in-plane w, normal
    if per_triangle == 1:
        bary = np.array([[1.0, 1.0, 1.0]]) / 3.0
    else:
        bary = np.array([[4.0, 1.0, 1.0], [1.0, 4.0, 1.0], [1.0, 1.0, 4.0]]) / 6.0
    means = np.einsum("bk,fkd->fbd", bary, v).reshape(-1, 3)
    # Neighbouring splats overlap and cover the surface without holes at size ≈ 0.3-0.5.
    s_in = np.repeat(size * np.sqrt(area2), per_triangle) / math.sqrt(per_triangle)
    scales = np.stack([s_in, s_in, 0.05 * s_in], axis=1)
    return means, scales, _matrix_quats(np.repeat(R, per_triangle, axis=0))


def particle_splats(rest_positions: np.ndarray, *, size: float) -> np.ndarray:
    """Isotropic standard deviations [m], shape [P], of one round Gaussian per particle (objects without a
    surface): ``size`` times the median distance between nearest particles (dimensionless ``size``)."""
    from scipy.spatial import cKDTree

    X = np.asarray(rest_positions, dtype=np.float64)
    extent = float(np.ptp(X, axis=0).max()) if len(X) else 0.0
    spacing = float(np.median(cKDTree(X).query(X, k=2)[0][:, 1])) if len(X) > 1 else 0.1 * extent
    return np.full(len(X), size * max(spacing, 1e-4))


def surface_gaussians(
    rest_positions: np.ndarray,
    triangles: np.ndarray | None = None,
    *,
    per_triangle: int = 1,
    opacity: float = 0.9,
    dtype: str = "float64",
    device: str | None = None,
) -> tuple[Gaussians, Binding]:
    """Gaussians on an object's surface (or at its particles) and their binding to the particles: the
    splats of scenes without a ``[gaussians]`` section (:func:`pliant.gaussians._scene.scene_gaussians`).

    Args:
        rest_positions: Particle positions [m] at rest, shape [P, 3].
        triangles: Surface triangles [F, 3] (particle indices), or None / empty for one Gaussian per
            particle bound by linear blend skinning.
        per_triangle: 1 (at the centroid) or 3 (at the barycentric points (2/3, 1/6, 1/6) and permutations).
        opacity: Opacity of every Gaussian, in (0, 1).
        dtype: ``"float32"`` / ``"float64"`` (the simulation's, so gradients flow into its positions).
        device: Warp device.

    Returns:
        (the Gaussians at rest, a :class:`Binding` whose ``deform(particle_q)`` places them).

    Raises:
        ValueError: a bad ``per_triangle``, or degenerate triangles.
    """
    X = np.asarray(rest_positions, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3 or len(X) == 0:
        raise ValueError(f"rest_positions must have shape [P, 3] with P > 0, got {X.shape}")
    size = float(np.ptp(X, axis=0).max()) or 1.0
    tris = None if triangles is None else np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if tris is None or len(tris) == 0:
        g = Gaussians.from_values(
            X,
            scales=particle_splats(X, size=0.6),
            opacities=opacity,
            colors=texture(X, size),
            dtype=dtype,
            device=device,
        )
        return g, bind(g, X, method="lbs", k=min(4, len(X)), neighbours=min(8, len(X)))
    # 0.42 √area: the in-plane σ that covers a cloth's triangles without holes or blur (size 0.42 / √2).
    means, scales, quats = triangle_splats(X, tris, size=0.42 * math.sqrt(0.5), per_triangle=per_triangle)
    g = Gaussians.from_values(
        means,
        scales=scales,
        rotations=quats,
        opacities=opacity,
        colors=texture(means, size),
        dtype=dtype,
        device=device,
    )
    return g, bind(g, X, method="triangles", triangles=tris)


def object_surface(model: object) -> np.ndarray | None:
    """The triangles to put Gaussians on: the model's drawn surface (``render_faces``), else its
    simulation triangles (``tri_indices``), else None (particles only)."""
    faces = np.asarray(getattr(model, "render_faces", np.zeros((0, 3))))
    if len(faces):
        return faces.reshape(-1, 3)
    tris = getattr(model, "tri_indices", None)
    if tris is not None and tris.shape[0]:
        return tris.numpy().reshape(-1, 3)
    return None


def ring_cameras(
    points: np.ndarray,
    count: int = 3,
    *,
    width: int = 96,
    height: int = 72,
    elevation: float = 35.0,
    fov_y: float = 50.0,
    up: tuple[float, float, float] = (0.0, 1.0, 0.0),
) -> list[Camera]:
    """``count`` cameras evenly spaced around the bounding sphere of ``points``, all seeing all of it.

    Args:
        points: Positions [m] to frame, any shape [..., 3] (e.g. a whole trajectory [T, N, 3]).
        count: Number of cameras (at azimuths 30° + 360°·c / count about ``up``).
        width: Image width [px].
        height: Image height [px].
        elevation: Angle above the horizontal plane [degrees].
        fov_y: Vertical field of view [degrees].
        up: World up direction (pliant's scenes are y-up).

    Returns:
        The cameras (OpenCV convention, pixel centres at integers).
    """
    if count < 1:
        raise ValueError(f"--cameras: expected at least 1 camera, got {count}")
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo, hi = p.min(axis=0), p.max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-3)
    half = 0.5 * math.radians(fov_y)
    half = min(half, math.atan(math.tan(half) * width / height))  # the narrower of the two fields of view
    dist = 1.1 * radius / math.sin(half)
    up_v = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    # Two horizontal axes orthogonal to up.
    a = np.cross(up_v, [1.0, 0.0, 0.0] if abs(up_v[0]) < 0.9 else [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(up_v, a)
    el = math.radians(elevation)
    cams = []
    for c in range(count):
        az = math.radians(30.0 + 360.0 * c / count)
        d = math.cos(el) * (math.cos(az) * a + math.sin(az) * b) + math.sin(el) * up_v
        cams.append(
            Camera.look_at(centre + dist * d, centre, up=up_v, fov_y=fov_y, width=width, height=height)
        )
    return cams


__all__ = [
    "GENERATED_BACKGROUND",
    "object_surface",
    "particle_splats",
    "ring_cameras",
    "surface_gaussians",
    "texture",
    "triangle_splats",
]
