"""Point-cloud clean-up for geometry from pictures: radius outlier removal and a RANSAC floor plane."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike


def remove_outliers(points: ArrayLike, radius: float, min_neighbors: int) -> np.ndarray:
    """Radius outlier removal: keep the points with at least ``min_neighbors`` other points within ``radius``.

    PhysTwin filters its fused depth clouds this way (its anchors keep points with ≥ 20 neighbours within
    1 cm): isolated depth readings (flying pixels at silhouettes, a mask's stray pixel) have few neighbours.

    Args:
        points: [M, 3] positions [m].
        radius: Neighbourhood radius [m], > 0.
        min_neighbors: Neighbours required, the point itself not counted.

    Returns:
        keep [M] bool.
    """
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if not radius > 0.0:
        raise ValueError(f"remove_outliers: radius: expected > 0 m, got {radius}")
    if p.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    counts = cKDTree(p).query_ball_point(p, radius, return_length=True)
    return np.asarray(counts) - 1 >= int(min_neighbors)


@dataclass
class Plane:
    """A plane ``normal · x = offset``.

    Attributes:
        normal: [3] unit normal, on the side of ``up``.
        offset: ``normal · x`` on the plane [m].
        height: Where the plane crosses the line through the origin along ``up`` [m] (a floor's height).
        inlier_fraction: Fraction of the points within ``tol`` of the plane.
        inliers: [M] bool, those points.
    """

    normal: np.ndarray
    offset: float
    height: float
    inlier_fraction: float
    inliers: np.ndarray


def fit_plane(
    points: ArrayLike,
    *,
    up: ArrayLike = (0.0, 1.0, 0.0),
    max_tilt_deg: float = 10.0,
    tol: float = 0.005,
    iters: int = 256,
    seed: int = 0,
    min_fraction: float = 0.2,
) -> Plane | None:
    """RANSAC for a dominant, nearly horizontal plane (a floor or table top).

    ``iters`` triples of points are drawn at once; a triple whose plane tilts more than ``max_tilt_deg``
    from ``up`` is skipped, the others are scored by their inliers (distance ≤ ``tol``), and the best one is
    refined by least squares on its inliers (the normal is the smallest principal axis).

    Args:
        points: [M, 3] positions [m].
        up: World up direction (pliant's scenes are y-up).
        max_tilt_deg: Largest angle between the plane's normal and ``up`` [degrees].
        tol: Inlier distance [m].
        iters: Random triples tried.
        seed: Seed of the draws (the result is deterministic).
        min_fraction: Smallest inlier fraction [0-1] that counts as a dominant plane.

    Returns:
        The :class:`Plane`, or None when no horizontal plane holds ``min_fraction`` of the points.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    u = np.asarray(up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    M = p.shape[0]
    if M < 3:
        return None
    cos_max = np.cos(np.radians(max_tilt_deg))
    rng = np.random.default_rng(seed)
    tri = p[rng.integers(0, M, size=(iters, 3))]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ln = np.linalg.norm(n, axis=1)
    ok = ln > 1e-12
    n = n[ok] / ln[ok, None]
    n *= np.sign(n @ u)[:, None] + (n @ u == 0.0)[:, None]
    flat = n @ u >= cos_max
    n, off = n[flat], np.einsum("ij,ij->i", n[flat], tri[ok][flat, 0])
    if n.shape[0] == 0:
        return None
    # Score the candidates in blocks: [candidates, M] distances stay under ~16 M entries.
    best, best_count = 0, -1
    step = max(1, (1 << 24) // M)
    for s in range(0, n.shape[0], step):
        cnt = (np.abs(p @ n[s : s + step].T - off[s : s + step]) <= tol).sum(axis=0)
        i = int(np.argmax(cnt))
        if cnt[i] > best_count:
            best, best_count = s + i, int(cnt[i])
    inl = np.abs(p @ n[best] - off[best]) <= tol
    if inl.sum() >= 3:  # least-squares refinement on the inliers, kept only if still horizontal
        q = p[inl]
        c = q.mean(axis=0)
        nr = np.linalg.svd(q - c, full_matrices=False)[2][2]
        nr = nr if nr @ u >= 0.0 else -nr
        if nr @ u >= cos_max:
            n_best, off_best = nr, float(nr @ c)
            inl = np.abs(p @ n_best - off_best) <= tol
        else:
            n_best, off_best = n[best], float(off[best])
    else:
        n_best, off_best = n[best], float(off[best])
    frac = float(inl.mean())
    if frac < min_fraction:
        return None
    return Plane(
        normal=n_best,
        offset=off_best,
        height=off_best / float(n_best @ u),
        inlier_fraction=frac,
        inliers=inl,
    )


__all__ = ["Plane", "fit_plane", "remove_outliers"]
