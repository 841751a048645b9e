"""Particle–particle and cloth self-collision with a thickness, as a post-step position/velocity pass.

Two kinds of contact are resolved after the integrator, each thread moving only its own particle (no
atomics; every thread reads a snapshot of the predicted positions, so CPU and CUDA give the same result):

* particle–particle, found with ``wp.HashGrid``: centres closer than the thickness h are pushed apart,
  each by its share w_i/(w_i + w_j) of the overlap (w: inverse masses; half each for equal masses), so
  that momentum is conserved, except pairs already closer than h in the rest configuration (neighbours
  in the same mesh);
* point–triangle against every triangle of the model (found with AABB queries of a ``wp.Bvh`` over the
  triangles' boxes, refitted each pass), skipping the particle's own triangles. The side a particle must
  stay on is the side it was on at the *start* of the step, so a particle that crossed a triangle within
  one step is put back: its signed distance to the plane is restored to ≥ h on that side. Only the
  point moves along the normal (the triangle side of the push is :class:`StepBound`'s separation).

The approaching normal velocity (relative to the triangle or partner) is removed, and friction is the
ground's smoothed Coulomb law (:func:`pliant.collision._friction.friction_scale`, one law for every
contact): the relative tangential velocity ṽ_t changes by at most μ Δv_n, Δv_n the relative normal
velocity change of the contact (stopped inside the cone, smoothed below the stick velocity ε_v). That
change Δv_t is an impulse J = Δv_t / W, W = Σ_k c_k² w_k over the pair's points (c_k: 1 and −1 for two
particles, 1 and the barycentric weights for a point and a triangle; w_k inverse masses), shared by both
sides (point k: c_k w_k J), so it conserves momentum; each side also moves by Δt times its velocity change
(friction acts inside the step: without it a sticking contact still creeps by Δt ṽ_t every step). A
triangle's vertices take their share in the same pass: each particle also finds, from the side of its
own triangles, the contacts other particles find with them (a BVH of the points' swept boxes). With
several contacts, each particle averages its normal corrections, and separately its friction corrections
from both sides (Jacobi): momentum is exact for a particle with one contact.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from ..model import STICK_VELOCITY
from ._friction import tangential_change

if TYPE_CHECKING:
    from ..model import Model, State


#: Whether this Warp replays a HashGrid build (reserved beforehand) and a Bvh refit recorded in a graph,
#: on the CPU as on CUDA (both documented from Warp 1.19).
_CAPTURABLE = tuple(int(p) for p in wp.__version__.split(".")[:2]) >= (1, 19)


@wp.func
def closest_point_triangle(p: Any, a: Any, b: Any, c: Any):
    """Closest point to p on triangle abc and its barycentric weights (Ericson, RTCD §5.1.5)."""
    zero = p[0] * type(p[0])(0.0)
    one = type(zero)(1.0)
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = wp.dot(ab, ap)
    d2 = wp.dot(ac, ap)
    w = type(p)(one, zero, zero)
    if d1 <= zero and d2 <= zero:
        return a, w
    bp = p - b
    d3 = wp.dot(ab, bp)
    d4 = wp.dot(ac, bp)
    if d3 >= zero and d4 <= d3:
        return b, type(p)(zero, one, zero)
    vc = d1 * d4 - d3 * d2
    if vc <= zero and d1 >= zero and d3 <= zero:
        v = d1 / (d1 - d3)
        return a + v * ab, type(p)(one - v, v, zero)
    cp = p - c
    d5 = wp.dot(ab, cp)
    d6 = wp.dot(ac, cp)
    if d6 >= zero and d5 <= d6:
        return c, type(p)(zero, zero, one)
    vb = d5 * d2 - d1 * d6
    if vb <= zero and d2 >= zero and d6 <= zero:
        t = d2 / (d2 - d6)
        return a + t * ac, type(p)(one - t, zero, t)
    va = d3 * d6 - d5 * d4
    if va <= zero and (d4 - d3) >= zero and (d5 - d6) >= zero:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return b + t * (c - b), type(p)(zero, one - t, t)
    denom = one / (va + vb + vc)
    v = vb * denom
    t = vc * denom
    return a + v * ab + t * ac, type(p)(one - v - t, v, t)


@wp.func
def _triangle_push(x: Any, x0: Any, a: Any, b: Any, c: Any, a0: Any, b0: Any, c0: Any, thickness: Any):
    """(push [m], barycentric weights) of point x (x0 at the step's start) against triangle abc (a0b0c0 at
    the start): back to the start side if it crossed, out to the thickness if closer; push = 0: no
    contact."""
    zero = thickness * type(thickness)(0.0)
    push = x * zero
    bary = x * zero
    nrm = wp.cross(b - a, c - a)
    ln = wp.length(nrm)
    n0 = wp.cross(b0 - a0, c0 - a0)
    if ln > zero and wp.length(n0) > zero:
        n = nrm / ln
        s0 = wp.dot(x0 - a0, n0)
        s1 = wp.dot(x - a, n)
        side = type(thickness)(1.0)
        if s0 < zero or (s0 == zero and s1 < zero):
            side = type(thickness)(-1.0)
        cp, bary = closest_point_triangle(x, a, b, c)
        d = x - cp
        dist = wp.length(d)
        # Crossed: on the other side of the plane with its projection inside the triangle (up to 1 % of h
        # sideways, for a crossing through an edge). A point beside the triangle is not behind it: a box's
        # vertex resting on another box's top face lies in the plane of that box's side faces, and
        # rounding flips its side of them; taking that for a crossing pushed it h sideways.
        lateral = wp.sqrt(wp.max(dist * dist - s1 * s1, zero))
        inside = bary[0] > zero and bary[1] > zero and bary[2] > zero
        if side * s1 < zero and (inside or lateral < type(thickness)(0.01) * thickness):
            push = (thickness - side * s1) * side * n  # back to the start side
        elif dist < thickness and dist > zero:
            push = (thickness - dist) * (d / dist)
    return push, bary


@wp.kernel
def _triangle_bounds(
    tri_indices: wp.array(dtype=wp.int32),
    xf_in: wp.array(dtype=wp.vec3f),
    lower_out: wp.array(dtype=wp.vec3f),
    upper_out: wp.array(dtype=wp.vec3f),
):
    # Triangle t's axis-aligned box, the leaf the BVH refits around.
    t = wp.tid()
    a = xf_in[tri_indices[3 * t]]
    b = xf_in[tri_indices[3 * t + 1]]
    c = xf_in[tri_indices[3 * t + 2]]
    lower_out[t] = wp.min(wp.min(a, b), c)
    upper_out[t] = wp.max(wp.max(a, b), c)


@wp.kernel
def _snapshot(
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
    xf_out: wp.array(dtype=wp.vec3f),
):
    i = wp.tid()
    x = x_in[i]
    x_out[i] = x
    v_out[i] = v_in[i]
    xf_out[i] = wp.vec3f(wp.float32(x[0]), wp.float32(x[1]), wp.float32(x[2]))


@wp.func
def _triangle_side(
    k: int,
    particle_inv_mass: wp.array(dtype=Any),
    tri_indices: wp.array(dtype=wp.int32),
    adj_start: wp.array(dtype=wp.int32),
    adj: wp.array(dtype=wp.int32),
    points: wp.uint64,
    thickness: Any,
    friction: Any,
    stick_velocity: Any,
    dt: Any,
    x_start: wp.array(dtype=Any),
    x_pred: wp.array(dtype=Any),
    v_pred: wp.array(dtype=Any),
):
    """The triangle side of point–triangle friction: (Δx, Δv, count), the sums over every contact (q, t)
    of a triangle t of particle k that thread q finds (the same contact, computed by the same functions
    from the same snapshot) of k's share −c_k w_k J."""
    zero = thickness * type(thickness)(0.0)
    wk = particle_inv_mass[k]
    h = wp.float32(thickness)
    r = wp.vec3f(h, h, h)
    dx = x_pred[k] * zero
    dv = x_pred[k] * zero
    count = int(0)  # noqa: UP018 (a mutable Warp variable)
    for e in range(adj_start[k], adj_start[k + 1]):
        t = adj[e]
        ia = tri_indices[3 * t]
        ib = tri_indices[3 * t + 1]
        ic = tri_indices[3 * t + 2]
        a = x_pred[ia]
        b = x_pred[ib]
        c = x_pred[ic]
        lo = wp.min(wp.min(a, b), c)
        hi = wp.max(wp.max(a, b), c)
        lof = wp.vec3f(wp.float32(lo[0]), wp.float32(lo[1]), wp.float32(lo[2])) - r
        hif = wp.vec3f(wp.float32(hi[0]), wp.float32(hi[1]), wp.float32(hi[2])) + r
        q = wp.bvh_query_aabb(points, lof, hif)
        j = int(0)  # noqa: UP018
        while wp.bvh_query_next(q, j):
            wj = particle_inv_mass[j]
            if j != ia and j != ib and j != ic and wj != zero:
                push, bary = _triangle_push(
                    x_pred[j], x_start[j], a, b, c, x_start[ia], x_start[ib], x_start[ic], thickness
                )
                lp = wp.length(push)
                if lp > zero:
                    pn = push / lp
                    vrel = v_pred[j] - (bary[0] * v_pred[ia] + bary[1] * v_pred[ib] + bary[2] * v_pred[ic])
                    vn = wp.dot(vrel, pn)
                    if vn < zero:
                        big_w = wj + (
                            bary[0] * bary[0] * particle_inv_mass[ia]
                            + bary[1] * bary[1] * particle_inv_mass[ib]
                            + bary[2] * bary[2] * particle_inv_mass[ic]
                        )
                        ck = bary[0]
                        if k == ib:
                            ck = bary[1]
                        elif k == ic:
                            ck = bary[2]
                        dvt = (-ck * wk / big_w) * tangential_change(vrel, pn, -vn, friction, stick_velocity)
                        dv += dvt
                        dx += dt * dvt
                        count += 1
    return dx, dv, count


