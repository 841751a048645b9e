"""Point clouds from pictures: radius outlier removal, a RANSAC floor plane, and per-frame surface clouds
from masks and depth (the observation file's ``cloud`` layout)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ._pictures import _cameras, backproject, carve, hull_bounds, object_mask


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


def _filtered_sample(
    pts: np.ndarray, radius: float, min_neighbors: int, max_points: int, rng: np.random.Generator
) -> np.ndarray:
    """At most ``max_points`` of the points that pass :func:`~pliant.geometry.remove_outliers`, a uniform
    random subset of them: candidates are tested in a random order (their neighbours counted in the whole
    cloud) until enough pass, so a cloud of 30 000 points costs a few thousand neighbour counts, not all."""
    from scipy.spatial import cKDTree

    tree = cKDTree(pts)
    order = rng.permutation(pts.shape[0])
    kept, total = [], 0
    for s in range(0, order.size, 2 * max_points):
        cand = order[s : s + 2 * max_points]
        count = np.asarray(tree.query_ball_point(pts[cand], radius, return_length=True)) - 1
        kept.append(cand[count >= min_neighbors])
        total += kept[-1].size
        if total >= max_points:
            break
    return pts[np.sort(np.concatenate(kept)[:max_points])]


def frame_clouds(
    K: ArrayLike,
    world_to_camera: ArrayLike,
    masks: ArrayLike,
    *,
    depth: ArrayLike | None = None,
    lo: ArrayLike | None = None,
    hi: ArrayLike | None = None,
    spacing: float | None = None,
    max_points: int = 2000,
    outlier_radius: float | None = None,
    min_neighbors: int = 8,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Per observed frame, a point cloud of the object's surface from the pictures, in the layout of an
    observation file's ``cloud`` [T, P, 3] and ``cloud_count`` [T] (``pliant fit``'s Chamfer loss).

    With ``depth``, every camera's masked depth is back-projected (:func:`backproject`), merged and
    filtered (:func:`~pliant.geometry.remove_outliers`). Without, the surface voxels of the frame's carved
    hull (:func:`carve`, :meth:`Voxels.surface`, counting voxels that all views but one saw) are the cloud:
    the visual hull contains the object, so these points lie on or outside its surface. A frame with more
    than ``max_points`` points keeps a seeded random subset (deterministic).

    Args:
        K: [C, 3, 3] intrinsics [px].
        world_to_camera: [C, 4, 4] rigid world → camera transforms [m].
        masks: [C, T, H, W] object masks (bool, uint8 or floats in [0, 1]).
        depth: [C, T, H, W] camera z, uint16 millimetres or float metres (0 = no reading), or None.
        lo: [3] lower corner of the carving box [m] (without depth; default :func:`hull_bounds` of all
            frames' masks).
        hi: [3] upper corner [m].
        spacing: Carving voxel edge [m] (default the box's longest edge / 64).
        max_points: Most points per frame.
        outlier_radius: Outlier-removal radius [m] (with depth; default 4 × the median pixel footprint
            z / f of the readings, so the test scales with the cameras' resolution).
        min_neighbors: Neighbours within ``outlier_radius`` a depth point needs to be kept.
        seed: Seed of the subsampling.

    Returns:
        (cloud [T, P, 3] float64 [m], zero-padded past each frame's count; count [T] int64), with
        P ≤ ``max_points``.
    """
    m = np.asarray(masks)
    if m.ndim != 4:
        raise ValueError(f"frame_clouds: masks: expected [C, T, H, W], got shape {m.shape}")
    C, T, H, W = m.shape
    Ks, Ts = _cameras(K, world_to_camera, C)
    if max_points < 1:
        raise ValueError(f"frame_clouds: max_points: expected >= 1, got {max_points}")
    if depth is not None:
        d = np.asarray(depth)
        if d.shape != m.shape:
            raise ValueError(f"frame_clouds: depth: expected {m.shape} like masks, got {d.shape}")
        scale = 1e-3 if d.dtype == np.uint16 else 1.0
    elif lo is None or hi is None:
        lo, hi = hull_bounds(Ks, Ts, m)
    if depth is None and spacing is None:
        spacing = float(np.max(np.asarray(hi) - np.asarray(lo))) / 64.0
    need = max(min(C, 2), C - 1)  # as hull_bounds: voxels most views saw
    clouds: list[np.ndarray] = []
    for t in range(T):
        if depth is None:
            assert lo is not None and hi is not None and spacing is not None  # set above without depth
            pts = carve(Ks, Ts, m[:, t], lo, hi, spacing).surface(min_views=need)
        else:
            zs = [d[c, t].astype(np.float64) * scale for c in range(C)]
            parts = [backproject(zs[c], Ks[c], Ts[c], m[c, t]) for c in range(C)]
            pts = np.concatenate(parts, axis=0)
            r = outlier_radius
            if r is None and pts.shape[0]:
                foot = [
                    z[(z > 0) & object_mask(m[c, t])] / Ks[c, :2, :2].diagonal().mean()
                    for c, z in enumerate(zs)
                ]
                r = 4.0 * float(np.median(np.concatenate(foot)))
            if pts.shape[0]:
                assert r is not None  # found above from the readings whenever there are points
                pts = _filtered_sample(pts, r, min_neighbors, max_points, np.random.default_rng([seed, t]))
        if pts.shape[0] > max_points:
            pick = np.random.default_rng([seed, t]).choice(pts.shape[0], max_points, replace=False)
            pts = pts[np.sort(pick)]
        clouds.append(pts)
    count = np.array([p.shape[0] for p in clouds], dtype=np.int64)
    cloud = np.zeros((T, int(count.max()), 3))
    for t, p in enumerate(clouds):
        cloud[t, : p.shape[0]] = p
    return cloud, count


__all__ = ["Plane", "fit_plane", "frame_clouds", "remove_outliers"]
