"""Shape matching for rigid and deformable clusters, with optional oriented particles."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import warp as wp
from numpy.typing import ArrayLike

from ..model import Model
from ._base import Constraint, ProjectionContext, color_incidence, pbd_iteration_stiffness, sort_by_color


@wp.func
def polar_rotation(A: Any):
    """R of the polar decomposition A = R S (R a rotation, det R = +1) via ``wp.svd3``.

    With A = U Σ Vᵀ, R = U Vᵀ; when det(U Vᵀ) < 0 (a reflection) the column of U belonging to the
    smallest singular value is negated, which gives the closest proper rotation.
    """
    # Zero-valued outputs for svd3 to fill: initialising them as copies of A (same values after svd3)
    # would also route their adjoints back into A and corrupt ∂R/∂A.
    zero = A[0, 0] * type(A[0, 0])(0.0)
    U = A * zero
    sigma = wp.get_diag(A) * zero
    V = A * zero
    wp.svd3(A, U, sigma, V)
    R = U * wp.transpose(V)
    if wp.determinant(R) < type(sigma[0])(0.0):
        # wp.svd3 sorts singular values in decreasing order: the last column is the smallest.
        one = type(sigma[0])(1.0)
        D = wp.diag(type(sigma)(one, one, -one))
        R = U * D * wp.transpose(V)
    return R


@wp.func
def oriented_moment(m: Any, R: Any, radii: Any):
    """A_i = (1/5) m R diag(a², b², c²): ∫ρ (R y) yᵀ dV of a solid ellipsoid with semi-axes (a, b, c).

    Müller & Chentanez, "Solid simulation with oriented particles", SIGGRAPH 2011; for a sphere of radius
    r this is (1/5) m r² R.
    """
    fifth = type(m)(0.2)
    D = wp.diag(type(radii)(radii[0] * radii[0], radii[1] * radii[1], radii[2] * radii[2]))
    return (fifth * m) * (R * D)


@wp.func
def shape_matching_goal(R: Any, rest: Any, rest_center: Any, center: Any):
    """g_i = R (p̄_i − c̄) + c  [m]."""
    return R * (rest - rest_center) + center


@wp.kernel
def _project_shape(
    # Clusters (CSR):
    offsets: wp.array(dtype=wp.int32),
    members: wp.array(dtype=wp.int32),
    rest: wp.array(dtype=Any),
    rest_center: wp.array(dtype=Any),
    member_mass: wp.array(dtype=Any),
    radii: wp.array(dtype=Any),
    # Model:
    inv_mass: wp.array(dtype=Any),
    # Parameters:
    k_s: Any,
    oriented: int,
    offset: int,
    jacobi: int,
    # In/out:
    p_io: wp.array(dtype=Any),
    orientation_io: wp.array(dtype=Any),
    delta_out: wp.array(dtype=Any),
    count_out: wp.array(dtype=wp.int32),
):
    s = offset + wp.tid()
    a = offsets[s]
    b = offsets[s + 1]
    zero = type(k_s)(0.0)
    total = zero
    c = rest[a] * zero
    for k in range(a, b):
        c = c + member_mass[k] * p_io[members[k]]
        total = total + member_mass[k]
    c = c / total
    cb = rest_center[s]
    A = wp.outer(c, c) * zero
    for k in range(a, b):
        i = members[k]
        A = A + member_mass[k] * wp.outer(p_io[i] - c, rest[k] - cb)
        if oriented != 0:
            A = A + oriented_moment(member_mass[k], wp.quat_to_matrix(orientation_io[i]), radii[k])
    R = polar_rotation(A)
    q = wp.quat_from_matrix(R)
    for k in range(a, b):
        i = members[k]
        if inv_mass[i] > zero:
            dp = k_s * (shape_matching_goal(R, rest[k], cb, c) - p_io[i])
            if jacobi != 0:
                wp.atomic_add(delta_out, i, dp)
                wp.atomic_add(count_out, i, 1)
            else:
                p_io[i] = p_io[i] + dp
        if oriented != 0:
            # Rest orientations are the identity: a particle turns with its cluster.
            orientation_io[i] = q


# ---------------------------------------------------------------------- differentiable path
# The same update split into per-member and per-cluster kernels that accumulate with atomics and write
# fresh arrays, so that a wp.Tape can replay it (the fused kernel above loops over a cluster's members
# with loop-carried sums, which Warp's adjoint does not replay).
@wp.kernel
def _cluster_center(
    member_cluster: wp.array(dtype=wp.int32),
    members: wp.array(dtype=wp.int32),
    member_mass: wp.array(dtype=Any),
    cluster_mass: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    center_out: wp.array(dtype=Any),
):
    k = wp.tid()
    s = member_cluster[k]
    wp.atomic_add(center_out, s, (member_mass[k] / cluster_mass[s]) * p_in[members[k]])


@wp.kernel
def _cluster_moment(
    member_cluster: wp.array(dtype=wp.int32),
    members: wp.array(dtype=wp.int32),
    member_mass: wp.array(dtype=Any),
    rest: wp.array(dtype=Any),
    rest_center: wp.array(dtype=Any),
    center_in: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    moment_out: wp.array(dtype=Any),
):
    k = wp.tid()
    s = member_cluster[k]
    wp.atomic_add(
        moment_out, s, member_mass[k] * wp.outer(p_in[members[k]] - center_in[s], rest[k] - rest_center[s])
    )


@wp.kernel
def _cluster_rotation(moment_in: wp.array(dtype=Any), rotation_out: wp.array(dtype=Any)):
    s = wp.tid()
    rotation_out[s] = polar_rotation(moment_in[s])


@wp.kernel
def _shape_deltas(
    member_cluster: wp.array(dtype=wp.int32),
    members: wp.array(dtype=wp.int32),
    rest: wp.array(dtype=Any),
    rest_center: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=Any),
    k_s: Any,
    center_in: wp.array(dtype=Any),
    rotation_in: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    delta_out: wp.array(dtype=Any),
    count_out: wp.array(dtype=wp.int32),
):
    k = wp.tid()
    s = member_cluster[k]
    i = members[k]
    if inv_mass[i] > type(k_s)(0.0):
        goal = shape_matching_goal(rotation_in[s], rest[k], rest_center[s], center_in[s])
        wp.atomic_add(delta_out, i, k_s * (goal - p_in[i]))
        wp.atomic_add(count_out, i, 1)


@wp.kernel
def _angular_velocity(
    inv_dt: Any,
    q_prev: wp.array(dtype=Any),
    q_in: wp.array(dtype=Any),
    w_out: wp.array(dtype=Any),
):
    # ω = 2 vec(q q_prev⁻¹)/Δt, taking the short way round (the sign of the real part).
    i = wp.tid()
    dq = q_in[i] * wp.quat_inverse(q_prev[i])
    s = type(inv_dt)(2.0) * inv_dt
    if dq[3] < type(inv_dt)(0.0):
        s = -s
    w_out[i] = type(w_out[i])(dq[0] * s, dq[1] * s, dq[2] * s)


class ShapeMatching(Constraint):
    """Shape matching (Müller, Heidelberger, Teschner, Gross 2005): Δp_i = k_S [R(p̄_i − c̄) + c − p_i].

    A = Σ m_i (p_i − c)(p̄_i − c̄)ᵀ (= Σ m_i p_i p̄_iᵀ − M c c̄ᵀ), R its polar rotation (``wp.svd3`` with the
    reflection fixed). k_S = 1 makes a cluster rigid; smaller k_S a deformable body. With ``radii`` the
    particles are oriented (Müller & Chentanez 2011): A gains Σ (1/5) m_i R_i diag(r_i²) (the lecture's
    slide drops r², which makes the term dimensionally wrong), and each particle's orientation quaternion
    follows its cluster, kept in :attr:`orientation` (identity at rest).

    Clusters may overlap; the colouring schedule colours them so that a colour's clusters are disjoint.
    Pinned members do not move but still count in c and A. Angular momentum is conserved because RᵀA is
    symmetric.

    Args:
        clusters: list of particle index arrays, one per cluster (default: one cluster of all particles).
        stiffness: k_S in [0, 1] (corrected per iteration as 1 − (1 − k_S)^(1/n), so n iterations give k_S).
        radii: per-particle ellipsoid semi-axes [m] ([N] sphere radii or [N, 3]) to enable oriented
            particles; default None (plain points).

    Example::

        rigid = pl.constraints.ShapeMatching([np.arange(model.particle_count)], stiffness=1.0)
        solver = pl.solvers.XPBD(model, constraints=[rigid])
    """

    uses_deltas = True
    differentiable = True

    def __init__(
        self, clusters: Sequence[Any] | None = None, *, stiffness: float = 1.0, radii: ArrayLike | None = None
    ) -> None:
        super().__init__(compliance=None, stiffness=stiffness)
        self._clusters = None if clusters is None else [np.asarray(c, np.int64).reshape(-1) for c in clusters]
        self._radii = radii

    def bind(self, model: Model, coloring: bool) -> None:
        """Rest shapes, masses and colours of the clusters."""
        self.model = model
        n = model.particle_count
        clusters = self._clusters if self._clusters is not None else [np.arange(n)]
        for k, c in enumerate(clusters):
            if c.size < 2 or c.min() < 0 or c.max() >= n:
                raise ValueError(f"ShapeMatching: cluster {k} needs >= 2 particle indices in [0, {n})")
        cid = np.concatenate([np.full(c.size, k) for k, c in enumerate(clusters)])
        mem = np.concatenate(clusters)
        inv_mass = model.particle_inv_mass.numpy()
        order, self.color_offsets = (
            sort_by_color(color_incidence(cid[inv_mass[mem] > 0], mem[inv_mass[mem] > 0], len(clusters), n))
            if coloring
            else (np.arange(len(clusters)), np.array([0, len(clusters)], np.int64))
        )
        clusters = [clusters[k] for k in order]
        mem = np.concatenate(clusters)
        offsets = np.concatenate([[0], np.cumsum([c.size for c in clusters])]).astype(np.int32)
        q = model.particle_q_np
        mass = model.particle_mass_np[mem]
        rest_center = np.stack(
            [np.average(q[c], axis=0, weights=model.particle_mass_np[c]) for c in clusters]
        )
        if self._radii is None:
            radii = np.zeros((mem.size, 3))
            self.oriented = False
        else:
            r = np.asarray(self._radii, float)
            r = np.repeat(r.reshape(-1, 1), 3, axis=1) if r.ndim == 1 else r.reshape(-1, 3)
            if r.shape[0] != n:
                raise ValueError(f"ShapeMatching: radii need one entry per particle ({n}), got {r.shape[0]}")
            radii = r[mem]
            self.oriented = True
        # Oriented particles write orientations in place (and race under Jacobi): not differentiable.
        self.differentiable = not self.oriented
        d, f, v = model.device, model.scalar, model.vec3
        self.count = len(clusters)
        self.offsets: wp.array = wp.array(offsets, dtype=wp.int32, device=d)
        self.members: wp.array = wp.array(mem.astype(np.int32), dtype=wp.int32, device=d)
        self.rest: wp.array = wp.array(q[mem], dtype=v, device=d)
        self.rest_center: wp.array = wp.array(rest_center, dtype=v, device=d)
        self.member_mass: wp.array = wp.array(mass, dtype=f, device=d)
        self.radii: wp.array = wp.array(radii, dtype=v, device=d)
        quat = wp.quat if model.dtype == "float32" else wp.quatd
        ident = np.tile(np.array([0.0, 0.0, 0.0, 1.0]), (n, 1))
        self.orientation: wp.array = wp.array(ident, dtype=quat, device=d)
        self._orientation_prev: wp.array = wp.array(ident, dtype=quat, device=d)
        self.angular_velocity = wp.zeros(n, dtype=v, device=d)
        self._ident = ident
        self.order = order
        sizes = np.diff(offsets)
        self.member_cluster: wp.array = wp.array(
            np.repeat(np.arange(len(clusters)), sizes).astype(np.int32), device=d
        )
        cmass = np.array([model.particle_mass_np[c].sum() for c in clusters])
        self.cluster_mass: wp.array = wp.array(cmass, dtype=f, device=d)
        self._mat = model.mat33

    def reset_orientations(self) -> None:
        """Set every particle orientation back to the identity (the rest orientation)."""
        self.orientation.assign(self._ident)

    def begin_step(self, ctx: ProjectionContext, x: wp.array, p: wp.array, dt: float) -> None:
        """Remember the orientations at the start of the step (oriented particles)."""
        if self.oriented:
            ctx.call(wp.copy, self._orientation_prev, self.orientation)

    def end_step(self, ctx: ProjectionContext, x: wp.array, p: wp.array, v: wp.array, dt: float) -> None:
        """Angular velocities from the orientation change of the step (oriented particles)."""
        if self.oriented:
            m = self.model
            ctx.launch(
                _angular_velocity,
                m.particle_count,
                [m.s(1.0 / dt), self._orientation_prev, self.orientation, self.angular_velocity],
            )

    def project(self, ctx: ProjectionContext, p: wp.array, dt: float) -> None:
        """Pull each cluster towards its best-fit rigid motion of the rest shape."""
        m = self.model
        k = pbd_iteration_stiffness(self.stiffness, ctx.iterations)
        if ctx.requires_grad:
            self._project_differentiable(ctx, p, m.s(k))
            return
        for off, size in self.color_ranges(ctx.coloring):
            ctx.launch(
                _project_shape,
                size,
                [
                    self.offsets,
                    self.members,
                    self.rest,
                    self.rest_center,
                    self.member_mass,
                    self.radii,
                    m.particle_inv_mass,
                    m.s(k),
                    int(self.oriented),
                    off,
                    int(not ctx.coloring),
                    p,
                    self.orientation,
                    ctx.delta,
                    ctx.delta_count,
                ],
            )

    def _project_differentiable(self, ctx: ProjectionContext, p: wp.array, k_s: Any) -> None:
        """The Jacobi sweep in four tape-replayable kernels writing fresh arrays (gradients requested).

        ∂R/∂A goes through ``wp.svd3``'s adjoint, which divides by σ_i² − σ_j²: a cluster whose current
        moment A has repeated singular values (an undeformed isotropic cluster, e.g. a cube of equal
        masses) has no usable gradient there; use clusters with distinct principal extents.
        """
        m = self.model
        n, c = self.members.shape[0], self.count
        d = m.device
        center = wp.zeros(c, dtype=m.vec3, device=d, requires_grad=True)
        moment = wp.zeros(c, dtype=self._mat, device=d, requires_grad=True)
        rotation = wp.zeros(c, dtype=self._mat, device=d, requires_grad=True)
        ctx.launch(
            _cluster_center,
            n,
            [self.member_cluster, self.members, self.member_mass, self.cluster_mass, p, center],
        )
        ctx.launch(
            _cluster_moment,
            n,
            [
                self.member_cluster,
                self.members,
                self.member_mass,
                self.rest,
                self.rest_center,
                center,
                p,
                moment,
            ],
        )
        ctx.launch(_cluster_rotation, c, [moment, rotation])
        ctx.launch(
            _shape_deltas,
            n,
            [
                self.member_cluster,
                self.members,
                self.rest,
                self.rest_center,
                m.particle_inv_mass,
                k_s,
                center,
                rotation,
                p,
                ctx.delta,
                ctx.delta_count,
            ],
        )
