"""An independent intersection test for triangle-mesh trajectories, by ipctk (the IPC Toolkit).

pliant's own contact code (``pliant.collision``) must not judge itself: this module asks ipctk's exact
edge–triangle intersection test (``ipctk.has_intersections``) whether any edge of the meshes passes through
any triangle of them, in each frame. One collision mesh holds every part — a cloth, a soft body's surface,
a triangulated collider — so both self-intersection and intersection between parts count. ipctk skips
pairs that share a vertex (an edge and the triangle it bounds), so a mesh at rest does not count.

Test-only: ipctk is in the ``test`` extras (pyproject.toml), not a dependency of pliant.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt


class Part:
    """One triangle mesh in the check: its triangles and its vertices in every frame (or fixed).

    Args:
        triangles: int [T, 3] vertex indices of the triangles.
        positions: [F, V, 3] vertex positions [m] per frame, or [V, 3] for a part that does not move.
    """

    def __init__(self, triangles: npt.ArrayLike, positions: npt.ArrayLike) -> None:
        tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        x = np.asarray(positions, dtype=np.float64)
        if x.ndim not in (2, 3) or x.shape[-1] != 3:
            raise ValueError(f"tests/intersections.py: positions must be [F, V, 3] or [V, 3], got {x.shape}")
        n = x.shape[-2]
        if tri.size and (tri.min() < 0 or tri.max() >= n):
            raise ValueError(f"tests/intersections.py: triangles index past the {n} vertices; fix the mesh")
        self.triangles = tri
        self.positions = x

    def frame(self, f: int) -> np.ndarray:
        """The [V, 3] positions [m] in frame ``f``."""
        return self.positions if self.positions.ndim == 2 else self.positions[f]

    @property
    def frames(self) -> int | None:
        """Number of frames; None for a fixed part."""
        return None if self.positions.ndim == 2 else self.positions.shape[0]


def intersecting_frames(parts: Sequence[Part]) -> list[int]:
    """The frames in which some edge of the parts passes through some triangle of them (ipctk).

    Args:
        parts: the meshes; the moving ones must share one frame count.

    Returns:
        The indices of the intersecting frames (empty: none intersects).
    """
    import ipctk

    counts = {p.frames for p in parts} - {None}
    if len(counts) > 1:
        raise ValueError(f"tests/intersections.py: parts have different frame counts {sorted(counts)}")
    n_frames = counts.pop() if counts else 1
    offsets = np.cumsum([0] + [p.positions.shape[-2] for p in parts])
    faces = np.concatenate([p.triangles + o for p, o in zip(parts, offsets[:-1], strict=True)]).astype(
        np.int32
    )
    edges = ipctk.edges(np.asfortranarray(faces))

    def stacked(f: int) -> np.ndarray:
        return np.asfortranarray(np.concatenate([p.frame(f) for p in parts]))

    mesh = ipctk.CollisionMesh(stacked(0), edges, np.asfortranarray(faces))
    return [f for f in range(n_frames) if ipctk.has_intersections(mesh, stacked(f))]


def grid_triangles(nx: int, ny: int) -> np.ndarray:
    """int [2 nx ny, 3]: the triangles of an (nx+1) × (ny+1) vertex grid, row-major (x fastest)."""
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="xy")
    a = (j * (nx + 1) + i).ravel()
    b, c, d = a + 1, a + nx + 1, a + nx + 2
    return np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def sphere_mesh(center: npt.ArrayLike, radius: float, subdivisions: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """A geodesic sphere (subdivided icosahedron): ([V, 3] vertices [m] on the sphere, int [T, 3])."""
    t = (1.0 + 5.0**0.5) / 2.0
    v = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
         [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
        dtype=np.float64,
    )  # fmt: skip
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
         [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11],
         [6, 2, 10], [8, 6, 7], [9, 8, 1]],
        dtype=np.int64,
    )  # fmt: skip
    for _ in range(subdivisions):
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(e, axis=0, return_inverse=True)
        mid = len(v) + inv.reshape(3, -1).T  # midpoints of (01, 12, 20) per face
        v = np.concatenate([v, 0.5 * (v[uniq[:, 0]] + v[uniq[:, 1]])])
        a, b, c = f.T
        ab, bc, ca = mid.T
        f = np.concatenate([np.stack(s, 1) for s in ((a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca))])
    v = v / np.linalg.norm(v, axis=1, keepdims=True)
    return np.asarray(center, dtype=np.float64) + radius * v, f
