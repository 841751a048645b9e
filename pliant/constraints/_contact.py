"""Unilateral contact constraints C ≥ 0: ground plane, particle–particle, point–triangle."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import warp as wp
from numpy.typing import ArrayLike

from ..collision import ParticleGrid, TriangleBVH, friction_law_code, friction_law_velocity
from ..model import STICK_VELOCITY, Model
from ._base import Constraint, ProjectionContext
from ._contact_math import (
    evaluate_ground,
    evaluate_particle_pairs,
    evaluate_point_triangle,
    ground_c,
    ground_grad,
    plane_barycentric,
    point_triangle_c,
    point_triangle_grad,
)
from ._ground_compliant import check_compliance, compliant_velocity, project_compliant
from ._self_friction import SelfFriction, project_particle_friction, project_point_triangle_friction


# ---------------------------------------------------------------------- ground
@wp.kernel
def _project_ground(
    inv_mass: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    normal: Any,
    d: Any,
    p_in: wp.array(dtype=Any),
    lam_in: wp.array(dtype=Any),
    p_out: wp.array(dtype=Any),
    lam_out: wp.array(dtype=Any),
):
    # Every thread writes its particle's p_out and lam_out, so the outputs may be the inputs (in place) or
    # fresh arrays (a step wp.Tape records), as collision.ground_contact's.
    i = wp.tid()
    w = inv_mass[i]
    x = p_in[i]
    lam = lam_in[i]
    if w != type(w)(0.0):
        c = ground_c(x, normal, d, radius[i])
        if c < type(w)(0.0):
            # |∇C| = 1: Δλ = −C/w and Δx = wΔλ n = −C n (the lecture's Δp = C n with C = min(·, 0)).
            lam = lam - c / w
            x = x - c * ground_grad(x, normal)
    p_out[i] = x
    lam_out[i] = lam


@wp.kernel
def _ground_velocity(
    inv_mass: wp.array(dtype=Any),
    normal: Any,
    friction: Any,
    restitution: Any,
    threshold: Any,
    law: int,
    stick_velocity: Any,
    dt: Any,
    lam_in: wp.array(dtype=Any),
    v_pre_in: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    p_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    # Every thread writes its particle's p_out and v_out: they may be the inputs (in place) or fresh arrays
    # (recorded step).
    i = wp.tid()
    lam = lam_in[i]
    zero = type(lam)(0.0)
    v = v_in[i]
    p = p_in[i]
    if lam <= zero:
        p_out[i] = p
        v_out[i] = v
        return
    vn = wp.dot(v, normal)
    vt = v - vn * normal
    # Coulomb: the tangential velocity change is bounded by μ times the normal one, |Δx_n|/Δt = wλ/Δt (the
    # whole push of this step, the part that held the weight included).
    vt_new = friction_law_velocity(law, vt, friction * inv_mass[i] * lam / dt, stick_velocity)
    vn_pre = wp.dot(v_pre_in[i], normal)
    vn_new = wp.max(vn, zero)
    if vn_pre < -threshold:
        vn_new = -restitution * vn_pre
    # Friction acts inside the step: p moves by Δt Δv_t too (v = (p − x)/Δt stays consistent, and a sticking
    # particle stays at x).
    p_out[i] = p + dt * (vt_new - vt)
    v_out[i] = vt_new + vn_new * normal


class Ground(Constraint):
    """Ground plane: C(x_i) = n·x_i + d − r_i ≥ 0, plus Coulomb friction and restitution on velocities.

    Positions are projected onto the plane (Δx = −C n when C < 0); after v = (p − x)/Δt the velocity
    pass of Müller et al. ("Detailed rigid body simulation with XPBD", 2020) limits the tangential
    velocity change to μ|Δx_n|/Δt (stopping it below that: static friction, smoothed below the stick
    velocity ε_v, :mod:`pliant.collision._friction`), moves p by Δt times that change (so that a sticking
    particle stays where it started the step) and sets v_n = −e ṽ_n from the pre-solve normal velocity ṽ_n.

    With ``stiffness`` κ [1/s²] the contact is compliant instead (:mod:`._ground_compliant`).

    Args:
        normal: plane normal n (normalised); default +y.
        offset: d [m]; default −height of ``model.ground`` (so the plane is y = height).
        friction: μ; default ``model.ground.friction``.
        restitution: e in [0, 1]; default ``model.ground.restitution``.
        stick_velocity: ε_v [m/s] >= 0; default ``model.ground.stick_velocity``
            (:data:`pliant.model.STICK_VELOCITY` without a ground).
        stiffness: κ [1/s²] > 0 of compliant contact; default ``model.ground.stiffness`` (None: hard).
        damping_ratio: ζ [-] >= 0 of its damper; default ``model.ground.damping_ratio``.
    """

    uses_deltas = False
    is_contact = True
    differentiable = True

    def __init__(
        self,
        *,
        normal: ArrayLike = (0.0, 1.0, 0.0),
        offset: float | None = None,
        friction: float | None = None,
        restitution: float | None = None,
        stick_velocity: float | None = None,
        stiffness: float | None = None,
        damping_ratio: float | None = None,
    ) -> None:
        super().__init__(compliance=0.0)
        check_compliance(stiffness, damping_ratio)
        self._stiffness, self._damping_ratio = stiffness, damping_ratio
        n = np.asarray(normal, float).reshape(3)
        if np.linalg.norm(n) == 0:
            raise ValueError("Ground: normal must be non-zero")
        if stick_velocity is not None and not (math.isfinite(stick_velocity) and stick_velocity >= 0):
            raise ValueError(f"Ground: stick_velocity must be >= 0 m/s (or omitted), got {stick_velocity}")
        self.normal = n / np.linalg.norm(n)
        self._offset, self._friction, self._restitution = offset, friction, restitution
        self._stick = stick_velocity

    def bind(self, model: Model, coloring: bool) -> None:
        """Resolve plane and material from ``model.ground``; one multiplier per particle."""
        self.model = model
        g = model.ground
        self.offset = float(self._offset if self._offset is not None else (-g.height if g else 0.0))
        self.friction = float(self._friction if self._friction is not None else (g.friction if g else 0.0))
        self.restitution = float(
            self._restitution if self._restitution is not None else (g.restitution if g else 0.0)
        )
        if self.friction < 0 or not 0 <= self.restitution <= 1:
            raise ValueError("Ground: friction must be >= 0 and restitution in [0, 1]")
        self.stick_velocity = float(
            self._stick if self._stick is not None else (g.stick_velocity if g else STICK_VELOCITY)
        )
        self.friction_law = friction_law_code(g.friction_law if g else "coulomb")  # the model's ground's
        # κ [1/s²] of compliant contact, not the PBD stiffness k in [0, 1] every Constraint has
        kappa = self._stiffness if self._stiffness is not None else (g.stiffness if g else None)
        self.contact_stiffness: float | None = kappa
        zeta = self._damping_ratio if self._damping_ratio is not None else (g.damping_ratio if g else 0.0)
        self.damping = 2.0 * zeta * kappa**0.5 if kappa is not None else 0.0  # b [1/s]
        self.count = model.particle_count
        self.lam = wp.zeros(self.count, dtype=model.scalar, device=model.device)
        self._x_start: wp.array | None = None

    def begin_step(self, ctx: ProjectionContext, x: wp.array, p: wp.array, dt: float) -> None:
        """Reset λ; compliant contact keeps the step's start positions x (its damper's reference)."""
        super().begin_step(ctx, x, p, dt)
        self._x_start = x

    def evaluate(self, x: wp.array) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """C [N], indices [N, 1] and ∇C [N, 1, 3] of every particle's ground constraint at ``x``."""
        return evaluate_ground(self.model, self.normal, self.offset, x)

    def project(self, ctx: ProjectionContext, p: wp.array, dt: float) -> wp.array | None:
        """Push particles onto the plane (each thread touches only its own particle).

        One kernel either way: it updates ``p`` and λ in place, or in a differentiable step writes fresh
        arrays; it returns the positions it wrote.
        Its gradient is that of the active set: exact away from the contact switch C = 0, a one-sided
        (sub)gradient at it.
        """
        m = self.model
        p_out, lam_out = (
            (ctx.fresh(p), ctx.fresh(self._multipliers())) if ctx.requires_grad else (p, self.lam)
        )
        if self.contact_stiffness is not None:
            return project_compliant(self, ctx, p, dt)
        ctx.launch(
            _project_ground,
            self.count,
            [
                m.particle_inv_mass,
                m.particle_radius,
                m.vec3(*self.normal),
                m.s(self.offset),
                p,
                self.lam,
                p_out,
                lam_out,
            ],
        )
        self.lam = lam_out
        return p_out

    def end_step(
        self, ctx: ProjectionContext, x: wp.array, p: wp.array, v: wp.array, dt: float
    ) -> tuple[wp.array, wp.array]:
        """Friction and restitution for the particles the plane pushed this step; friction moves the
        positions p too (Δt Δv_t). Returns (p, v) written: ``p`` and ``v`` themselves (in place), or fresh
        arrays in a differentiable step.

        Differentiable as far as smooth: friction is C¹ (the stick velocity ε_v smooths the Coulomb
        switch); the restitution switch (approach speed above 2|g|Δt) gives one-sided gradients.
        """
        if self.contact_stiffness is not None:
            return compliant_velocity(self, ctx, p, v, dt)
        m = self.model
        g = float(np.linalg.norm(m.gravity))
        p_out, v_out = (ctx.fresh(p), ctx.fresh(v)) if ctx.requires_grad else (p, v)
        ctx.launch(
            _ground_velocity,
            self.count,
            [
                m.particle_inv_mass,
                m.vec3(*self.normal),
                m.s(self.friction),
                m.s(self.restitution),
                m.s(2.0 * g * dt),  # below this approach speed a contact rests instead of bouncing
                self.friction_law,
                m.s(self.stick_velocity),
                m.s(dt),
                self.lam,
                ctx.v_pred,
                p,
                v,
                p_out,
                v_out,
            ],
        )
        return p_out, v_out


