"""Kernels of the PBD/XPBD loop: prediction, Jacobi averaging, velocity update."""

from __future__ import annotations

from typing import Any

import warp as wp

from .._post import drag_force


@wp.kernel
def predict(
    # Model:
    inv_mass: wp.array(dtype=Any),
    gravity: wp.array(dtype=Any),
    # Control:
    f_ext: wp.array(dtype=Any),
    drag_index: int,
    drag_target: Any,
    drag_stiffness: Any,
    drag_max_force: Any,
    # Parameters:
    dt: Any,
    # State in:
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    # Out:
    p_out: wp.array(dtype=Any),
    v_pred_out: wp.array(dtype=Any),
):
    """Algorithm 1, lines 5–6: v ← v + Δt(g + w f_ext), p ← x + Δt v (pinned particles stay)."""
    i = wp.tid()
    w = inv_mass[i]
    x = x_in[i]
    if w == type(w)(0.0):
        p_out[i] = x
        v_pred_out[i] = x * type(w)(0.0)
        return
    f = f_ext[i]
    if i == drag_index:
        # The drag handle: the same zero-length spring as the force solvers add (_post.drag_force).
        f = f + drag_force(drag_target, drag_stiffness, drag_max_force, x)
    v = v_in[i] + dt * (gravity[0] + w * f)
    p_out[i] = x + dt * v
    v_pred_out[i] = v


@wp.kernel
def apply_kinematic(
    indices: wp.array(dtype=wp.int32),
    targets: wp.array(dtype=Any),
    p_out: wp.array(dtype=Any),
):
    """Kinematic particles (inverse mass 0) sit on their targets during the projection."""
    k = wp.tid()
    p_out[indices[k]] = targets[k]


@wp.func
def jacobi_scale(relaxation: Any, average: int, n: int):
    """ω / n_i (the average of the n_i corrections at particle i) or, with ``average`` 0, ω (their sum)."""
    scale = relaxation
    if average != 0:
        scale = relaxation / type(relaxation)(n)
    return scale


@wp.func
def apply_average(
    relaxation: Any,
    average: int,
    i: int,
    p_io: wp.array(dtype=Any),
    delta_io: wp.array(dtype=Any),
    count_io: wp.array(dtype=wp.int32),
):
    """p_i += ω Σ_c Δp_i^c / n_i (or ω Σ_c Δp_i^c without ``average``), then the accumulators of particle
    i reset (nothing where n_i = 0)."""
    n = count_io[i]
    if n > 0:
        p_io[i] = p_io[i] + jacobi_scale(relaxation, average, n) * delta_io[i]
        delta_io[i] = delta_io[i] * type(relaxation)(0.0)
        count_io[i] = 0


@wp.kernel
def apply_deltas(
    relaxation: Any,
    average: int,
    p_io: wp.array(dtype=Any),
    delta_io: wp.array(dtype=Any),
    count_io: wp.array(dtype=wp.int32),
):
    """Jacobi: p_i += ω Σ_c Δp_i^c / n_i (the average over the n_i constraints that moved i; with ``average``
    0 the sum ω Σ_c Δp_i^c), then reset."""
    apply_average(relaxation, average, wp.tid(), p_io, delta_io, count_io)


@wp.kernel
def update_velocity(
    inv_dt: Any,
    damping_factor: Any,
    x_in: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    """Algorithm 1, lines 12–13: v ← (p − x)/Δt, scaled by exp(−cΔt) (x ← p is the state swap)."""
    i = wp.tid()
    v_out[i] = ((p_in[i] - x_in[i]) * inv_dt) * damping_factor


@wp.kernel
def apply_deltas_update_velocity(
    relaxation: Any,
    average: int,
    inv_dt: Any,
    damping_factor: Any,
    x_in: wp.array(dtype=Any),
    delta_io: wp.array(dtype=Any),
    count_io: wp.array(dtype=wp.int32),
    p_io: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    """:func:`apply_deltas` then :func:`update_velocity` in one launch (the step's last Jacobi correction),
    the same expressions in the same order: the positions and velocities are theirs bit for bit."""
    i = wp.tid()
    apply_average(relaxation, average, i, p_io, delta_io, count_io)
    v_out[i] = ((p_io[i] - x_in[i]) * inv_dt) * damping_factor


@wp.kernel
def apply_deltas_to(
    relaxation: Any,
    average: int,
    p_in: wp.array(dtype=Any),
    delta_in: wp.array(dtype=Any),
    count_in: wp.array(dtype=wp.int32),
    p_out: wp.array(dtype=Any),
):
    """Jacobi into a fresh array (differentiable step): p_out = p_in + ω Σ_c Δp_i^c / n_i (or without / n_i
    when ``average`` is 0)."""
    i = wp.tid()
    n = count_in[i]
    x = p_in[i]
    if n > 0:
        x = x + jacobi_scale(relaxation, average, n) * delta_in[i]
    p_out[i] = x


@wp.kernel
def write_state(
    p_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    q_out: wp.array(dtype=Any),
    qd_out: wp.array(dtype=Any),
):
    """The end of a differentiable step: the last projected positions and velocities into the state."""
    i = wp.tid()
    q_out[i] = p_in[i]
    qd_out[i] = v_in[i]
