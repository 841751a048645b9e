"""Losses of fitting, as Warp kernels (differentiable on the tape; generic over float32/float64).

Following PhysTwin (``Jianghanxiao/PhysTwin``, ``compute_track_loss``, ``compute_chamfer_loss``,
``compute_acc_loss``), written anew for pliant:

- tracking: smooth-L1 (Huber with threshold β [m]) per coordinate between each visible track and the
  particle it is bound to, averaged over visible tracks × 3 coordinates;
- Chamfer, one-sided (observed → simulated): for each observed cloud point, the squared distance [m²] to the
  nearest simulated particle, averaged over the cloud's points; the nearest index is found by one kernel and
  held fixed, and a second kernel computes the distance (so the tape differentiates only the distance);
- acceleration regulariser: smooth-L1 of the change of per-frame acceleration of every particle
  ``(x₃ − 2x₂ + x₁) − (x₂ − 2x₁ + x₀)`` [m per frame²], averaged over particles × 3 (PhysTwin: weight 0.01).

Each ``*_loss`` function adds ``weight × (its mean)`` into a one-element array ``out`` so that several terms
and frames can share one loss on a ``wp.Tape``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp


@wp.func
def smooth_l1(d: Any, beta: Any):
    """Huber / smooth-L1 of one residual d [m]: ½d²/β for |d| < β, |d| − ½β beyond."""
    a = wp.abs(d)
    r = a - type(d)(0.5) * beta
    if a < beta:
        r = type(d)(0.5) * d * d / beta
    return r


@wp.func
def smooth_l1_vec(d: Any, beta: Any):
    return smooth_l1(d[0], beta) + smooth_l1(d[1], beta) + smooth_l1(d[2], beta)


@wp.kernel
def _track_kernel(
    x: wp.array(dtype=Any),
    n: int,
    particle: wp.array(dtype=wp.int32),
    obs: wp.array(dtype=Any),
    visible: wp.array(dtype=wp.int32),
    k_count: int,
    beta: Any,
    weight: Any,
    out: wp.array(dtype=Any),
):
    t, k = wp.tid()
    o = t * k_count + k
    if visible[o] != 0:
        d = x[t * n + particle[k]] - obs[o]
        wp.atomic_add(out, 0, weight * smooth_l1_vec(d, beta))


@wp.kernel
def _nearest_kernel(
    cloud: wp.array(dtype=Any),
    count: wp.array(dtype=wp.int32),
    p_count: int,
    x: wp.array(dtype=Any),
    n: int,
    nearest_out: wp.array(dtype=wp.int32),
):
    # Brute force over the particles (one thread per observed point): the index is not differentiated.
    t, p = wp.tid()
    if p >= count[t]:
        return
    q = cloud[t * p_count + p]
    best = wp.int32(0)  # a dynamic variable (a literal 0 would be a constant inside the loop)
    best_d = wp.length_sq(x[t * n] - q)
    for j in range(1, n):
        dj = wp.length_sq(x[t * n + j] - q)
        if dj < best_d:
            best_d = dj
            best = j
    nearest_out[t * p_count + p] = t * n + best


@wp.kernel
def _chamfer_kernel(
    cloud: wp.array(dtype=Any),
    count: wp.array(dtype=wp.int32),
    p_count: int,
    x: wp.array(dtype=Any),
    nearest: wp.array(dtype=wp.int32),
    weight: Any,
    out: wp.array(dtype=Any),
):
    t, p = wp.tid()
    if p < count[t]:
        o = t * p_count + p
        d = cloud[o] - x[nearest[o]]
        wp.atomic_add(out, 0, weight * wp.dot(d, d))


@wp.kernel
def _acceleration_kernel(
    x0: wp.array(dtype=Any),
    x1: wp.array(dtype=Any),
    x2: wp.array(dtype=Any),
    x3: wp.array(dtype=Any),
    beta: Any,
    weight: Any,
    out: wp.array(dtype=Any),
):
    i = wp.tid()
    two = type(beta)(2.0)
    jerk = (x3[i] - two * x2[i] + x1[i]) - (x2[i] - two * x1[i] + x0[i])
    wp.atomic_add(out, 0, weight * smooth_l1_vec(jerk, beta))


def _scalar(out: wp.array) -> type:
    return wp.float64 if out.dtype == wp.float64 else wp.float32


def track_loss(
    x: wp.array,
    particle: wp.array,
    points: wp.array,
    visible: wp.array,
    out: wp.array,
    *,
    frames: int = 1,
    beta: float = 0.01,
    weight: float = 1.0,
    normaliser: float | None = None,
) -> None:
    """Add ``weight × Σ smooth_l1(x[particle[k]] − points[k]) / normaliser`` over visible tracks into ``out``.

    Args:
        x: [frames·N] simulated positions [m] (vec3 of the model's dtype), frame-major.
        particle: [K] int32 particle of each track.
        points: [frames·K] observed positions [m] (same vec3 type), frame-major; ignored where not visible.
        visible: [frames·K] int32, 1 where a track was seen.
        out: [1] scalar array the loss is added to (atomically).
        frames: frames in ``x`` / ``points``.
        beta: smooth-L1 threshold [m].
        weight: factor of this term.
        normaliser: divisor (default: 3 × the number of visible entries, a mean over coordinates).
    """
    k = particle.shape[0]
    n = x.shape[0] // frames
    if normaliser is None:
        normaliser = 3.0 * max(int(visible.numpy().sum()), 1)
    s = _scalar(out)
    wp.launch(
        _track_kernel,
        (frames, k),
        [x, n, particle, points, visible, k, s(beta), s(weight / normaliser), out],
        device=x.device,
    )


def chamfer_loss(
    x: wp.array,
    cloud: wp.array,
    count: wp.array,
    out: wp.array,
    *,
    frames: int = 1,
    weight: float = 1.0,
    normaliser: float | None = None,
) -> None:
    """Add the one-sided Chamfer term ``weight × Σ_p min_i |cloud_p − x_i|² / normaliser`` into ``out``.

    Args:
        x: [frames·N] simulated positions [m], frame-major.
        cloud: [frames·P] padded observed points [m], frame-major.
        count: [frames] int32 valid points per frame (the first ``count[t]`` of each frame).
        out: [1] scalar array the loss is added to.
        frames: frames in ``x`` / ``cloud``.
        weight: factor of this term.
        normaliser: divisor (default: the number of valid cloud points, a mean).
    """
    p = cloud.shape[0] // frames
    n = x.shape[0] // frames
    if normaliser is None:
        normaliser = max(int(count.numpy().sum()), 1)
    nearest = wp.zeros(cloud.shape[0], dtype=wp.int32, device=x.device)
    wp.launch(_nearest_kernel, (frames, p), [cloud, count, p, x, n, nearest], device=x.device)
    s = _scalar(out)
    wp.launch(
        _chamfer_kernel,
        (frames, p),
        [cloud, count, p, x, nearest, s(weight / normaliser), out],
        device=x.device,
    )


def acceleration_loss(
    x0: wp.array,
    x1: wp.array,
    x2: wp.array,
    x3: wp.array,
    out: wp.array,
    *,
    beta: float = 0.01,
    weight: float = 0.01,
    normaliser: float | None = None,
) -> None:
    """Add ``weight × Σ_i smooth_l1((x3 − 2x2 + x1) − (x2 − 2x1 + x0)) / normaliser`` into ``out``.

    Args:
        x0: [N] positions [m] of the first of four consecutive frames.
        x1: [N] positions [m] of the second.
        x2: [N] positions [m] of the third.
        x3: [N] positions [m] of the fourth.
        out: [1] scalar array the loss is added to.
        beta: smooth-L1 threshold [m].
        weight: factor of this term.
        normaliser: divisor (default: 3N, a mean over coordinates).
    """
    n = x3.shape[0]
    if normaliser is None:
        normaliser = 3.0 * n
    s = _scalar(out)
    wp.launch(
        _acceleration_kernel, n, [x0, x1, x2, x3, s(beta), s(weight / normaliser), out], device=x3.device
    )


def track_errors(x: np.ndarray, particle: np.ndarray, points: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Per-frame mean Euclidean distance [m] between visible tracks and their particles (PhysTwin's track
    error; a metric, not differentiated). Frames with no visible track give NaN.

    Args:
        x: [T, N, 3] simulated positions [m].
        particle: [K] particle of each track.
        points: [T, K, 3] observed positions [m].
        visible: [T, K] bool.
    """
    d = np.linalg.norm(x[:, particle] - np.nan_to_num(points), axis=2)
    n = visible.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, (d * visible).sum(axis=1) / np.maximum(n, 1), np.nan)


__all__ = ["acceleration_loss", "chamfer_loss", "smooth_l1", "track_errors", "track_loss"]