# ---------------------------------------------------------------------- particle–particle
@wp.kernel
def _project_particle_collision(
    grid: wp.uint64,
    inv_mass: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    query_radius: Any,
    p_in: wp.array(dtype=Any),
    delta_out: wp.array(dtype=Any),
    count_out: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    wi = inv_mass[i]
    zero = type(wi)(0.0)
    if wi == zero:
        return
    xi = p_in[i]
    ri = radius[i]
    acc = xi * zero
    n_hit = wp.int32(0)
    for j in wp.hash_grid_query(grid, xi, query_radius):
        if j != i:
            wj = inv_mass[j]
            d = xi - p_in[j]
            l = wp.length(d)
            c = l - ri - radius[j]
            if c < zero and l > zero:
                # The lecture's mass-weighted split: particle i moves w_i/(w_i + w_j) of the overlap.
                acc = acc - (wi / (wi + wj)) * c * (d / l)
                n_hit += wp.int32(1)
    if n_hit > 0:
        # Each thread writes only its own particle: no conflicts, the pairs are symmetric.
        delta_out[i] = delta_out[i] + acc
        count_out[i] = count_out[i] + n_hit


class ParticleCollision(Constraint):
    """Particle–particle contact: C = |x_i − x_j| − r_i − r_j ≥ 0, broad phase by ``wp.HashGrid``.

    Each particle moves by Δx_i = −w_i/(w_i + w_j) C n̂ for every overlapping neighbour (the lecture's
    formula); the corrections are accumulated per particle and averaged (Jacobi), whatever the schedule,
    because contacts change every step and are not worth colouring.

    Args:
        cell_size: hash-grid cell [m]; default twice the largest particle radius.
        friction: Coulomb μ between particles (0: none; :mod:`._self_friction`).
        stick_velocity: ε_v [m/s] of the smoothed law; default :data:`pliant.model.STICK_VELOCITY`.
        friction_law: the law's name in the friction-law registry.

    Every particle collides with every other one, including its neighbours in a mesh: give particles a
    radius below half the rest spacing of connected particles.
    """

    always_jacobi = True
    is_contact = True

    def __init__(
        self,
        *,
        cell_size: float | None = None,
        friction: float = 0.0,
        stick_velocity: float | None = None,
        friction_law: str = "coulomb",
    ) -> None:
        super().__init__(compliance=0.0)
        self.friction_settings = SelfFriction("ParticleCollision", friction, stick_velocity, friction_law)
        if cell_size is not None and not (math.isfinite(cell_size) and cell_size > 0):
            # Checked here, not when bind() builds the grid, so a scene names the field before any work.
            raise ValueError(f"cell_size must be a positive length [m] (or omitted), got {cell_size}")
        self._cell = cell_size

    def bind(self, model: Model, coloring: bool) -> None:
        """Allocate the hash grid."""
        self.model = model
        rmax = float(model.particle_radius.numpy().max())
        if rmax <= 0:
            raise ValueError("ParticleCollision: particles need a radius > 0 (ModelBuilder radius=)")
        self.query_radius = 2.0 * rmax
        self.grid = ParticleGrid(model.device, model.dtype, self._cell or self.query_radius)
        self.count = model.particle_count
        self.friction_settings.bind(model, self.count)

    def evaluate(self, x: wp.array) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """C [P], pairs [P, 2] and ∇C [P, 2, 3] of the particle pairs within the query radius at ``x``."""
        return evaluate_particle_pairs(self.model, self.grid, self.query_radius, x)

    def begin_step(self, ctx: ProjectionContext, x: wp.array, p: wp.array, dt: float) -> None:
        """Rebuild the grid over the predicted positions; friction keeps the step's start positions x."""
        ctx.call(self.grid.build, p)
        self.friction_settings.begin_step(ctx, x)

    def project(self, ctx: ProjectionContext, p: wp.array, dt: float) -> None:
        """Accumulate contact corrections into ``ctx.delta``."""
        m, f = self.model, self.friction_settings
        args = [wp.uint64(self.grid.id), m.particle_inv_mass, m.particle_radius, m.s(self.query_radius)]
        kernel = project_particle_friction if f.friction > 0 else _project_particle_collision
        fric = f.args(dt, p) if f.friction > 0 else [p]
        ctx.launch(kernel, self.count, [*args, *fric, ctx.delta, ctx.delta_count])


# ---------------------------------------------------------------------- point–triangle
@wp.kernel
def _detect_point_triangle(
    mesh: wp.uint64,
    tri_indices: wp.array2d(dtype=wp.int32),
    inv_mass: wp.array(dtype=Any),
    thickness: Any,
    margin: Any,
    x_in: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    capacity: int,
    contact_count_out: wp.array(dtype=wp.int32),
    contact_particle_out: wp.array(dtype=wp.int32),
    contact_tri_out: wp.array(dtype=wp.int32),
    contact_side_out: wp.array(dtype=Any),
):
    q = wp.tid()
    xq = x_in[q]
    pq = p_in[q]
    zero = type(thickness)(0.0)
    reach = thickness + margin
    lo = wp.min(xq, pq)
    hi = wp.max(xq, pq)
    lo32 = wp.vec3(wp.float32(lo[0] - reach), wp.float32(lo[1] - reach), wp.float32(lo[2] - reach))
    hi32 = wp.vec3(wp.float32(hi[0] + reach), wp.float32(hi[1] + reach), wp.float32(hi[2] + reach))
    for t in wp.mesh_query_aabb(mesh, lo32, hi32):
        i1 = tri_indices[t, 0]
        i2 = tri_indices[t, 1]
        i3 = tri_indices[t, 2]
        if q == i1 or q == i2 or q == i3:
            continue
        if inv_mass[q] + inv_mass[i1] + inv_mass[i2] + inv_mass[i3] == zero:
            continue
        # Which side q started on decides the sign of the constraint (the lecture's two forms).
        n0 = wp.cross(x_in[i2] - x_in[i1], x_in[i3] - x_in[i1])
        s0 = wp.dot(xq - x_in[i1], n0)
        if s0 == zero:
            continue
        side = type(thickness)(1.0)
        if s0 < zero:
            side = type(thickness)(-1.0)
        a = p_in[i1]
        b = p_in[i2]
        c = p_in[i3]
        bary = plane_barycentric(pq, a, b, c)
        tol = type(thickness)(-0.01)
        if bary[0] < tol or bary[1] < tol or bary[2] < tol:
            continue
        if point_triangle_c(pq, a, b, c, side, thickness) < margin:
            k = wp.atomic_add(contact_count_out, 0, 1)
            if k < capacity:
                contact_particle_out[k] = q
                contact_tri_out[k] = t
                contact_side_out[k] = side


@wp.kernel
def _project_point_triangle(
    tri_indices: wp.array2d(dtype=wp.int32),
    inv_mass: wp.array(dtype=Any),
    thickness: Any,
    capacity: int,
    contact_count: wp.array(dtype=wp.int32),
    contact_particle: wp.array(dtype=wp.int32),
    contact_tri: wp.array(dtype=wp.int32),
    contact_side: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    delta_out: wp.array(dtype=Any),
    count_out: wp.array(dtype=wp.int32),
):
    k = wp.tid()
    if k >= wp.min(contact_count[0], capacity):
        return
    q = contact_particle[k]
    t = contact_tri[k]
    i1 = tri_indices[t, 0]
    i2 = tri_indices[t, 1]
    i3 = tri_indices[t, 2]
    xq = p_in[q]
    x1 = p_in[i1]
    x2 = p_in[i2]
    x3 = p_in[i3]
    side = contact_side[k]
    c = point_triangle_c(xq, x1, x2, x3, side, thickness)
    if c >= type(thickness)(0.0):
        return
    gq, g1, g2, g3 = point_triangle_grad(xq, x1, x2, x3, side)
    wq = inv_mass[q]
    w1 = inv_mass[i1]
    w2 = inv_mass[i2]
    w3 = inv_mass[i3]
    wgs = wq * wp.dot(gq, gq) + w1 * wp.dot(g1, g1) + w2 * wp.dot(g2, g2) + w3 * wp.dot(g3, g3)
    if wgs == type(thickness)(0.0):
        return
    dl = -c / wgs
    wp.atomic_add(delta_out, q, (wq * dl) * gq)
    wp.atomic_add(delta_out, i1, (w1 * dl) * g1)
    wp.atomic_add(delta_out, i2, (w2 * dl) * g2)
    wp.atomic_add(delta_out, i3, (w3 * dl) * g3)
    wp.atomic_add(count_out, q, 1)
    wp.atomic_add(count_out, i1, 1)
    wp.atomic_add(count_out, i2, 1)
    wp.atomic_add(count_out, i3, 1)


@wp.kernel
def _point_triangle_min_c(
    tri_indices: wp.array2d(dtype=wp.int32),
    thickness: Any,
    capacity: int,
    contact_count: wp.array(dtype=wp.int32),
    contact_particle: wp.array(dtype=wp.int32),
    contact_tri: wp.array(dtype=wp.int32),
    contact_side: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    k = wp.tid()
    if k >= wp.min(contact_count[0], capacity):
        return
    t = contact_tri[k]
    c = point_triangle_c(
        p_in[contact_particle[k]],
        p_in[tri_indices[t, 0]],
        p_in[tri_indices[t, 1]],
        p_in[tri_indices[t, 2]],
        contact_side[k],
        thickness,
    )
    wp.atomic_min(out, 0, c)


class PointTriangleCollision(Constraint):
    """Point–triangle contact with thickness h: C = s (q − x1)·n̂ − h ≥ 0 (the lecture's collision).

    Contacts are generated once per step (Algorithm 1, line 7): a particle q whose swept box x → p comes
    within h + margin of a triangle it is not a vertex of, and whose projection falls inside it, gets a
    contact with s = ±1 the side q was on at the start of the step. The gradient is exact (the triangle's
    vertices move too; see :func:`point_triangle_grad`). Corrections are averaged (Jacobi).

    Args:
        thickness: h [m].
        triangles: [T, 3]; default ``model.tri_indices`` (cloth self-collision and collisions with any other
            triangle mesh in the model: pin its particles to make it a static obstacle).
        margin: extra detection distance [m] (default h).
        capacity: most contacts per step (extra ones are dropped; see :attr:`overflow`).
        friction: Coulomb μ between the point and the triangle (:mod:`._self_friction`; 0: none).
        stick_velocity: ε_v [m/s] of the smoothed law; default :data:`pliant.model.STICK_VELOCITY`.
        friction_law: a name of :data:`pliant.collision.FRICTION_LAWS`.
    """

    always_jacobi = True
    is_contact = True

    def __init__(
        self,
        *,
        thickness: float = 0.01,
        triangles: ArrayLike | None = None,
        margin: float | None = None,
        capacity: int | None = None,
        friction: float = 0.0,
        stick_velocity: float | None = None,
        friction_law: str = "coulomb",
    ) -> None:
        super().__init__(compliance=0.0)
        self.friction_settings = SelfFriction(
            "PointTriangleCollision", friction, stick_velocity, friction_law
        )
        if thickness <= 0:
            raise ValueError(f"PointTriangleCollision: thickness must be > 0 m, got {thickness}")
        self.thickness = float(thickness)
        self.margin = float(thickness if margin is None else margin)
        self._tris = triangles
        self._capacity = capacity

    def bind(self, model: Model, coloring: bool) -> None:
        """Build the BVH and the contact buffers."""
        self.model = model
        tris = model.tri_indices.numpy() if self._tris is None else np.asarray(self._tris, np.int32)
        tris = tris.reshape(-1, 3)
        if tris.shape[0] == 0:
            raise ValueError("PointTriangleCollision: the model has no triangles; pass triangles=")
        d, f = model.device, model.scalar
        self.tri_indices: wp.array = wp.array(tris, dtype=wp.int32, device=d)
        self.bvh = TriangleBVH(d, tris, model.particle_count)
        self.capacity = int(self._capacity or 8 * model.particle_count)
        self.contact_count = wp.zeros(1, dtype=wp.int32, device=d)
        self.contact_particle = wp.zeros(self.capacity, dtype=wp.int32, device=d)
        self.contact_tri = wp.zeros(self.capacity, dtype=wp.int32, device=d)
        self.contact_side = wp.zeros(self.capacity, dtype=f, device=d)
        self._min = wp.zeros(1, dtype=f, device=d)
        self.count = self.capacity
        self.friction_settings.bind(model, self.capacity)

    def begin_step(self, ctx: ProjectionContext, x: wp.array, p: wp.array, dt: float) -> None:
        """Refit the BVH at the predicted positions and generate this step's contacts."""
        m = self.model
        self.friction_settings.begin_step(ctx, x)
        self.bvh.update(p, ctx)
        ctx.call(self.contact_count.zero_)
        ctx.launch(
            _detect_point_triangle,
            m.particle_count,
            [
                wp.uint64(self.bvh.id),
                self.tri_indices,
                m.particle_inv_mass,
                m.s(self.thickness),
                m.s(self.margin),
                x,
                p,
                self.capacity,
                self.contact_count,
                self.contact_particle,
                self.contact_tri,
                self.contact_side,
            ],
        )

    def _contact_args(self) -> list:
        return [
            self.capacity,
            self.contact_count,
            self.contact_particle,
            self.contact_tri,
            self.contact_side,
        ]

    def project(self, ctx: ProjectionContext, p: wp.array, dt: float) -> None:
        """Accumulate contact corrections into ``ctx.delta``."""
        m, f = self.model, self.friction_settings
        args = [self.tri_indices, m.particle_inv_mass, m.s(self.thickness), *self._contact_args()]
        kernel = project_point_triangle_friction if f.friction > 0 else _project_point_triangle
        fric = f.args(dt, p) if f.friction > 0 else [p]
        ctx.launch(kernel, self.capacity, [*args, *fric, ctx.delta, ctx.delta_count])

    def evaluate(self, x: wp.array) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """C [K], indices [K, 4] (point, triangle) and ∇C [K, 4, 3] of this step's contacts at ``x``."""
        return evaluate_point_triangle(self.model, self, x)

    def min_value(self, p: wp.array) -> float:
        """Smallest C over this step's contacts at positions ``p`` [m] (host sync; for tests)."""
        m = self.model
        self._min.fill_(1e30)
        wp.launch(
            _point_triangle_min_c,
            self.capacity,
            [self.tri_indices, m.s(self.thickness), *self._contact_args(), p, self._min],
            device=m.device,
        )
        return float(self._min.numpy()[0])

    @property
    def overflow(self) -> bool:
        """Whether the last step found more contacts than ``capacity`` (host sync)."""
        return int(self.contact_count.numpy()[0]) > self.capacity
