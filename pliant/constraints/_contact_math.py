"""The maths of the contact constraints (C and ∇C ``@wp.func``s) and the kernels that evaluate them.

Kept below :mod:`._contact` (which imports it) so that the projection kernels and ``evaluate`` — the
contract tests' view of C and ∇C — call the same funcs.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

if TYPE_CHECKING:
    from ..collision import ParticleGrid
    from ..model import Model
    from ._contact import PointTriangleCollision


# ---------------------------------------------------------------------- ground
@wp.func
def ground_c(x: Any, normal: Any, d: Any, radius: Any):
    """C(x) = n·x + d − r ≥ 0  [m] (the lecture's ground constraint, plane n·x + d = 0)."""
    return wp.dot(normal, x) + d - radius


@wp.func
def ground_grad(x: Any, normal: Any):
    """∇C = n."""
    return normal


# ---------------------------------------------------------------------- particle–particle
@wp.func
def particle_collision_c(xi: Any, xj: Any, ri: Any, rj: Any):
    """C(x_i, x_j) = |x_i − x_j| − r_i − r_j ≥ 0  [m]."""
    return wp.length(xi - xj) - ri - rj


# ---------------------------------------------------------------------- point–triangle
@wp.func
def point_triangle_c(q: Any, x1: Any, x2: Any, x3: Any, side: Any, h: Any):
    """C = s (q − x1)·n̂ − h ≥ 0, n̂ = (x2 − x1)×(x3 − x1)/|·|, s = ±1 the side q started on  [m]."""
    n = wp.cross(x2 - x1, x3 - x1)
    ln = wp.length(n)
    if ln == type(h)(0.0):
        return type(h)(0.0)
    return side * wp.dot(q - x1, n) / ln - h


@wp.func
def point_triangle_grad(q: Any, x1: Any, x2: Any, x3: Any, side: Any):
    """∇_q = s n̂, ∇_2 = s b×u, ∇_3 = s u×a, ∇_1 = −Σ; a = x2 − x1, b = x3 − x1, u = (I − n̂n̂ᵀ)r/|a×b|."""
    a = x2 - x1
    b = x3 - x1
    n = wp.cross(a, b)
    ln = wp.length(n)
    zero = type(side)(0.0)
    gq = n * zero
    g2 = n * zero
    g3 = n * zero
    if ln > zero:
        nh = n / ln
        r = q - x1
        u = (r - wp.dot(r, nh) * nh) / ln
        gq = side * nh
        g2 = side * wp.cross(b, u)
        g3 = side * wp.cross(u, a)
    return gq, -(gq + g2 + g3), g2, g3


@wp.func
def plane_barycentric(q: Any, a: Any, b: Any, c: Any):
    """Barycentric (u, v, w) of the projection of q onto the plane of triangle abc."""
    v0 = b - a
    v1 = c - a
    v2 = q - a
    d00 = wp.dot(v0, v0)
    d01 = wp.dot(v0, v1)
    d11 = wp.dot(v1, v1)
    d20 = wp.dot(v2, v0)
    d21 = wp.dot(v2, v1)
    den = d00 * d11 - d01 * d01
    one = type(d00)(1.0)
    if den == type(d00)(0.0):
        return type(q)(-one, -one, -one)
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return type(q)(one - v - w, v, w)


# ---------------------------------------------------------------------- evaluation (C and ∇C per contact)
@wp.kernel(enable_backward=False)
def _ground_values(
    normal: Any,
    d: Any,
    radius: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    c_out: wp.array(dtype=Any),
    grad_out: wp.array2d(dtype=Any),
):
    i = wp.tid()
    c_out[i] = ground_c(p_in[i], normal, d, radius[i])
    grad_out[i, 0] = ground_grad(p_in[i], normal)


@wp.kernel(enable_backward=False)
def _particle_pair_values(
    grid: wp.uint64,
    radius: wp.array(dtype=Any),
    query_radius: Any,
    p_in: wp.array(dtype=Any),
    capacity: int,
    count_io: wp.array(dtype=wp.int32),
    pair_out: wp.array2d(dtype=wp.int32),
    c_out: wp.array(dtype=Any),
    grad_out: wp.array2d(dtype=Any),
):
    i = wp.tid()
    xi = p_in[i]
    for j in wp.hash_grid_query(grid, xi, query_radius):
        if j > i and wp.length(xi - p_in[j]) < query_radius:
            k = wp.atomic_add(count_io, 0, 1)
            if k < capacity:
                xj = p_in[j]
                pair_out[k, 0] = i
                pair_out[k, 1] = j
                c_out[k] = particle_collision_c(xi, xj, radius[i], radius[j])
                # The projection's direction d/|d|: distance_grad's, written out (no import of _distance).
                n = (xi - xj) / wp.length(xi - xj)
                grad_out[k, 0] = n
                grad_out[k, 1] = -n


@wp.kernel(enable_backward=False)
def _point_triangle_values(
    tri_indices: wp.array2d(dtype=wp.int32),
    thickness: Any,
    contact_particle: wp.array(dtype=wp.int32),
    contact_tri: wp.array(dtype=wp.int32),
    contact_side: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    idx_out: wp.array2d(dtype=wp.int32),
    c_out: wp.array(dtype=Any),
    grad_out: wp.array2d(dtype=Any),
):
    k = wp.tid()
    t = contact_tri[k]
    i0 = contact_particle[k]
    i1 = tri_indices[t, 0]
    i2 = tri_indices[t, 1]
    i3 = tri_indices[t, 2]
    idx_out[k, 0] = i0
    idx_out[k, 1] = i1
    idx_out[k, 2] = i2
    idx_out[k, 3] = i3
    x0 = p_in[i0]
    x1 = p_in[i1]
    x2 = p_in[i2]
    x3 = p_in[i3]
    c_out[k] = point_triangle_c(x0, x1, x2, x3, contact_side[k], thickness)
    g0, g1, g2, g3 = point_triangle_grad(x0, x1, x2, x3, contact_side[k])
    grad_out[k, 0] = g0
    grad_out[k, 1] = g1
    grad_out[k, 2] = g2
    grad_out[k, 3] = g3


def _outputs(model: Model, n: int, k: int) -> tuple[wp.array, wp.array]:
    """Zeroed C [n] and ∇C [n, k] arrays on the model's device and dtype."""
    return (
        wp.zeros(n, dtype=model.scalar, device=model.device),
        wp.zeros((n, k), dtype=model.vec3, device=model.device),
    )


def evaluate_ground(model: Model, normal: np.ndarray, offset: float, x: wp.array) -> tuple:
    """C [N], indices [N, 1] and ∇C [N, 1, 3] of the ground constraint of every particle at ``x``.

    Args:
        model: the bound Model (radii, device, dtype).
        normal: unit plane normal n.
        offset: d [m] of the plane n·x + d = 0.
        x: positions [m].
    """
    n = model.particle_count
    c, g = _outputs(model, n, 1)
    normal_v = model.vec3(*(float(v) for v in normal))
    args = [normal_v, model.s(offset), model.particle_radius, x, c, g]
    wp.launch(_ground_values, n, args, device=model.device)
    return c.numpy(), np.arange(n, dtype=np.int32)[:, None], g.numpy()


def evaluate_particle_pairs(model: Model, grid: ParticleGrid, query_radius: float, x: wp.array) -> tuple:
    """C [P], pairs [P, 2] and ∇C [P, 2, 3] of every particle pair closer than ``query_radius`` [m] at x.

    Args:
        model: the bound Model.
        grid: the constraint's ``ParticleGrid`` (rebuilt here over ``x``).
        query_radius: the contact search radius [m].
        x: positions [m].
    """
    grid.build(x)
    d = model.device
    count = wp.zeros(1, dtype=wp.int32, device=d)
    args = [wp.uint64(grid.id), model.particle_radius, model.s(query_radius), x]
    # First pass with no room: counts the pairs; the second writes them into arrays of that size.
    pairs = wp.zeros((0, 2), dtype=wp.int32, device=d)
    c, g = _outputs(model, 0, 2)
    wp.launch(_particle_pair_values, model.particle_count, [*args, 0, count, pairs, c, g], device=d)
    n = int(count.numpy()[0])
    count.zero_()
    pairs = wp.zeros((n, 2), dtype=wp.int32, device=d)
    c, g = _outputs(model, n, 2)
    wp.launch(_particle_pair_values, model.particle_count, [*args, n, count, pairs, c, g], device=d)
    return c.numpy(), pairs.numpy(), g.numpy()


def evaluate_point_triangle(model: Model, constraint: PointTriangleCollision, x: wp.array) -> tuple:
    """C [K], indices [K, 4] (point, triangle) and ∇C [K, 4, 3] of the step's point–triangle contacts at x.

    Args:
        model: the bound Model.
        constraint: the :class:`PointTriangleCollision` (its contacts from the last ``begin_step``).
        x: positions [m].
    """
    n = min(int(constraint.contact_count.numpy()[0]), constraint.capacity)
    c, g = _outputs(model, n, 4)
    idx = wp.zeros((n, 4), dtype=wp.int32, device=model.device)
    args = [constraint.tri_indices, model.s(constraint.thickness), constraint.contact_particle]
    args += [constraint.contact_tri, constraint.contact_side, x, idx, c, g]
    if n:
        wp.launch(_point_triangle_values, n, args, device=model.device)
    return c.numpy(), idx.numpy(), g.numpy()