@wp.func
def _write(
    i: int,
    x: Any,
    v: Any,
    count: int,
    dx: Any,
    dv: Any,
    fcount: int,
    fdx: Any,
    fdv: Any,
    thickness: Any,
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    """Particle i's position and velocity after the pass: the mean of its normal corrections, plus the mean
    of its friction corrections from both sides (a pair of boxes touches both ways: each one's vertices
    on the other's triangles; each side's correction is its whole share of the relative change)."""
    if count > 0 or fcount > 0:
        xn = x
        vn_ = v
        if count > 0:
            inv = type(thickness)(1.0) / type(thickness)(count)
            xn = x + dx * inv
            vn_ = v + dv * inv
        if fcount > 0:
            finv = type(thickness)(1.0) / type(thickness)(fcount)
            xn = xn + fdx * finv
            vn_ = vn_ + fdv * finv
        x_out[i] = xn
        v_out[i] = vn_


@wp.kernel
def _self_contact(
    # Model:
    particle_inv_mass: wp.array(dtype=Any),
    rest_q: wp.array(dtype=Any),
    tri_indices: wp.array(dtype=wp.int32),
    tri_bvh: wp.uint64,
    grid: wp.uint64,
    use_particles: int,
    use_triangles: int,
    thickness: Any,
    friction: Any,
    stick_velocity: Any,
    dt: Any,
    # The triangle side of friction (use_sides != 0): each particle's triangles (CSR), the points' BVH:
    use_sides: int,
    adj_start: wp.array(dtype=wp.int32),
    adj: wp.array(dtype=wp.int32),
    points: wp.uint64,
    # State at the start of the step and the predicted (snapshot) state:
    x_start: wp.array(dtype=Any),
    x_pred: wp.array(dtype=Any),
    v_pred: wp.array(dtype=Any),
    xf_pred: wp.array(dtype=wp.vec3f),
    # Out:
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    i = wp.tid()
    zero = thickness * type(thickness)(0.0)
    wi = particle_inv_mass[i]
    if wi == zero:
        return
    x = x_pred[i]
    v = v_pred[i]
    dx = x * zero
    dv = x * zero
    count = int(0)  # noqa: UP018 (a mutable Warp variable)
    # Friction's corrections, averaged over the particle's frictional contacts on either side of them.
    fdx = x * zero
    fdv = x * zero
    fcount = int(0)  # noqa: UP018
    if use_particles != 0:
        query = wp.hash_grid_query(grid, xf_pred[i], wp.float32(thickness))
        j = int(0)  # noqa: UP018
        while wp.hash_grid_query_next(query, j):
            if j != i:
                d = x - x_pred[j]
                l = wp.length(d)
                if l < thickness and l > zero and wp.length(rest_q[i] - rest_q[j]) >= thickness:
                    n = d / l
                    # i's share w_i/(w_i + w_j) of the pair's corrections (j takes the rest): momentum
                    # is conserved; ½ for equal masses, all of it against a pinned or kinematic j.
                    w = wi / (wi + particle_inv_mass[j])
                    dx += (w * (thickness - l)) * n
                    vrel = v - v_pred[j]
                    vn = wp.dot(vrel, n)
                    if vn < zero:
                        dv -= (w * vn) * n
                        if friction > zero:
                            dvt = w * tangential_change(vrel, n, -vn, friction, stick_velocity)
                            fdv += dvt
                            fdx += dt * dvt
                            fcount += 1
                    count += 1
    if use_triangles != 0:
        x0 = x_start[i]
        lo = wp.min(x, x0) - type(x)(thickness, thickness, thickness)
        hi = wp.max(x, x0) + type(x)(thickness, thickness, thickness)
        lof = wp.vec3f(wp.float32(lo[0]), wp.float32(lo[1]), wp.float32(lo[2]))
        hif = wp.vec3f(wp.float32(hi[0]), wp.float32(hi[1]), wp.float32(hi[2]))
        q = wp.bvh_query_aabb(tri_bvh, lof, hif)
        f = int(0)  # noqa: UP018
        while wp.bvh_query_next(q, f):
            ia = tri_indices[3 * f]
            ib = tri_indices[3 * f + 1]
            ic = tri_indices[3 * f + 2]
            if ia != i and ib != i and ic != i:
                a0 = x_start[ia]
                b0 = x_start[ib]
                c0 = x_start[ic]
                push, bary = _triangle_push(x, x0, x_pred[ia], x_pred[ib], x_pred[ic], a0, b0, c0, thickness)
                lp = wp.length(push)
                if lp > zero:
                    pn = push / lp
                    dx += push
                    vrel = v - (bary[0] * v_pred[ia] + bary[1] * v_pred[ib] + bary[2] * v_pred[ic])
                    vn = wp.dot(vrel, pn)
                    if vn < zero:
                        dv -= vn * pn
                        if friction > zero:
                            big_w = wi + (
                                bary[0] * bary[0] * particle_inv_mass[ia]
                                + bary[1] * bary[1] * particle_inv_mass[ib]
                                + bary[2] * bary[2] * particle_inv_mass[ic]
                            )
                            dvt = (wi / big_w) * tangential_change(vrel, pn, -vn, friction, stick_velocity)
                            fdv += dvt
                            fdx += dt * dvt
                            fcount += 1
                    count += 1
    if use_sides != 0:
        sdx, sdv, scount = _triangle_side(
            i, particle_inv_mass, tri_indices, adj_start, adj, points,
            thickness, friction, stick_velocity, dt, x_start, x_pred, v_pred,
        )  # fmt: skip
        fdx += sdx
        fdv += sdv
        fcount += scount
    _write(i, x, v, count, dx, dv, fcount, fdx, fdv, thickness, x_out, v_out)


@wp.kernel
def _swept_boxes(
    x_start: wp.array(dtype=Any),
    xf: wp.array(dtype=wp.vec3f),
    lower_out: wp.array(dtype=wp.vec3f),
    upper_out: wp.array(dtype=wp.vec3f),
):
    # Particle i's box from its start to its predicted position: the leaf the points' BVH refits around.
    i = wp.tid()
    x = x_start[i]
    x0 = wp.vec3f(wp.float32(x[0]), wp.float32(x[1]), wp.float32(x[2]))
    lower_out[i] = wp.min(x0, xf[i])
    upper_out[i] = wp.max(x0, xf[i])


class SelfCollision:
    """Contacts between all particles (hash grid) and of particles against all triangles, with thickness h.

    Use as a post-step contact handler (``FastMassSpring(..., collisions=[SelfCollision(model, ...)])``) or
    call :meth:`apply` after any solver's step. Keeps the particles of a cloth folding onto itself from
    passing through its triangles, and particles of different objects apart.

    Args:
        model: the Model (its triangles ``model.tri_indices`` and rest positions are used).
        thickness: h [m]: minimum particle–particle and particle–triangle distance. Keep it below the cloth's
            edge length and above the largest displacement per step.
        friction: Coulomb μ between contacting particles / triangles (the smoothed law of
            :mod:`pliant.collision._friction`, shared by both sides of each contact).
        iterations: Jacobi passes per step (each pass resolves the contacts found in it).
        particles: resolve particle–particle contacts.
        triangles: resolve particle–triangle contacts (needs triangles in the model).
        bound: γ [-] in (0, 0.5), or None (the default: off): after the passes, truncate each particle's
            displacement to γ times its distance to the nearest other primitive at the step's start
            (:class:`pliant.collision.StepBound`, reach and edge separation = ``thickness``), so that no
            vertex–triangle or edge–edge pair crosses within a step however fast it moves.
        stick_velocity: ε_v [m/s] > 0 of the friction law: a contact inside the Coulomb cone creeps slower
            than this (default :data:`pliant.model.STICK_VELOCITY`, the ground's).
    """

    def __init__(
        self,
        model: Model,
        *,
        thickness: float,
        friction: float = 0.0,
        iterations: int = 2,
        particles: bool = True,
        triangles: bool = True,
        bound: float | None = None,
        stick_velocity: float = STICK_VELOCITY,
    ) -> None:
        if thickness <= 0:
            raise ValueError(f"thickness must be > 0 m, got {thickness}")
        if friction < 0 or iterations < 1:
            raise ValueError("friction must be >= 0 and iterations >= 1")
        if not stick_velocity > 0:
            raise ValueError(f"SelfCollision: stick_velocity must be > 0 m/s, got {stick_velocity}")
        self.thickness = float(thickness)
        self.friction = float(friction)
        self.stick_velocity = float(stick_velocity)
        self.iterations = int(iterations)
        self.use_particles = bool(particles)
        self.use_triangles = bool(triangles) and model.tri_count > 0
        # The step bound (opt-in: it changes trajectories, so the default keeps the goldens).
        self._bound = None
        if bound is not None:
            from ._step_bound import StepBound

            self._bound = StepBound(
                model,
                fraction=bound,
                reach=self.thickness,
                separation=self.thickness,
                friction=self.friction,
                stick_velocity=self.stick_velocity,
            )
        d = model.device
        n = model.particle_count
        self._x = wp.zeros(n, dtype=model.vec3, device=d)
        self._v = wp.zeros(n, dtype=model.vec3, device=d)
        self._xf = wp.zeros(n, dtype=wp.vec3f, device=d)
        tris = (
            model.tri_indices.numpy().reshape(-1).astype(np.int32)
            if model.tri_count
            else np.zeros(3, np.int32)
        )
        self._tris: wp.array = wp.array(tris, dtype=wp.int32, device=d)
        # Triangle bounds in a wp.Bvh, refit each iteration: Warp records a Bvh refit in a CPU graph and
        # a CUDA one (a wp.Mesh's host refit is not replayed by a CPU graph).
        self._bvh: wp.Bvh | None = None
        if self.use_triangles:  # (tri_count > 0)
            self._tri_lo = wp.zeros(model.tri_count, dtype=wp.vec3f, device=d)
            self._tri_hi = wp.zeros(model.tri_count, dtype=wp.vec3f, device=d)
            self._xf.assign(model.particle_q_np.astype(np.float32))
            self._bound_triangles()
            self._bvh = wp.Bvh(self._tri_lo, self._tri_hi)
        # The triangle side of point–triangle friction: each particle's triangles (CSR) and a BVH of the
        # particles' swept boxes (start → predicted), refit each pass.
        self._points: wp.Bvh | None = None
        self._adj_start: wp.array = wp.zeros(1, dtype=wp.int32, device=d)
        self._adj: wp.array = wp.zeros(1, dtype=wp.int32, device=d)
        if self.use_triangles and self.friction > 0:
            flat = tris.reshape(-1)
            order = np.argsort(flat, kind="stable")
            start = np.searchsorted(flat[order], np.arange(n + 1)).astype(np.int32)
            self._adj_start = wp.array(start, dtype=wp.int32, device=d)
            self._adj = wp.array((order // 3).astype(np.int32), dtype=wp.int32, device=d)
            self._pt_lo: wp.array = wp.array(model.particle_q_np.astype(np.float32), dtype=wp.vec3f, device=d)
            self._pt_hi: wp.array = wp.array(model.particle_q_np.astype(np.float32), dtype=wp.vec3f, device=d)
            self._points = wp.Bvh(self._pt_lo, self._pt_hi)
        # Hash-table size ~2 cells per particle per axis³, capped: a build clears every cell.
        dim = int(np.clip(round(2.0 * n ** (1.0 / 3.0)), 8, 128))
        self._grid = wp.HashGrid(dim, dim, dim, device=d) if self.use_particles else None
        if self._grid is not None and _CAPTURABLE:
            # Sized once, so that a build inside a captured frame never allocates (a CPU capture cannot).
            self._grid.reserve(n)

    def graph_blocker(self) -> str | None:
        """None where Warp records the hash-grid build and the BVH refit in a graph (Warp ≥ 1.19; the grid
        is reserved at construction): a frame with self-collision then replays. Older Warps say why not."""
        if not _CAPTURABLE:
            return f"Warp {wp.__version__} cannot replay a hash-grid build or a BVH refit (Warp >= 1.19 can)"
        return None

    def _bound_triangles(self) -> None:
        """The BVH's leaves: each triangle's box around the snapshot positions ``_xf``."""
        wp.launch(
            _triangle_bounds,
            self._tri_lo.shape[0],
            [self._tris, self._xf, self._tri_lo, self._tri_hi],
            device=self._xf.device,
        )

    def apply(self, model: Model, state_in: State, state_out: State, dt: float) -> None:
        """Resolve contacts in ``state_out`` (positions and velocities), using ``state_in`` for the sides."""
        s = model.s
        for _ in range(self.iterations):
            wp.launch(
                _snapshot,
                model.particle_count,
                [state_out.particle_q, state_out.particle_qd, self._x, self._v, self._xf],
                device=model.device,
            )
            if self._bvh is not None:
                self._bound_triangles()
                self._bvh.refit()
            if self._grid is not None:
                self._grid.build(self._xf, self.thickness)
            if self._points is not None:
                args = [state_in.particle_q, self._xf, self._pt_lo, self._pt_hi]
                wp.launch(_swept_boxes, model.particle_count, args, device=model.device)
                self._points.refit()
            wp.launch(
                _self_contact,
                model.particle_count,
                [
                    model.particle_inv_mass,
                    model.particle_q,
                    self._tris,
                    wp.uint64(self._bvh.id if self._bvh is not None else 0),
                    wp.uint64(self._grid.id if self._grid is not None else 0),
                    int(self.use_particles),
                    int(self.use_triangles),
                    s(self.thickness),
                    s(self.friction),
                    s(self.stick_velocity),
                    s(dt),
                    int(self._points is not None),
                    self._adj_start,
                    self._adj,
                    wp.uint64(self._points.id if self._points is not None else 0),
                    state_in.particle_q,
                    self._x,
                    self._v,
                    self._xf,
                    state_out.particle_q,
                    state_out.particle_qd,
                ],
                device=model.device,
            )
        if self._bound is not None:
            self._bound.apply(model, state_in, state_out, dt)
