"""RigidBodySolver: Newton–Euler rigid bodies over particle clusters, to compare with shape matching."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import warp as wp

from ...constraints import polar_rotation
from ...model import Control, Model, State
from .._base import Solver


@wp.func
def skew(a: Any):
    """[a]× with [a]× b = a × b."""
    z = type(a[0])(0.0)
    return type(wp.outer(a, a))(z, -a[2], a[1], a[2], z, -a[0], -a[1], a[0], z)


@wp.func
def gyroscopic_step(I: Any, w: Any, dt: Any):
    """One Newton step on I(ω' − ω) + Δt ω' × Iω' = 0 (implicit gyroscopic term, Catto 2015), body frame."""
    f = dt * wp.cross(w, I * w)
    J = I + dt * (skew(w) * I - skew(I * w))
    return w - wp.inverse(J) * f


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
    # State in:
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    # Out:
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    b = wp.tid()
    a0 = offsets[b]
    a1 = offsets[b + 1]
    zero = dt * type(dt)(0.0)
    # Body state from the particles: centre, rotation (polar part of A, exact for a rigid arrangement),
    # linear momentum, angular momentum, and the forces.
    M = zero
    c = gravity * zero
    p = gravity * zero
    F = gravity * zero
    for k in range(a0, a1):
        i = members[k]
        M = M + mass[i]
        c = c + mass[i] * x_in[i]
        p = p + mass[i] * v_in[i]
        F = F + mass[i] * gravity + f_ext[i]
    c = c / M
    cb = rest_center[b]
    A = wp.outer(c, c) * zero
    L = c * zero
    tau = c * zero
    for k in range(a0, a1):
        i = members[k]
        r = x_in[i] - c
        A = A + mass[i] * wp.outer(r, rest[k] - cb)
        L = L + mass[i] * wp.cross(r, v_in[i])
        tau = tau + wp.cross(r, f_ext[i])
    R = polar_rotation(A)
    Ib = inertia_body[b]
    # Newton: symplectic Euler for the centre.
    v = p / M + dt * F / M
    c_new = c + dt * v
    # Euler: ω from L = R I_b Rᵀ ω, torque impulse, implicit gyroscopic term in the body frame.
    wb = wp.inverse(Ib) * (wp.transpose(R) * L)
    wb = wb + dt * (wp.inverse(Ib) * (wp.transpose(R) * tau))
    wb = gyroscopic_step(Ib, wb, dt)
    w = R * wb
    # Orientation: q ← normalize(q + ½Δt [ω, 0] q).
    q = wp.quat_from_matrix(R)
    half = type(dt)(0.5) * dt
    dq = type(q)(w[0], w[1], w[2], zero) * q
    q = wp.normalize(
        type(q)(q[0] + half * dq[0], q[1] + half * dq[1], q[2] + half * dq[2], q[3] + half * dq[3])
    )
    R_new = wp.quat_to_matrix(q)
    for k in range(a0, a1):
        i = members[k]
        r = R_new * (rest[k] - cb)
        x_out[i] = c_new + r
        v_out[i] = v + wp.cross(w, r)


class RigidBodySolver(Solver):
    """Rigid bodies by the Newton–Euler equations, each body a cluster of the model's particles.

    Every step reads each body's state from its particles (centre t, rotation R as the polar part of
    Σ m (x − c)(p̄ − c̄)ᵀ, momentum, angular momentum L) and advances t, v by symplectic Euler and the
    orientation by I_b ω̇ = τ_b − ω × I_b ω (body frame; the gyroscopic term taken implicitly with one Newton
    step, Catto 2015, which keeps the energy bounded) and q ← normalize(q + ½Δt [ω, 0] q); the particles are
    then placed rigidly. Being stateless (all state in the particles), it follows the Solver contract and
    compares directly with :class:`pliant.constraints.ShapeMatching` at k_S = 1 under XPBD.

    Args:
        model: the Model; bodies' particles must not be pinned.
        bodies: particle index arrays, one per body (default: all particles form one body).
        collisions: contact handlers run after each step (``apply(model, state_in, state_out, dt)``); they
            move particles one by one, and the next step's polar decomposition makes each body rigid again.

    Example::

        solver = pl.solvers.RigidBodySolver(model)
        solver.step(state_0, state_1, control, 1e-3)
    """

    def __init__(
        self, model: Model, bodies: Sequence[Any] | None = None, *, collisions: Sequence[Any] = ()
    ) -> None:
        super().__init__(model, collisions)
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
        d, f = model.device, model.scalar
        self.body_count = len(bodies)
        self.offsets: wp.array = wp.array(np.asarray(offsets, np.int32), dtype=wp.int32, device=d)
        self.members: wp.array = wp.array(members.astype(np.int32), dtype=wp.int32, device=d)
        self.rest: wp.array = wp.array(q[members], dtype=model.vec3, device=d)
        self.rest_center: wp.array = wp.array(np.asarray(centers), dtype=model.vec3, device=d)
        self.inertia_body: wp.array = wp.array(np.asarray(inertia), dtype=model.mat33, device=d)
        self._zero_f = wp.zeros(n, dtype=model.vec3, device=d)
        del f

    def step(self, state_in: State, state_out: State, control: Control | None, dt: float) -> None:
        """Advance every body by ``dt`` [s]; particles outside bodies are copied unchanged."""
        m = self.model
        wp.copy(state_out.particle_q, state_in.particle_q)
        wp.copy(state_out.particle_qd, state_in.particle_qd)
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
                control.particle_f if control is not None else self._zero_f,
                m.s(dt),
                state_in.particle_q,
                state_in.particle_qd,
                state_out.particle_q,
                state_out.particle_qd,
            ],
            device=m.device,
        )
        self.apply_collisions(state_in, state_out, dt)

    def describe(self) -> dict:
        """Solver name and body count."""
        return {"solver": "RigidBodySolver", "integrator": "newton_euler", "bodies": self.body_count}
