"""Conservative per-vertex displacement bounds: a step that cannot tunnel (offset geometry, as in VBD).

At the start of a step every vertex i gets a bound b_i = γ · (min(d_v(i), d_e(e ∋ i), d_t(t ∋ i), R) − δ)⁺:

* d_v(i): the distance from i to the nearest triangle that does not contain it;
* d_e(e): the distance from edge e to the nearest edge that shares no vertex with it;
* d_t(t): the distance from triangle t to the nearest vertex not in it;
* R [m]: the reach of the search (nothing farther than R is looked at, so R bounds every b_i too);
* δ [m]: a floor (default 1 µm) above the rounding of the positions.

After the step each free vertex's displacement is truncated to b_i (the direction kept). With γ < ½ no
pair can cross: a vertex p and a triangle t at distance d start apart, p moves at most γ d_v(p) ≤ γ d, and
every point of t (a convex combination of its vertices) at most max_k b_k ≤ γ (d − δ), so their
distance stays ≥ d − 2γ (d − δ) ≥ δ; an edge pair the same way through d_e. Without the floor, pairs
pressed together approach geometrically until float32 rounding, not motion, crosses them. This is the
"divide and truncate" bound of Newton's VBD self-contact (Chen et al., "Vertex Block Descent", 2024),
without its per-iteration refresh: one bound per step, computed from the step's start positions.

The velocity is scaled by the same factor as the displacement (what a symplectic step's x₁ = x₀ + Δt v₁
implies). Kinematic and pinned particles (inverse mass 0) are not truncated, so pairs with a prescribed
mover keep the guarantee only as far as the mover's own step stays below the bound: take steps in which a
mover moves less than the contact thickness, and let :class:`SelfCollision` push the others out of its way.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from ..model import STICK_VELOCITY
from ._friction import tangential_change
from ._hashgrid import triangle_closest_point

if TYPE_CHECKING:
    from ..model import Model, State

#: Whether this Warp replays a Bvh refit recorded in a graph (as ``_selfcollision._CAPTURABLE``).
_CAPTURABLE = tuple(int(p) for p in wp.__version__.split(".")[:2]) >= (1, 19)


@wp.func
def closest_point_triangle(p: wp.vec3f, a: wp.vec3f, b: wp.vec3f, c: wp.vec3f):
    """The point of triangle abc closest to p, and its barycentric weights."""
    w = triangle_closest_point(p, a, b, c)
    return w[0] * a + w[1] * b + w[2] * c, w


@wp.func
def segment_closest(p1: wp.vec3f, q1: wp.vec3f, p2: wp.vec3f, q2: wp.vec3f):
    """(s, t, distance [m]) of the closest points p1 + s(q1 − p1) and p2 + t(q2 − p2) of two segments
    (Ericson, RTCD §5.1.9; degenerate segments as points)."""
    eps = wp.float32(1.0e-20)
    d1 = q1 - p1
    d2 = q2 - p2
    r = p1 - p2
    a = wp.dot(d1, d1)
    e = wp.dot(d2, d2)
    f = wp.dot(d2, r)
    s = wp.float32(0.0)
    t = wp.float32(0.0)
    if a <= eps and e <= eps:
        return wp.vec3f(s, t, wp.length(r))
    if a <= eps:
        t = wp.clamp(f / e, 0.0, 1.0)
    else:
        c = wp.dot(d1, r)
        if e <= eps:
            s = wp.clamp(-c / a, 0.0, 1.0)
        else:
            b = wp.dot(d1, d2)
            den = a * e - b * b
            if den > eps * a * e:
                s = wp.clamp((b * f - c * e) / den, 0.0, 1.0)
            t = (b * s + f) / e
            if t < 0.0:
                t = 0.0
                s = wp.clamp(-c / a, 0.0, 1.0)
            elif t > 1.0:
                t = 1.0
                s = wp.clamp((b - c) / a, 0.0, 1.0)
    return wp.vec3f(s, t, wp.length((p1 + d1 * s) - (p2 + d2 * t)))


@wp.func
def segment_distance(p1: wp.vec3f, q1: wp.vec3f, p2: wp.vec3f, q2: wp.vec3f):
    """Distance [m] between the segments p1q1 and p2q2."""
    return segment_closest(p1, q1, p2, q2)[2]


@wp.kernel
def _start(
    x_in: wp.array(dtype=Any),
    reach: wp.float32,
    xf_out: wp.array(dtype=wp.vec3f),
    bound_out: wp.array(dtype=wp.float32),
):
    # The float32 snapshot of the start positions, and every vertex's bound reset to the reach.
    i = wp.tid()
    x = x_in[i]
    xf_out[i] = wp.vec3f(wp.float32(x[0]), wp.float32(x[1]), wp.float32(x[2]))
    bound_out[i] = reach


@wp.kernel
def _boxes(
    elems: wp.array(dtype=wp.int32),
    per: int,
    xf: wp.array(dtype=wp.vec3f),
    reach: wp.float32,
    lower_out: wp.array(dtype=wp.vec3f),
    upper_out: wp.array(dtype=wp.vec3f),
    dist_out: wp.array(dtype=wp.float32),
):
    # Element k's box (its ``per`` vertices), and its distance reset to the reach.
    k = wp.tid()
    lo = xf[elems[per * k]]
    hi = lo
    for j in range(1, per):
        p = xf[elems[per * k + j]]
        lo = wp.min(lo, p)
        hi = wp.max(hi, p)
    lower_out[k] = lo
    upper_out[k] = hi
    dist_out[k] = reach


@wp.kernel
def _vertex_triangle(
    tris: wp.array(dtype=wp.int32),
    bvh: wp.uint64,
    xf: wp.array(dtype=wp.vec3f),
    reach: wp.float32,
    bound_io: wp.array(dtype=wp.float32),
    tri_dist_io: wp.array(dtype=wp.float32),
):
    # d_v(i), and d_t(t) for each triangle t found, by atomic minimum (order-free: the same on every run).
    i = wp.tid()
    p = xf[i]
    r = wp.vec3f(reach, reach, reach)
    best = reach
    q = wp.bvh_query_aabb(bvh, p - r, p + r)
    t = int(0)  # noqa: UP018 (a mutable Warp variable)
    while wp.bvh_query_next(q, t):
        a = tris[3 * t]
        b = tris[3 * t + 1]
        c = tris[3 * t + 2]
        if a != i and b != i and c != i:
            cp, bary = closest_point_triangle(p, xf[a], xf[b], xf[c])
            d = wp.length(p - cp)
            if d < reach:
                best = wp.min(best, d)
                wp.atomic_min(tri_dist_io, t, d)
    wp.atomic_min(bound_io, i, best)


@wp.kernel
def _edge_edge(
    edges: wp.array(dtype=wp.int32),
    bvh: wp.uint64,
    xf: wp.array(dtype=wp.vec3f),
    reach: wp.float32,
    edge_dist_out: wp.array(dtype=wp.float32),
):
    # d_e(e): the nearest edge sharing no vertex with e (each edge finds its own: no atomics).
    e = wp.tid()
    u = edges[2 * e]
    w = edges[2 * e + 1]
    p1 = xf[u]
    q1 = xf[w]
    r = wp.vec3f(reach, reach, reach)
    best = reach
    q = wp.bvh_query_aabb(bvh, wp.min(p1, q1) - r, wp.max(p1, q1) + r)
    k = int(0)  # noqa: UP018
    while wp.bvh_query_next(q, k):
        u2 = edges[2 * k]
        w2 = edges[2 * k + 1]
        if u2 != u and u2 != w and w2 != u and w2 != w:
            best = wp.min(best, segment_distance(p1, q1, xf[u2], xf[w2]))
    edge_dist_out[e] = best


@wp.kernel
def _scatter(
    elems: wp.array(dtype=wp.int32),
    per: int,
    dist: wp.array(dtype=wp.float32),
    bound_io: wp.array(dtype=wp.float32),
):
    # An element's distance bounds each of its vertices.
    k = wp.tid()
    for j in range(per):
        wp.atomic_min(bound_io, elems[per * k + j], dist[k])


@wp.kernel
def _snapshot(
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    xf_out: wp.array(dtype=wp.vec3f),
    vf_out: wp.array(dtype=wp.vec3f),
):
    # The predicted state in float32, read by every thread of the push (each writes only its own particle).
    i = wp.tid()
    x = x_in[i]
    v = v_in[i]
    xf_out[i] = wp.vec3f(wp.float32(x[0]), wp.float32(x[1]), wp.float32(x[2]))
    vf_out[i] = wp.vec3f(wp.float32(v[0]), wp.float32(v[1]), wp.float32(v[2]))


@wp.func
def _apply(
    count: int,
    dx: wp.vec3f,
    dv: wp.vec3f,
    fcount: int,
    fdx: wp.vec3f,
    fdv: wp.vec3f,
    x_io: wp.array(dtype=Any),
    v_io: wp.array(dtype=Any),
    i: int,
):
    """Particle i += the push's corrections over √count and friction's over fcount (≤ count; the float32
    sums cast to the state's precision)."""
    if count > 0:
        f = wp.float32(0.0)
        if fcount > 0:
            f = 1.0 / wp.float32(fcount)
        inv = 1.0 / wp.sqrt(wp.float32(count))
        ddx = dx * inv + fdx * f
        ddv = dv * inv + fdv * f
        x = x_io[i]
        v = v_io[i]
        zero = x[0] * type(x[0])(0.0)
        x_io[i] = x + type(x)(type(zero)(ddx[0]), type(zero)(ddx[1]), type(zero)(ddx[2]))
        v_io[i] = v + type(v)(type(zero)(ddv[0]), type(zero)(ddv[1]), type(zero)(ddv[2]))


@wp.kernel
def _edge_push(
    particle_inv_mass: wp.array(dtype=Any),
    edges: wp.array(dtype=wp.int32),
    adj_start: wp.array(dtype=wp.int32),
    adj: wp.array(dtype=wp.int32),
    bvh: wp.uint64,
    xf: wp.array(dtype=wp.vec3f),
    vf: wp.array(dtype=wp.vec3f),
    h: wp.float32,
    friction: wp.float32,
    stick: wp.float32,
    dt: wp.float32,
    x_io: wp.array(dtype=Any),
    v_io: wp.array(dtype=Any),
):
    # Edges of particle i closer than h to another edge (sharing no vertex) are pushed apart: half the
    # gap to h for each edge, shared by its two ends in proportion to their weight at the closest point,
    # and the approaching relative normal velocity removed the same way (one thread per particle: no
    # atomics). Without it nothing keeps edges apart, and the bound alone lets their distance shrink
    # geometrically until float32 rounding crosses them.
    i = wp.tid()
    zero = particle_inv_mass[i] * type(particle_inv_mass[i])(0.0)
    if particle_inv_mass[i] == zero:
        return
    dx = wp.vec3f(0.0, 0.0, 0.0)
    dv = wp.vec3f(0.0, 0.0, 0.0)
    count = int(0)  # noqa: UP018 (a mutable Warp variable)
    fdx = wp.vec3f(0.0, 0.0, 0.0)  # friction's corrections, averaged apart (1/count: no overshoot)
    fdv = wp.vec3f(0.0, 0.0, 0.0)
    fcount = int(0)  # noqa: UP018
    r = wp.vec3f(h, h, h)
    # Sweep 0: the push; sweep 1 (with friction): friction, for the normal velocity change the push
    # made, which its 1/√count average scales by √count over one contact's.
    sweeps = int(1)  # noqa: UP018
    if friction > 0.0:
        sweeps = 2
    for sweep in range(sweeps):
        scale = wp.sqrt(wp.float32(wp.max(count, 1)))
        for k in range(adj_start[i], adj_start[i + 1]):
            e = adj[k]
            u = edges[2 * e]
            w = edges[2 * e + 1]
            p1 = xf[u]
            q1 = xf[w]
            q = wp.bvh_query_aabb(bvh, wp.min(p1, q1) - r, wp.max(p1, q1) + r)
            o = int(0)  # noqa: UP018
            while wp.bvh_query_next(q, o):
                u2 = edges[2 * o]
                w2 = edges[2 * o + 1]
                if u2 != u and u2 != w and w2 != u and w2 != w:
                    p2 = xf[u2]
                    q2 = xf[w2]
                    c = segment_closest(p1, q1, p2, q2)
                    d = c[2]
                    if d < h and d > 0.0:
                        s = c[0]
                        t = c[1]
                        n = ((p1 + (q1 - p1) * s) - (p2 + (q2 - p2) * t)) / d
                        wi = s
                        if i == u:
                            wi = 1.0 - s
                        share = 0.5 * wi / (s * s + (1.0 - s) * (1.0 - s))
                        if sweep == 0:
                            dx += (share * (h - d)) * n
                        vrel = (vf[u] * (1.0 - s) + vf[w] * s) - (vf[u2] * (1.0 - t) + vf[w2] * t)
                        vn = wp.dot(vrel, n)
                        if sweep == 0:
                            if vn < 0.0:
                                dv -= (share * vn) * n
                            count += 1
                        elif vn < 0.0:
                            # This edge's part of the relative tangential change: all of it against an edge
                            # that cannot move (kinematic or pinned), half otherwise.
                            part = 0.5
                            if particle_inv_mass[u2] == zero and particle_inv_mass[w2] == zero:
                                part = 1.0
                            dvt = (2.0 * part * share) * tangential_change(
                                vrel, n, -vn * scale, friction, stick
                            )
                            fdv += dvt
                            fdx += dt * dvt
                            fcount += 1
    _apply(count, dx, dv, fcount, fdx, fdv, x_io, v_io, i)


@wp.kernel
def _triangle_push(
    particle_inv_mass: wp.array(dtype=Any),
    tris: wp.array(dtype=wp.int32),
    adj_start: wp.array(dtype=wp.int32),
    adj: wp.array(dtype=wp.int32),
    points: wp.uint64,
    xf: wp.array(dtype=wp.vec3f),
    vf: wp.array(dtype=wp.vec3f),
    h: wp.float32,
    friction: wp.float32,
    stick: wp.float32,
    dt: wp.float32,
    x_io: wp.array(dtype=Any),
    v_io: wp.array(dtype=Any),
):
    # The triangle side of vertex–triangle contact (SelfCollision moves only the vertex): a triangle of
    # particle i closer than h to a vertex not in it moves away from it, by the whole gap to h when the
    # vertex is kinematic or pinned (it will not move), half of it otherwise; i takes its barycentric share.
    i = wp.tid()
    zero = particle_inv_mass[i] * type(particle_inv_mass[i])(0.0)
    if particle_inv_mass[i] == zero:
        return
    dx = wp.vec3f(0.0, 0.0, 0.0)
    dv = wp.vec3f(0.0, 0.0, 0.0)
    count = int(0)  # noqa: UP018 (a mutable Warp variable)
    fdx = wp.vec3f(0.0, 0.0, 0.0)  # friction's corrections, averaged apart (1/count: no overshoot)
    fdv = wp.vec3f(0.0, 0.0, 0.0)
    fcount = int(0)  # noqa: UP018
    r = wp.vec3f(h, h, h)
    # Sweep 0: the push; sweep 1 (with friction): friction, for the normal velocity change the push
    # made, which its 1/√count average scales by √count over one contact's.
    sweeps = int(1)  # noqa: UP018
    if friction > 0.0:
        sweeps = 2
    for sweep in range(sweeps):
        scale = wp.sqrt(wp.float32(wp.max(count, 1)))
        for k in range(adj_start[i], adj_start[i + 1]):
            t = adj[k]
            ia = tris[3 * t]
            ib = tris[3 * t + 1]
            ic = tris[3 * t + 2]
            a = xf[ia]
            b = xf[ib]
            c = xf[ic]
            q = wp.bvh_query_aabb(points, wp.min(wp.min(a, b), c) - r, wp.max(wp.max(a, b), c) + r)
            j = int(0)  # noqa: UP018
            while wp.bvh_query_next(q, j):
                if j != ia and j != ib and j != ic:
                    p = xf[j]
                    cp, bary = closest_point_triangle(p, a, b, c)
                    d = wp.length(p - cp)
                    if d < h and d > 0.0:
                        n = (p - cp) / d
                        wi = bary[0]
                        if i == ib:
                            wi = bary[1]
                        elif i == ic:
                            wi = bary[2]
                        part = 0.5
                        if particle_inv_mass[j] == zero:
                            part = 1.0
                        share = part * wi / wp.dot(bary, bary)
                        if sweep == 0:
                            dx -= (share * (h - d)) * n
                        vrel = vf[j] - (bary[0] * vf[ia] + bary[1] * vf[ib] + bary[2] * vf[ic])
                        vn = wp.dot(vrel, n)
                        if sweep == 0:
                            if vn < 0.0:
                                dv += (share * vn) * n
                            count += 1
                        elif vn < 0.0:
                            # The triangle's part (as the push's) of the relative tangential change.
                            dvt = -share * tangential_change(vrel, n, -vn * scale, friction, stick)
                            fdv += dvt
                            fdx += dt * dvt
                            fcount += 1
    _apply(count, dx, dv, fcount, fdx, fdv, x_io, v_io, i)


@wp.kernel
def _truncate(
    particle_inv_mass: wp.array(dtype=Any),
    bound: wp.array(dtype=wp.float32),
    fraction: wp.float32,
    floor: wp.float32,
    x_start: wp.array(dtype=Any),
    x_io: wp.array(dtype=Any),
    v_io: wp.array(dtype=Any),
):
    # |x₁ − x₀| ≤ γ (d_i − δ)⁺ for the free particles; the velocity scaled with the displacement.
    i = wp.tid()
    zero = particle_inv_mass[i] * type(particle_inv_mass[i])(0.0)
    if particle_inv_mass[i] == zero:
        return
    x0 = x_start[i]
    dx = x_io[i] - x0
    n = wp.length(dx)
    b = type(zero)(fraction * wp.max(bound[i] - floor, wp.float32(0.0)))
    if n > b:
        s = b / n
        x_io[i] = x0 + dx * s
        v_io[i] = v_io[i] * s


class StepBound:
    """Truncates each particle's displacement per step so that no vertex–triangle or edge–edge pair of the
    model's triangles can cross (see the module docstring for the rule and the guarantee).

    A post-step contact handler for any solver (``ForceSolver``, ``FastMassSpring``, ``XPBD``:
    ``collisions=[..., StepBound(model)]``); put it last, after the handlers that push particles apart.
    :class:`SelfCollision` runs one itself when given ``bound=γ``.

    Args:
        model: the Model; its triangles ``model.tri_indices`` (cloth, or surfaces added with
            ``add_triangles``) are the primitives kept apart.
        fraction: γ [-], in (0, 0.5): the share of the distance to the nearest other primitive a vertex may
            move in one step (VBD uses 0.4).
        reach: R [m] > 0: how far to look for primitives; it also caps every step's displacement at γR.
            Take it a few times the largest displacement a step makes freely (speed × Δt).
        separation: h [m] ≤ R, or None (off): before truncating, push apart edges closer than h, and
            triangles from vertices closer than h (the edge–edge contact and the triangle side of
            vertex–triangle contact that :class:`SelfCollision` lacks: without them layers pressed
            together close up to the floor, and a kinematic vertex pokes through a triangle).
        floor: δ [m] ≥ 0: the bound is γ (d − δ)⁺, so no two primitives come closer than δ; keep it above
            the rounding of the positions (float32: 6e-8 × the largest coordinate), or rounding can cross
            a pair the bound let approach within it.
        passes: Jacobi passes of the separation push per step (each costs about twice the bound
            itself; more keep pressed layers nearer h, the bound keeps them apart either way).
        friction: Coulomb μ [-] ≥ 0 of the separation push (the smoothed law of
            :mod:`pliant.collision._friction`, as :class:`SelfCollision`'s): a cloth held up by a mesh's
            vertices and edges, which only this push touches, is otherwise carried by nothing.
        stick_velocity: ε_v [m/s] > 0 of that law (default :data:`pliant.model.STICK_VELOCITY`).
    """

    def __init__(
        self,
        model: Model,
        *,
        fraction: float = 0.4,
        reach: float,
        separation: float | None = None,
        floor: float = 1.0e-6,
        passes: int = 1,
        friction: float = 0.0,
        stick_velocity: float = STICK_VELOCITY,
    ) -> None:
        if not 0.0 < fraction < 0.5:
            raise ValueError(f"StepBound: fraction must be in (0, 0.5) (no pair can cross), got {fraction}")
        if not reach > 0.0:
            raise ValueError(f"StepBound: reach must be > 0 m, got {reach}")
        if passes < 1:
            raise ValueError(f"StepBound: passes must be >= 1, got {passes}")
        if not 0.0 <= floor < reach:
            raise ValueError(f"StepBound: floor must be in [0, reach = {reach}) m, got {floor}")
        if separation is not None and not 0.0 < separation <= reach:
            raise ValueError(f"StepBound: separation must be in (0, reach = {reach}] m, got {separation}")
        if not friction >= 0.0:
            raise ValueError(f"StepBound: friction must be >= 0 (a Coulomb μ), got {friction}")
        if not stick_velocity > 0.0:
            raise ValueError(f"StepBound: stick_velocity must be > 0 m/s, got {stick_velocity}")
        if model.tri_count == 0:
            raise ValueError("StepBound: the model has no triangles; add some (add_triangles) or drop it")
        from ..geometry import edges_from_triangles

        self.fraction = float(fraction)
        self.reach = float(reach)
        self.separation = None if separation is None else float(separation)
        self.floor = float(floor)
        self.passes = int(passes)
        self.friction = float(friction)
        self.stick_velocity = float(stick_velocity)
        d = model.device
        n = model.particle_count
        tris = model.tri_indices.numpy().reshape(-1, 3).astype(np.int32)
        edges = edges_from_triangles(tris).astype(np.int32)
        self._tris: wp.array = wp.array(tris.reshape(-1), dtype=wp.int32, device=d)
        self._edges: wp.array = wp.array(edges.reshape(-1), dtype=wp.int32, device=d)
        self._xf = wp.zeros(n, dtype=wp.vec3f, device=d)
        self.bound = wp.zeros(n, dtype=wp.float32, device=d)
        self._tri = [wp.zeros(len(tris), dtype=wp.vec3f, device=d) for _ in range(2)]
        self._edge = [wp.zeros(len(edges), dtype=wp.vec3f, device=d) for _ in range(2)]
        self._tri_dist = wp.zeros(len(tris), dtype=wp.float32, device=d)
        self._edge_dist = wp.zeros(len(edges), dtype=wp.float32, device=d)
        self._boxes(model.particle_q)
        self._tri_bvh = wp.Bvh(self._tri[0], self._tri[1])
        self._edge_bvh = wp.Bvh(self._edge[0], self._edge[1])
        # Each particle's edges (CSR), for the edge push; the predicted state's float32 snapshot.
        order = np.argsort(edges.reshape(-1), kind="stable")
        start = np.searchsorted(edges.reshape(-1)[order], np.arange(n + 1)).astype(np.int32)
        self._adj_start: wp.array = wp.array(start, dtype=wp.int32, device=d)
        self._adj: wp.array = wp.array((order // 2).astype(np.int32), dtype=wp.int32, device=d)
        order = np.argsort(tris.reshape(-1), kind="stable")
        start = np.searchsorted(tris.reshape(-1)[order], np.arange(n + 1)).astype(np.int32)
        self._tadj_start: wp.array = wp.array(start, dtype=wp.int32, device=d)
        self._tadj: wp.array = wp.array((order // 3).astype(np.int32), dtype=wp.int32, device=d)
        self._xp = wp.zeros(n, dtype=wp.vec3f, device=d)
        self._vp = wp.zeros(n, dtype=wp.vec3f, device=d)
        self._xp.assign(model.particle_q_np.astype(np.float32))
        self._points = wp.Bvh(self._xp, self._xp)  # the vertices as point boxes

    def graph_blocker(self) -> str | None:
        """None where Warp records a BVH refit in a graph (Warp ≥ 1.19); older Warps say why not."""
        if not _CAPTURABLE:
            return f"Warp {wp.__version__} cannot replay a BVH refit (Warp >= 1.19 can)"
        return None

    def _boxes(self, x: wp.array) -> None:
        d, reach = self._xf.device, wp.float32(self.reach)
        wp.launch(_start, x.shape[0], [x, reach, self._xf, self.bound], device=d)
        for elems, per, (lo, hi), dist in (
            (self._tris, 3, self._tri, self._tri_dist),
            (self._edges, 2, self._edge, self._edge_dist),
        ):
            wp.launch(_boxes, dist.shape[0], [elems, per, self._xf, reach, lo, hi, dist], device=d)

    def compute(self, x: wp.array) -> wp.array:
        """The bounds b_i / γ [m] (float32, per particle) for the start positions ``x`` [m]."""
        d, reach = self._xf.device, wp.float32(self.reach)
        self._boxes(x)
        self._tri_bvh.refit()
        self._edge_bvh.refit()
        n = x.shape[0]
        args = [self._tris, wp.uint64(self._tri_bvh.id), self._xf, reach, self.bound, self._tri_dist]
        wp.launch(_vertex_triangle, n, args, device=d)
        args = [self._edges, wp.uint64(self._edge_bvh.id), self._xf, reach, self._edge_dist]
        wp.launch(_edge_edge, self._edge_dist.shape[0], args, device=d)
        wp.launch(_scatter, self._tri_dist.shape[0], [self._tris, 3, self._tri_dist, self.bound], device=d)
        wp.launch(_scatter, self._edge_dist.shape[0], [self._edges, 2, self._edge_dist, self.bound], device=d)
        return self.bound

    def push(self, model: Model, state_out: State, dt: float = 0.0) -> None:
        """Push apart the edges of ``state_out`` closer than the separation, then its triangles from the
        vertices closer than it (in place); friction moves positions by ``dt`` [s] times its velocity
        change (the step's, as the other contact responses)."""
        d, x, v = model.device, state_out.particle_q, state_out.particle_qd
        fr = [wp.float32(self.friction), wp.float32(self.stick_velocity), wp.float32(dt)]
        assert self.separation is not None  # called only with a separation
        h = wp.float32(self.separation)
        wp.launch(_snapshot, model.particle_count, [x, v, self._xp, self._vp], device=d)
        lo, hi = self._edge
        args = [self._edges, 2, self._xp, wp.float32(self.reach), lo, hi, self._edge_dist]
        wp.launch(_boxes, self._edge_dist.shape[0], args, device=d)
        self._edge_bvh.refit()
        args = [
            model.particle_inv_mass,
            self._edges,
            self._adj_start,
            self._adj,
            wp.uint64(self._edge_bvh.id),
            self._xp,
            self._vp,
            h,
            *fr,
            x,
            v,
        ]
        wp.launch(_edge_push, model.particle_count, args, device=d)
        wp.launch(_snapshot, model.particle_count, [x, v, self._xp, self._vp], device=d)
        self._points.refit()
        args = [
            model.particle_inv_mass,
            self._tris,
            self._tadj_start,
            self._tadj,
            wp.uint64(self._points.id),
            self._xp,
            self._vp,
            h,
            *fr,
            x,
            v,
        ]
        wp.launch(_triangle_push, model.particle_count, args, device=d)

    def apply(self, model: Model, state_in: State, state_out: State, dt: float) -> None:
        """Push edges apart (with a separation), then truncate ``state_out``'s displacements from
        ``state_in`` (in place; ``dt`` [s]: the step, for friction's position change)."""
        if self.separation is not None:
            for _ in range(self.passes):
                self.push(model, state_out, dt)
        self.compute(state_in.particle_q)
        args = [
            model.particle_inv_mass,
            self.bound,
            wp.float32(self.fraction),
            wp.float32(self.floor),
            state_in.particle_q,
            state_out.particle_q,
            state_out.particle_qd,
        ]
        wp.launch(_truncate, model.particle_count, args, device=model.device)
