"""Broad phase for particle–particle (``wp.HashGrid``) and point–triangle (``wp.Mesh`` BVH) queries."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
import warp as wp


@wp.func
def triangle_closest_point(p: Any, a: Any, b: Any, c: Any):
    """Barycentric (u, v, w) of the point of triangle abc closest to p (Ericson, RTCD §5.1.5)."""
    zero = type(p[0])(0.0)
    one = type(p[0])(1.0)
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = wp.dot(ab, ap)
    d2 = wp.dot(ac, ap)
    bp = p - b
    d3 = wp.dot(ab, bp)
    d4 = wp.dot(ac, bp)
    cp = p - c
    d5 = wp.dot(ab, cp)
    d6 = wp.dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    bary = type(p)(one, zero, zero)
    if d1 <= zero and d2 <= zero:
        bary = type(p)(one, zero, zero)
    elif d3 >= zero and d4 <= d3:
        bary = type(p)(zero, one, zero)
    elif vc <= zero and d1 >= zero and d3 <= zero:
        t = d1 / (d1 - d3)
        bary = type(p)(one - t, t, zero)
    elif d6 >= zero and d5 <= d6:
        bary = type(p)(zero, zero, one)
    elif vb <= zero and d2 >= zero and d6 <= zero:
        t = d2 / (d2 - d6)
        bary = type(p)(one - t, zero, t)
    elif va <= zero and (d4 - d3) >= zero and (d5 - d6) >= zero:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        bary = type(p)(zero, one - t, t)
    else:
        denom = one / (va + vb + vc)
        v = vb * denom
        w = vc * denom
        bary = type(p)(one - v - w, v, w)
    return bary


@wp.kernel(enable_backward=False)
def _to_float32(x_in: wp.array(dtype=Any), x_out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    x = x_in[i]
    x_out[i] = wp.vec3(wp.float32(x[0]), wp.float32(x[1]), wp.float32(x[2]))


class ParticleGrid:
    """A ``wp.HashGrid`` over particle positions for radius queries (particle–particle contacts).

    Args:
        device: Warp device.
        dtype: "float32" or "float64" (the grid stores points of that precision).
        cell_size: grid cell width [m]; queries with radius ≤ cell_size visit 27 cells.
        dims: hash table dimensions (cells per axis before wrapping).

    Example::

        grid = ParticleGrid("cpu", "float32", cell_size=0.02)
        grid.build(state.particle_q)
        # in a kernel: for j in wp.hash_grid_query(grid_id, x, radius): ...
    """

    def __init__(self, device: str, dtype: str, cell_size: float, dims: int = 128) -> None:
        if cell_size <= 0:
            raise ValueError(f"cell_size must be > 0 m, got {cell_size}")
        self.cell_size = float(cell_size)
        scalar = wp.float64 if dtype == "float64" else wp.float32
        self.grid = wp.HashGrid(dims, dims, dims, device=device, dtype=scalar)

    @property
    def id(self) -> int:
        """The grid handle for kernels (``wp.hash_grid_query``)."""
        return self.grid.id

    def build(self, points: wp.array) -> None:
        """Rebuild the grid over ``points`` (no host synchronisation)."""
        self.grid.build(points, self.cell_size)


class StepRunner(Protocol):
    """Runs a step's operations, e.g. recording them for replay (``pl.solvers.XPBD`` does)."""

    def launch(self, kernel: wp.Kernel, dim: int, inputs: list) -> None: ...
    def call(self, fn: Callable[..., object], *args: object) -> None: ...


class TriangleBVH:
    """A ``wp.Mesh`` BVH over deforming triangles for point–triangle queries.

    ``wp.Mesh`` stores float32 points, so positions are copied (and cast) into a private buffer before each
    refit; float64 models get float32 bounds, padded by the caller's query margin.

    Args:
        device: Warp device.
        tri_indices: triangles [T, 3] int.
        particle_count: number of points indexed by ``tri_indices``.
    """

    def __init__(self, device: str, tri_indices: np.ndarray, particle_count: int) -> None:
        tris = np.asarray(tri_indices, np.int32).reshape(-1, 3)
        self.device = device
        self.points = wp.zeros(particle_count, dtype=wp.vec3, device=device)
        self.indices: wp.array = wp.array(tris.reshape(-1), dtype=wp.int32, device=device)
        self.mesh = wp.Mesh(points=self.points, indices=self.indices)

    @property
    def id(self) -> int:
        """The mesh handle for kernels (``wp.mesh_query_aabb``)."""
        return self.mesh.id

    def update(self, points: wp.array, runner: StepRunner | None = None) -> None:
        """Copy ``points`` (any precision) and refit the BVH (no host synchronisation).

        ``runner`` (optional) provides ``launch(kernel, dim, inputs)`` and ``call(fn, *args)``, e.g. a
        solver that records its step for replay.
        """
        if runner is None:
            wp.launch(_to_float32, points.shape[0], [points, self.points], device=self.device)
            self.mesh.refit()
        else:
            runner.launch(_to_float32, points.shape[0], [points, self.points])
            runner.call(self.mesh.refit)
