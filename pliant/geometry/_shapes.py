"""Procedural rope and cloth."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._arrays import as_vec3
from ._topology import bending_pairs as _bending_pairs

_AXES = {"x": 0, "y": 1, "z": 2}
_PLANES = ("xz", "xy", "yz")


@dataclass
class Rope:
    """A straight polyline of evenly spaced points.

    Attributes:
        points: Positions [N, 3] float64 (m), N = n_segments + 1, ordered from ``start``.
        edges: Consecutive pairs (i, i+1) [N-1, 2] int32.
        bend_edges: Second neighbours (i, i+2) [N-2, 2] int32, for bending springs.
    """

    points: NDArray[np.float64]
    edges: NDArray[np.int32]
    bend_edges: NDArray[np.int32]


def rope(
    n_segments: int,
    length: float,
    start: ArrayLike = (0.0, 0.0, 0.0),
    direction: ArrayLike = (1.0, 0.0, 0.0),
) -> Rope:
    """Straight rope of ``n_segments`` equal segments.

    Args:
        n_segments: Number of segments (>= 1); the rope has ``n_segments + 1`` points.
        length: Total length (m), > 0.
        start: Position of point 0 (m).
        direction: Direction from the first to the last point; normalised here.

    Returns:
        The :class:`Rope`.
    """
    if int(n_segments) != n_segments or n_segments < 1:
        raise ValueError(f"rope: n_segments must be an integer >= 1, got {n_segments!r}")
    if not np.isfinite(length) or length <= 0:
        raise ValueError(f"rope: length must be a positive number of metres, got {length!r}")
    n_segments = int(n_segments)
    d = as_vec3(direction, "rope direction")
    norm = np.linalg.norm(d)
    if norm == 0:
        raise ValueError("rope: direction must be non-zero")
    s = np.linspace(0.0, float(length), n_segments + 1)
    points = as_vec3(start, "rope start") + s[:, None] * (d / norm)
    i = np.arange(n_segments + 1, dtype=np.int32)
    edges = np.stack([i[:-1], i[1:]], axis=1)
    bend = np.stack([i[:-2], i[2:]], axis=1)
    return Rope(points=points, edges=edges, bend_edges=bend)


@dataclass
class ClothGrid:
    """A rectangular triangulated cloth.

    The ``plane`` string names the two in-plane axes ``(u, v)`` in order: ``"xz"`` ->
    (x, z), ``"xy"`` -> (x, y), ``"yz"`` -> (y, z). Vertex ``(i, j)`` (i along u,
    j along v) has index ``j * (nx + 1) + i``. "Left"/"right" mean min/max u and
    "bottom"/"top" mean min/max v, so for ``"xz"`` the top edge is the max-z row and
    for ``"xy"`` it is the max-y row (the one to pin for a cloth hanging under y-up
    gravity).

    Triangle normals point along the positive axis normal to the plane: +y for
    ``"xz"``, +z for ``"xy"``, +x for ``"yz"``. Cell diagonals alternate in a
    checkerboard so the cloth has no preferred shear direction.

    Attributes:
        points: Positions [(nx+1)(ny+1), 3] float64 (m).
        triangles: [2 nx ny, 3] int32, consistently wound (see above).
        structural: Grid-neighbour springs along u and v [nx(ny+1) + ny(nx+1), 2] int32.
        shear: Both diagonals of every cell [2 nx ny, 2] int32.
        bend: Distance-2 springs along rows and columns [(nx-1)(ny+1) + (ny-1)(nx+1), 2] int32.
        bending_pairs: (e0, e1, o0, o1) per interior edge [3 nx ny - nx - ny, 4] int32,
            see :func:`pliant.geometry.bending_pairs`.
        corner_indices: Vertex index of "bottom-left", "bottom-right", "top-left", "top-right".
        nx: Cells along u.
        ny: Cells along v.
        plane: The plane string.
    """

    points: NDArray[np.float64]
    triangles: NDArray[np.int32]
    structural: NDArray[np.int32]
    shear: NDArray[np.int32]
    bend: NDArray[np.int32]
    bending_pairs: NDArray[np.int32]
    corner_indices: dict[str, int]
    nx: int
    ny: int
    plane: str

    @property
    def springs(self) -> NDArray[np.int32]:
        """Structural, shear and bend springs stacked [S, 2] int32."""
        return np.concatenate([self.structural, self.shear, self.bend])

    def pin_indices(self, name: str) -> NDArray[np.int32]:
        """Vertex indices of a named set, for pinning.

        Args:
            name: One of the corner names ("top-left", "top-right", "bottom-left",
                "bottom-right"); "top-corners", "bottom-corners", "left-corners",
                "right-corners", "corners"; "top-edge", "bottom-edge", "left-edge",
                "right-edge", "boundary"; or "none".

        Returns:
            Sorted unique vertex indices [K] int32.
        """
        # g[j, i]: j along v (bottom -> top), i along u (left -> right).
        g = np.arange((self.nx + 1) * (self.ny + 1)).reshape(self.ny + 1, self.nx + 1)
        c = self.corner_indices
        sets: dict[str, Sequence[int] | NDArray[np.integer]] = {
            **{k: [v] for k, v in c.items()},
            "top-corners": [c["top-left"], c["top-right"]],
            "bottom-corners": [c["bottom-left"], c["bottom-right"]],
            "left-corners": [c["bottom-left"], c["top-left"]],
            "right-corners": [c["bottom-right"], c["top-right"]],
            "corners": list(c.values()),
            "top-edge": g[-1, :],
            "bottom-edge": g[0, :],
            "left-edge": g[:, 0],
            "right-edge": g[:, -1],
            "boundary": np.concatenate([g[0, :], g[-1, :], g[:, 0], g[:, -1]]),
            "none": [],
        }
        if name not in sets:
            raise ValueError(f"unknown pin set {name!r}; choose one of: {', '.join(sorted(sets))}")
        return np.unique(np.asarray(sets[name], dtype=np.int32))


def _pairs(a: NDArray[np.int32], b: NDArray[np.int32]) -> NDArray[np.int32]:
    return np.stack([a.reshape(-1), b.reshape(-1)], axis=1)


def cloth_grid(
    nx: int,
    ny: int,
    size: float | Sequence[float] = (1.0, 1.0),
    origin: ArrayLike = (0.0, 0.0, 0.0),
    plane: str = "xz",
) -> ClothGrid:
    """Rectangular cloth of ``nx`` x ``ny`` cells, each split into two triangles.

    Args:
        nx: Cells along the first in-plane axis u (>= 1).
        ny: Cells along the second in-plane axis v (>= 1).
        size: Extent (m) along (u, v), or one number for a square.
        origin: Position of the bottom-left vertex (min u, min v) (m).
        plane: "xz", "xy" or "yz"; see :class:`ClothGrid` for axis and naming conventions.

    Returns:
        The :class:`ClothGrid` with (nx+1)(ny+1) vertices and 2 nx ny triangles.
    """
    for name, n in (("nx", nx), ("ny", ny)):
        if int(n) != n or n < 1:
            raise ValueError(f"cloth_grid: {name} must be an integer >= 1 (number of cells), got {n!r}")
    nx, ny = int(nx), int(ny)
    if plane not in _PLANES:
        raise ValueError(f"cloth_grid: plane must be one of {_PLANES}, got {plane!r}")
    sizes = np.atleast_1d(np.asarray(size, dtype=float))  # one number: a square
    su, sv = float(sizes[0]), float(sizes[1] if sizes.size > 1 else sizes[0])
    if not (np.isfinite(su) and np.isfinite(sv) and su > 0 and sv > 0):
        raise ValueError(f"cloth_grid: size must be positive (m), got {size!r}")
    ax_u, ax_v = _AXES[plane[0]], _AXES[plane[1]]

    g = np.arange((nx + 1) * (ny + 1), dtype=np.int32).reshape(ny + 1, nx + 1)
    jj, ii = np.divmod(g.reshape(-1), nx + 1)
    points = np.zeros((g.size, 3))
    points[:, ax_u] = ii * (su / nx)
    points[:, ax_v] = jj * (sv / ny)
    points += as_vec3(origin, "cloth_grid origin")

    # Cell corners counter-clockwise in (u, v): a=(i,j), b=(i+1,j), c=(i+1,j+1), d=(i,j+1).
    a, b, c, d = g[:-1, :-1], g[:-1, 1:], g[1:, 1:], g[1:, :-1]
    ci, cj = np.meshgrid(np.arange(nx), np.arange(ny))
    diag_ac = ((ci + cj) % 2 == 0)[..., None]
    t0 = np.where(diag_ac, np.stack([a, b, c], -1), np.stack([a, b, d], -1))
    t1 = np.where(diag_ac, np.stack([a, c, d], -1), np.stack([b, c, d], -1))
    tris = np.stack([t0, t1], axis=2).reshape(-1, 3).astype(np.int32)
    # CCW in (u, v) gives normal u x v, which is -y for "xz"; reverse to get +y there.
    if np.cross(np.eye(3)[ax_u], np.eye(3)[ax_v]).sum() < 0:
        tris = tris[:, [0, 2, 1]]

    structural = np.concatenate([_pairs(g[:, :-1], g[:, 1:]), _pairs(g[:-1, :], g[1:, :])])
    shear = np.concatenate([_pairs(a, c), _pairs(b, d)])
    bend = np.concatenate([_pairs(g[:, :-2], g[:, 2:]), _pairs(g[:-2, :], g[2:, :])])
    corners = {
        "bottom-left": int(g[0, 0]),
        "bottom-right": int(g[0, -1]),
        "top-left": int(g[-1, 0]),
        "top-right": int(g[-1, -1]),
    }
    return ClothGrid(
        points=points,
        triangles=tris,
        structural=structural.astype(np.int32),
        shear=shear.astype(np.int32),
        bend=bend.astype(np.int32),
        bending_pairs=_bending_pairs(tris),
        corner_indices=corners,
        nx=nx,
        ny=ny,
        plane=plane,
    )
