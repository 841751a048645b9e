"""The implicit minimisers' per-particle kernels and the arithmetic they share with the static solve.

Newton and L-BFGS (:mod:`._newton`, :mod:`._quasi_newton`) fix whole particles (inverse mass 0); the
static solve (:mod:`._static`) fixes components (a 0/1 ``free`` mask per particle). Their kernels differ
in how they read that mask, so each keeps its own; what they compute alike (the largest component of a
vector, the Newton step's statistics) is written once, in the ``@wp.func`` helpers below. The static
solve's kernels stay in its own module (a Warp module is built as a whole, and they update arrays in
place, which Warp's read-then-write check flags when a taped test builds the module they are in).
"""

from __future__ import annotations

from typing import Any

import warp as wp


# ------------------------------------------------------------------------------------- shared arithmetic
@wp.func
def max_abs(v: Any):
    """max_k |v_k| of a 3-vector."""
    return wp.max(wp.max(wp.abs(v[0]), wp.abs(v[1])), wp.abs(v[2]))


@wp.func
def add_step_stats(g: Any, d: Any, stats_out: wp.array(dtype=Any)):
    """stats[0] = max over the step's components of |Δx|, stats[1] += ∇·Δx (the directional derivative)."""
    wp.atomic_max(stats_out, 0, max_abs(d))
    wp.atomic_add(stats_out, 1, wp.dot(g, d))


@wp.func
def trial_point(w: Any, m: Any, alpha: Any, x: Any, dx: Any, x_tilde: Any):
    """A line-search trial x + αΔx (x itself for a fixed particle, 1/m = w = 0) and its ½ m‖· − x̃‖² term of
    Φ: the host minimisers' and the device Newton's trial, one expression."""
    y = x
    if w != type(m)(0.0):
        y = x + alpha * dx
    d = y - x_tilde
    return y, type(m)(0.5) * m * wp.dot(d, d)


# -------------------------------------------------------------------- Newton and L-BFGS (fixed particles)
@wp.kernel(enable_backward=False)
def _incremental_gradient(
    mass: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    x_tilde_in: wp.array(dtype=Any),
    egrad_in: wp.array(dtype=Any),
    h2: Any,
    inv_h: Any,
    grad_out: wp.array(dtype=Any),
    stats_out: wp.array(dtype=Any),
):
    # ∇Φ = M (x − x̃) + h² ∇E, zero on fixed rows; over the free particles stats[0] = max |g_i|/(m_i h),
    # stats[1] = max |x|, stats[2] = ½‖x − x̃‖²_M (fixed ones stay at x̃).
    i = wp.tid()
    x = x_in[i]
    d = x - x_tilde_in[i]
    m = mass[i]
    g = m * d + h2 * egrad_in[i]
    zero = type(inv_h)(0.0)
    if inv_mass[i] == zero:
        grad_out[i] = g * zero
        return
    grad_out[i] = g
    wp.atomic_max(stats_out, 1, max_abs(x))
    wp.atomic_max(stats_out, 0, max_abs(g) * inv_mass[i] * inv_h)
    wp.atomic_add(stats_out, 2, type(inv_h)(0.5) * m * wp.dot(d, d))


@wp.kernel(enable_backward=False)
def _step_stats(
    inv_mass: wp.array(dtype=Any),
    grad_in: wp.array(dtype=Any),
    dx_in: wp.array(dtype=Any),
    stats_out: wp.array(dtype=Any),
):
    # add_step_stats over the free particles.
    i = wp.tid()
    if inv_mass[i] == type(inv_mass[i])(0.0):
        return
    add_step_stats(grad_in[i], dx_in[i], stats_out)


@wp.kernel(enable_backward=False)
def _trial_point(
    inv_mass: wp.array(dtype=Any),
    mass: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    dx_in: wp.array(dtype=Any),
    x_tilde_in: wp.array(dtype=Any),
    alpha: Any,
    x_out: wp.array(dtype=Any),
    stats_out: wp.array(dtype=Any),
):
    # x_out = x + α Δx (free particles only) and stats[0] += ½‖x_out − x̃‖²_M.
    i = wp.tid()
    x, e = trial_point(inv_mass[i], mass[i], alpha, x_in[i], dx_in[i], x_tilde_in[i])
    x_out[i] = x
    wp.atomic_add(stats_out, 0, e)


@wp.kernel(enable_backward=False)
def _negate(src: wp.array(dtype=Any), out: wp.array(dtype=Any)):
    # The linear solves' right-hand side −∇.
    i = wp.tid()
    out[i] = -src[i]


@wp.kernel(enable_backward=False)
def _toward(
    inv_mass: wp.array(dtype=Any),
    x_ref: wp.array(dtype=Any),
    x_tilde: wp.array(dtype=Any),
    alpha: Any,
    mode: int,
    dx_out: wp.array(dtype=Any),
    x_out: wp.array(dtype=Any),
):
    # mode 0: Δ = x̃ − x_ref; mode 1: x_out = x_ref + αΔ for free particles, x̃ for fixed ones (the start of
    # a minimisation whose energies bound the step from x_ref, see _newton._feasible_start).
    i = wp.tid()
    if mode == 0:
        dx_out[i] = x_tilde[i] - x_ref[i]
    elif inv_mass[i] != alpha * type(alpha)(0.0):
        x_out[i] = x_ref[i] + alpha * dx_out[i]
