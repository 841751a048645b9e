"""XPBD's convergence test on the device: one-thread kernels that read the residual the constraint sets
accumulated and set the flags ``wp.capture_while`` / ``wp.capture_if`` branch on, so that a step with a
tolerance needs no host read and can be captured as a graph (``XPBD._sweep_to_tolerance``).

A module of its own: only a solver with a tolerance launches these, and the built-in scenes (which have
none) neither compile nor prebuild it.

``counts`` slots (int32): the sweeps of the current step, the checks made in it, and, over the solver's
life, the steps and the sweeps (read by ``XPBD.last_iterations`` and ``XPBD.sweep_counts``).
"""

from __future__ import annotations

from typing import Any

import warp as wp

SWEEPS = 0
CHECKS = 1
STEPS = 2
TOTAL = 3
COUNT_SLOTS = 4


@wp.kernel
def tolerance_begin(
    first: int,
    residual_io: wp.array(dtype=Any),
    go_out: wp.array(dtype=wp.int32),
    tail_out: wp.array(dtype=wp.int32),
    counts_io: wp.array(dtype=wp.int32),
):
    """A step starts: ``first`` sweeps run before the first check; clear the residual and the flags."""
    zero = residual_io[0] * type(residual_io[0])(0.0)
    residual_io[0] = zero
    residual_io[1] = zero
    go_out[0] = 0
    tail_out[0] = 0
    counts_io[0] = first  # SWEEPS
    counts_io[1] = 0  # CHECKS
    counts_io[2] = counts_io[2] + 1  # STEPS
    counts_io[3] = counts_io[3] + first  # TOTAL


@wp.kernel
def tolerance_check(
    tolerance: wp.float64,
    chunk: int,
    checks: int,
    tail: int,
    residual_io: wp.array(dtype=Any),
    go_out: wp.array(dtype=wp.int32),
    tail_out: wp.array(dtype=wp.int32),
    counts_io: wp.array(dtype=wp.int32),
):
    """Converged when the RMS residual sqrt(s/n) ≤ ``tolerance`` (or n = 0); otherwise another ``chunk``
    sweeps (``go``, up to ``checks`` checks), then the last ``tail`` sweeps unchecked (``tail``).

    s/n is divided in the model's scalar type and the root taken in float64 against the float64 tolerance:
    the same arithmetic as the host test it replaces, so the same step stops at the same sweep.
    """
    s = residual_io[0]
    n = residual_io[1]
    zero = s * type(s)(0.0)
    residual_io[0] = zero  # the next check accumulates from zero
    residual_io[1] = zero
    converged = True
    if n > zero:
        converged = wp.sqrt(wp.float64(s / n)) <= tolerance
    k = counts_io[1] + 1
    counts_io[1] = k
    go = 0
    more = 0
    last = 0
    if not converged:
        if k < checks:
            go = 1
            more = chunk
        else:
            last = 1
            more = tail
    go_out[0] = go
    tail_out[0] = last
    counts_io[0] = counts_io[0] + more
    counts_io[3] = counts_io[3] + more
