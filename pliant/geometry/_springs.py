"""Spring topology from unstructured point sets."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._arrays import as_points


def springs_from_points(
    points: ArrayLike,
    radius: float,
    max_neighbors: int,
    *,
    mutual: bool = False,
    min_length: float = 0.0,
) -> NDArray[np.int32]:
    """Connect each point to its nearest neighbours within a radius (PhysTwin style).

    Each point picks up to ``max_neighbors`` nearest other points closer than
    ``radius``; the picked pairs are made undirected and deduplicated. Because a
    point can also be picked by others, its final degree may exceed
    ``max_neighbors`` (at most ``N * max_neighbors`` springs in total); with
    ``mutual=True`` a pair is kept only if both points picked each other, which caps
    every degree at ``max_neighbors``.

    Args:
        points: Positions [N, 3] (m).
        radius: Search radius (m); pairs at distance <= radius qualify.
        max_neighbors: Neighbours each point may pick (>= 1).
        mutual: Keep only pairs picked from both ends.
        min_length: Pairs at distance <= min_length are skipped (m); the default
            0 drops coincident points, whose zero rest length has no direction.

    Returns:
        Springs [S, 2] int32 with ``i < j``, unique, rows sorted lexicographically.
    """
    from scipy.spatial import cKDTree

    p = as_points(points)
    if not np.all(np.isfinite(p)):
        raise ValueError("springs_from_points: points contain NaN/inf")
    if int(max_neighbors) != max_neighbors or max_neighbors < 1:
        raise ValueError(f"springs_from_points: max_neighbors must be an integer >= 1, got {max_neighbors!r}")
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"springs_from_points: radius must be positive (m), got {radius!r}")
    n, k = len(p), int(max_neighbors)
    if n < 2:
        return np.zeros((0, 2), dtype=np.int32)

    # Ask for k + 1 so the query point itself (distance 0) does not eat a slot.
    dist, idx = cKDTree(p).query(p, k=min(k + 1, n), distance_upper_bound=float(radius))
    dist, idx = dist.reshape(n, -1), idx.reshape(n, -1)
    src = np.broadcast_to(np.arange(n)[:, None], idx.shape)
    # Missing neighbours come back as index n with infinite distance.
    valid = (idx != src) & (idx < n) & (dist > min_length)
    # Keep the first k valid hits per row; rows are sorted by distance already.
    valid &= np.cumsum(valid, axis=1) <= k
    i, j = src[valid], idx[valid]
    pairs = np.stack([np.minimum(i, j), np.maximum(i, j)], axis=1).astype(np.int64)
    uniq, counts = np.unique(pairs, axis=0, return_counts=True)
    if mutual:
        uniq = uniq[counts == 2]
    return uniq.astype(np.int32)
