"""RigidBodySolver: Newton–Euler rigid bodies over particle clusters, to compare with shape matching."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import warp as wp

from ...collision import Colliders
from ...model import STICK_VELOCITY, Control, Model, State
from .._base import Solver
from ._contact import gather_contacts, solve_positions, solve_velocities
from ._motion import advance_rotation, free_motion
from ._pairs import _coupled_contacts, _free_bodies, _place_bodies


@wp.kernel
def _rigid_step(
    # Bodies (CSR):
    offsets: wp.array(dtype=wp.int32),
    members: wp.array(dtype=wp.int32),
    rest: wp.array(dtype=Any),
    rest_center: wp.array(dtype=Any),
    inertia_body: wp.array(dtype=Any),
    # Model:
    mass: wp.array(dtype=Any),
    gravity: Any,
    # Control:
    f_ext: wp.array(dtype=Any),
    # Parameters:
    dt: Any,
    # Contact (surfaces = 0: none; else ground + colliders, the scratch's slots per member):
    surfaces: int,
    iterations: int,
    radius: wp.array(dtype=Any),
    ground: int,
    ground_height: Any,
    ground_coef: Any,
    col_count: int,
    col_kind: wp.array(dtype=wp.int32),
    col_pos: wp.array(dtype=Any),
    col_aux: wp.array(dtype=Any),
    col_rot: wp.array(dtype=Any),
    col_radius: wp.array(dtype=Any),
    col_mesh: wp.array(dtype=wp.uint64),
    col_coef: wp.array(dtype=Any),
    # State in:
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    # Out (the contact scratch, refilled each step, then the particles):
    c_r_out: wp.array(dtype=Any),
    c_n_out: wp.array(dtype=Any),
    c_coef_out: wp.array(dtype=Any),
    c_aux_out: wp.array(dtype=Any),
    c_imp_out: wp.array(dtype=Any),
    c_lam_out: wp.array(dtype=Any),
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    b = wp.tid()
    a0 = offsets[b]
    a1 = offsets[b + 1]
    cb = rest_center[b]
    Ib = inertia_body[b]
    M, c, q, v, w, R_new = free_motion(a0, a1, members, rest, cb, Ib, mass, gravity, f_ext, dt, x_in, v_in)
    c_new = c + dt * v
    if surfaces != 0:
        # Body-level contact (._contact): impulses on (v, ω) from the contacts of the free end pose, then
        # the pose again from the corrected velocities plus the split impulse's pseudo-velocities.
        inv_m = type(dt)(1.0) / M
        inv_i = R_new * wp.inverse(Ib) * wp.transpose(R_new)
        start = a0 * surfaces
        # Restitution only above twice the speed gravity gives in a step: a resting contact's approach
        # speed is |g|Δt, and reflecting it would make a body hop (and creep down a slope between hops).
        bounce = type(dt)(2.0) * dt * wp.length(gravity)
        end = gather_contacts(
            start, a0, a1, members, rest, cb, radius, c_new, R_new, ground, ground_height, ground_coef,
            bounce, col_count, col_kind, col_pos, col_aux, col_rot, col_radius, col_mesh, col_coef, inv_m,
            inv_i, v, w, c_r_out, c_n_out, c_coef_out, c_aux_out,
        )  # fmt: skip
        if end > start:
            v, w = solve_velocities(
                start, end, iterations, inv_m, inv_i, v, w, c_r_out, c_n_out, c_coef_out, c_aux_out,
                c_imp_out, c_lam_out,
            )  # fmt: skip
            vp, wq = solve_positions(
                start, end, iterations, dt, inv_m, inv_i, v, w, c_r_out, c_n_out, c_coef_out, c_aux_out,
                c_lam_out,
            )  # fmt: skip
            c_new = c + dt * (v + vp)
            R_new = advance_rotation(q, w + wq, dt)
    for k in range(a0, a1):
        i = members[k]
        r = R_new * (rest[k] - cb)
        x_out[i] = c_new + r
        v_out[i] = v + wp.cross(w, r)


@wp.kernel
def _pack_colliders(
    first: int,
    stick_velocity: Any,
    kind: wp.array(dtype=wp.int32),
    pos: wp.array(dtype=Any),
    aux: wp.array(dtype=Any),
    rot: wp.array(dtype=Any),
    radius: wp.array(dtype=Any),
    mesh: wp.array(dtype=wp.uint64),
    friction: wp.array(dtype=Any),
    restitution: wp.array(dtype=Any),
    kind_out: wp.array(dtype=wp.int32),
    pos_out: wp.array(dtype=Any),
    aux_out: wp.array(dtype=Any),
    rot_out: wp.array(dtype=Any),
    radius_out: wp.array(dtype=Any),
    mesh_out: wp.array(dtype=wp.uint64),
    coef_out: wp.array(dtype=Any),
):
    """One Colliders set's live arrays into the solver's combined ones from ``first`` on; ``coef_out`` is
    (μ, e, ε_v) per collider."""
    s = wp.tid()
    o = first + s
    kind_out[o] = kind[s]
    pos_out[o] = pos[s]
    aux_out[o] = aux[s]
    rot_out[o] = rot[s]
    radius_out[o] = radius[s]
    mesh_out[o] = mesh[s]
    coef_out[o] = type(pos[s])(friction[s], restitution[s], stick_velocity)


class RigidBodySolver(Solver):
    """Rigid bodies by the Newton–Euler equations, each body a cluster of the model's particles.

    Every step reads each body's state from its particles (centre t, rotation R as the polar part of
    Σ m (x − c)(p̄ − c̄)ᵀ, momentum, angular momentum L) and advances t, v by symplectic Euler and the
    orientation by I_b ω̇ = τ_b − ω × I_b ω (body frame; the gyroscopic term taken implicitly with one Newton
    step, Catto 2015, which keeps the energy bounded) and q ← normalize(q + ½Δt [ω, 0] q); the particles are
    then placed rigidly. Being stateless (all state in the particles), it follows the Solver contract and
    compares directly with :class:`pliant.constraints.ShapeMatching` at k_S = 1 under XPBD.

    Contact is the body's, not its particles': the model's (hard) ground and the
    :class:`pliant.collision.Colliders` among ``collisions`` are met after the free update by sequential
    impulses on the body's velocity and angular velocity over the particles that would end the step inside
    them (normal impulses with restitution on approach speeds above 2|g|Δt, so that resting contact does
    not hop, the project's smoothed Coulomb friction
    bounded by μ times each contact's normal impulse, a split impulse for leftover penetration), and the
    pose is then integrated from the corrected velocities, so the body stays rigid through contact, slides
    at μ g cos θ and rests inside the friction cone (:mod:`pliant.solvers.rigid._contact`). Bodies also meet
    each other, where particle spheres of different bodies overlap, with ``body_friction`` and
    ``body_restitution``: with more than one body all contacts are solved together by one Gauss–Seidel pass
    (:mod:`pliant.solvers.rigid._pairs`, one thread). A step where no body touches anything is the free
    update exactly, and a body that touches no other body moves as with the per-body solve, bit for bit.

    Args:
        model: the Model; bodies' particles must not be pinned; a ground must be hard (no ``stiffness``).
        bodies: particle index arrays, one per body (default: all particles form one body).
        collisions: ``Colliders`` (body-level contact, above) and other contact handlers, run after each
            step (``apply(model, state_in, state_out, dt)``): those move particles one by one, and the next
            step's polar decomposition makes each body rigid again.
        contact_iterations: Gauss–Seidel sweeps over a body's contacts per step, >= 1.
        pair_sweeps: sweeps over the contacts of bodies that touch another body, >= 1 (a stack's weight
            must pass through several bodies; impulses start from zero every step).
        body_friction: μ >= 0 between bodies (smoothed Coulomb, stick velocity 1e-4 m/s as the ground's).
        body_restitution: e in [0, 1] between bodies, on approach speeds above 2|g|Δt.
        pair_contacts: room for body-to-body contacts per step (default 4 per body particle); a step that
            finds more raises, naming this argument.

    Example::

        solver = pl.solvers.RigidBodySolver(model, collisions=[colliders])
        solver.step(state_0, state_1, control, 1e-3)
    """

    def __init__(
        self,
        model: Model,
        bodies: Sequence[Any] | None = None,
        *,
        collisions: Sequence[Any] = (),
        contact_iterations: int = 20,
        pair_sweeps: int = 100,
        body_friction: float = 0.5,
        body_restitution: float = 0.0,
        pair_contacts: int | None = None,
    ) -> None:
        super().__init__(model, collisions)
        if int(contact_iterations) < 1:
            raise ValueError(f"RigidBodySolver: contact_iterations must be >= 1, got {contact_iterations}")
        if int(pair_sweeps) < 1:
            raise ValueError(f"RigidBodySolver: pair_sweeps must be >= 1, got {pair_sweeps}")
        if not (np.isfinite(body_friction) and body_friction >= 0 and 0 <= body_restitution <= 1):
            raise ValueError(
                "RigidBodySolver: body_friction must be >= 0 and body_restitution in [0, 1], got "
                f"{body_friction}, {body_restitution}"
            )
        if model.ground is not None and model.ground.compliant:
            raise NotImplementedError(
                "RigidBodySolver: compliant ground contact (Ground.stiffness) is not supported for rigid "
                "bodies; add_ground() without stiffness"
            )
        n = model.particle_count
        bodies = [np.arange(n)] if bodies is None else [np.asarray(b, np.int64).reshape(-1) for b in bodies]
        inv_mass = model.particle_inv_mass.numpy()
        q = model.particle_q_np
        m = model.particle_mass_np
        offsets, inertia, centers = [0], [], []
        for k, b in enumerate(bodies):
            if b.size < 1 or b.min() < 0 or b.max() >= n:
                raise ValueError(f"RigidBodySolver: body {k} needs particle indices in [0, {n})")
            if np.any(inv_mass[b] == 0):
                raise NotImplementedError(f"RigidBodySolver: body {k} has pinned particles; unpin them")
            c = m[b] @ q[b] / m[b].sum()
            r = q[b] - c
            I = np.eye(3) * np.sum(m[b] * np.sum(r * r, axis=1)) - (r * m[b][:, None]).T @ r
            if np.linalg.cond(I) > 1e12:
                raise ValueError(
                    f"RigidBodySolver: body {k} has a singular inertia tensor (collinear particles); "
                    "give it particles spanning 3D"
                )
            offsets.append(offsets[-1] + b.size)
            inertia.append(I)
            centers.append(c)
        members = np.concatenate(bodies)
        d = model.device
        self.body_count = len(bodies)
        self.contact_iterations = int(contact_iterations)
        self.pair_sweeps = int(pair_sweeps)
        self.offsets: wp.array = wp.array(np.asarray(offsets, np.int32), dtype=wp.int32, device=d)
        self.members: wp.array = wp.array(members.astype(np.int32), dtype=wp.int32, device=d)
        self.rest: wp.array = wp.array(q[members], dtype=model.vec3, device=d)
        self.rest_center: wp.array = wp.array(np.asarray(centers), dtype=model.vec3, device=d)
        self.inertia_body: wp.array = wp.array(np.asarray(inertia), dtype=model.mat33, device=d)
        self._zero_f = wp.zeros(n, dtype=model.vec3, device=d)
        # Colliders are met at body level; the other handlers stay post-step (Solver.apply_collisions).
        self.colliders = [c for c in self.collisions if isinstance(c, Colliders)]
        self.collisions = [c for c in self.collisions if not isinstance(c, Colliders)]
        self._col_count = sum(len(c) for c in self.colliders)
        self._col = self._collider_buffers(max(self._col_count, 1))
        self._surfaces = (model.ground is not None) + self._col_count
        # With several bodies, pair contacts follow the ground's and colliders' in the same scratch.
        self.pair_contacts = 4 * members.size if pair_contacts is None else int(pair_contacts)
        if self.pair_contacts < 1:
            raise ValueError(f"RigidBodySolver: pair_contacts must be >= 1, got {pair_contacts}")
        self._coupled = self.body_count > 1
        size = max(members.size * self._surfaces + self._coupled * self.pair_contacts, 1)
        vec = [wp.zeros(size, dtype=model.vec3, device=d) for _ in range(5)]
        self._scratch = [*vec, wp.zeros(size, dtype=model.scalar, device=d)]
        self.body_friction, self.body_restitution = float(body_friction), float(body_restitution)
        if self._coupled:
            self._init_coupled(bodies, centers)

    def _init_coupled(self, bodies: list[np.ndarray], centers: list[np.ndarray]) -> None:
        """Per-body arrays of the coupled path (:mod:`._pairs`) and each body's bounding radius [m]: its
        farthest particle plus twice the largest radius, so that the broad phase also keeps the pairs that
        are watched (up to min(r_a, r_b) apart)."""
        m, d, B = self.model, self.model.device, self.body_count
        q, rad = m.particle_q_np, m.particle_radius.numpy()
        bound = [
            np.linalg.norm(q[b] - c, axis=1).max() + 2 * rad[b].max()
            for b, c in zip(bodies, centers, strict=True)
        ]
        self._bound: wp.array = wp.array(np.asarray(bound), dtype=m.scalar, device=d)
        quat = wp.quatd if m.scalar == wp.float64 else wp.quat
        types = [m.vec3, quat, m.mat33, m.vec3, m.vec3, m.scalar, m.mat33, m.vec3, m.vec3]
        self._body = [wp.zeros(B, dtype=t, device=d) for t in types]
        self._touch = wp.zeros(B, dtype=wp.int32, device=d)
        self._pair = [
            wp.zeros(self._scratch[0].shape[0], dtype=m.vec3, device=d),
            wp.zeros(self._scratch[0].shape[0], dtype=wp.vec2i, device=d),
        ]
        self._counts = wp.zeros(2, dtype=wp.int32, device=d)

    def _collider_buffers(self, count: int) -> list[wp.array]:
        """The combined collider arrays the step's kernel reads (kind, pos, aux, rot, radius, mesh, coef)."""
        m, d = self.model, self.model.device
        types = [wp.int32, m.vec3, m.vec3, m.mat33, m.scalar, wp.uint64, m.vec3]
        return [wp.zeros(count, dtype=t, device=d) for t in types]

    def _pack_colliders(self) -> None:
        """Copy every Colliders set's live arrays (μ, e and positions may be changed in place) into one."""
        first = 0
        for c in self.colliders:
            a = c.arrays(self.model)
            args = [first, self.model.s(c.stick_velocity), *c.geometry_inputs(self.model)]
            args += [a["friction"], a["restitution"], *self._col]
            wp.launch(_pack_colliders, len(c), args, device=self.model.device)
            first += len(c)

    def step(self, state_in: State, state_out: State, control: Control | None, dt: float) -> None:
        """Advance every body by ``dt`` [s]; particles outside bodies are copied unchanged."""
        m = self.model
        wp.copy(state_out.particle_q, state_in.particle_q)
        wp.copy(state_out.particle_qd, state_in.particle_qd)
        if self.colliders:
            self._pack_colliders()
        g = m.ground
        ground = [0, m.s(0.0), m.vec3()] if g is None else [1, m.s(g.height)]
        if g is not None:
            ground.append(m.vec3(g.friction, g.restitution, g.stick_velocity))
        f_ext = control.particle_f if control is not None else self._zero_f
        if self._coupled:
            self._step_coupled(state_in, state_out, f_ext, dt, ground)
            self.apply_collisions(state_in, state_out, dt)
            return
        wp.launch(
            _rigid_step,
            self.body_count,
            [
                self.offsets,
                self.members,
                self.rest,
                self.rest_center,
                self.inertia_body,
                m.particle_mass,
                m.gravity_vec,
                f_ext,
                m.s(dt),
                self._surfaces,
                self.contact_iterations,
                m.particle_radius,
                *ground,
                self._col_count,
                *self._col,
                state_in.particle_q,
                state_in.particle_qd,
                *self._scratch,
                state_out.particle_q,
                state_out.particle_qd,
            ],
            device=m.device,
        )
        self.apply_collisions(state_in, state_out, dt)

    def _step_coupled(
        self, state_in: State, state_out: State, f_ext: wp.array, dt: float, ground: list
    ) -> None:
        """Free steps, one Gauss–Seidel pass over all contacts, placement (:mod:`._pairs`)."""
        m, d, B = self.model, self.model.device, self.body_count
        c, q, R, v, w, im, ii, vp, wq = self._body
        common = [self.offsets, self.members, self.rest, self.rest_center]
        free = [*common, self.inertia_body, m.particle_mass, m.gravity_vec, f_ext, m.s(dt)]
        wp.launch(
            _free_bodies,
            B,
            [*free, state_in.particle_q, state_in.particle_qd, c, q, R, v, w, im, ii],
            device=d,
        )
        pair = m.vec3(self.body_friction, self.body_restitution, STICK_VELOCITY)
        args = [B, *common, self._bound, m.particle_radius, m.s(dt), m.gravity_vec, self.contact_iterations]
        args += [self.pair_sweeps]
        args += [self._surfaces, *ground, pair, self.pair_contacts, self._col_count, *self._col]
        args += [c, R, im, ii, v, w, *self._scratch, *self._pair, vp, wq, self._touch, self._counts]
        wp.launch(_coupled_contacts, 1, args, device=d)
        wanted = int(self._counts.numpy()[1])
        if wanted > self.pair_contacts:
            raise RuntimeError(
                f"RigidBodySolver: {wanted} body-to-body contacts in one step, room for "
                f"{self.pair_contacts}; pass a larger pair_contacts"
            )
        out = [state_out.particle_q, state_out.particle_qd]
        wp.launch(_place_bodies, B, [*common, m.s(dt), c, q, R, v, w, vp, wq, self._touch, *out], device=d)

    def describe(self) -> dict:
        """Solver name and body count."""
        return {
            "solver": "RigidBodySolver",
            "integrator": "newton_euler",
            "bodies": self.body_count,
            "contact_iterations": self.contact_iterations,
            "pair_sweeps": self.pair_sweeps,
        }
