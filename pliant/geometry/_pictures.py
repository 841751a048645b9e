"""Geometry from calibrated pictures: projection, space carving from masks (and free-space carving from
depth), an automatic search box, depth back-projection, a check of the views against each other.

Cameras follow the OpenCV convention of :class:`pliant.gaussians.Camera` and pliant's rasteriser: ``K`` =
``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` [px], ``world_to_camera`` a rigid [4, 4] transform (metres; camera
axes x right, y down, z forward), pixel centres at integer coordinates: pixel (row i, column j) is centred at
(u, v) = (j, i) and covers [j − ½, j + ½) × [i − ½, i + ½). A point lies on the pixel ``(round(v), round(u))``
(rounding halves up), the pixel whose splat value the rasteriser evaluates at its centre. Depth is a
point's camera z [m] (along the optical axis, not the distance along the ray), as the rasteriser's depth.

Masks are bool, uint8 (object where ≥ 128) or floats in [0, 1] (object where > 0.5). NumPy and SciPy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

#: Voxels carved per chunk: bounds the temporaries (about 100 bytes per voxel) on fine grids.
_CHUNK = 1 << 20


@dataclass
class Voxels:
    """A carved voxel grid.

    Attributes:
        centres: [M, 3] centres [m] of the kept voxels, in grid order (x slowest, z fastest).
        origin: [3] the grid's lower corner [m]; voxel (i, j, k) spans ``origin + [i, j, k] · spacing`` to
            ``origin + [i + 1, j + 1, k + 1] · spacing``, centred at ``origin + ([i, j, k] + ½) · spacing``.
        spacing: Voxel edge [m].
        shape: (nx, ny, nz) voxels per axis.
        occupied: [nx, ny, nz] bool, the kept voxels.
        seen_by: [nx, ny, nz] uint8, how many views hold the voxel's centre in their image (in front of the
            camera): a kept voxel that no view saw is kept for want of evidence, not because it is the
            object's.
        sole: [C] int, voxels that camera c alone removed (every other view kept them): a camera whose
            pose, intrinsics or masks disagree with the others stands out here.
    """

    centres: np.ndarray
    origin: np.ndarray
    spacing: float
    shape: tuple[int, int, int]
    occupied: np.ndarray
    seen_by: np.ndarray
    sole: np.ndarray

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) [m]: the box of the kept voxels' faces. Raises ValueError when nothing is kept."""
        if self.centres.shape[0] == 0:
            raise ValueError("Voxels.bounds: no voxel is kept (the views share no object region)")
        h = 0.5 * self.spacing
        return self.centres.min(axis=0) - h, self.centres.max(axis=0) + h

    def surface(self, min_views: int = 0) -> np.ndarray:
        """[S, 3] centres [m] of the kept voxels with a face on an empty voxel or on the grid's boundary.

        Args:
            min_views: Count only kept voxels that at least this many views saw (``seen_by``): voxels kept
                for want of evidence (outside most images) are then empty.
        """
        from scipy.ndimage import binary_erosion

        occ = self.occupied & (self.seen_by >= min_views)
        inner = binary_erosion(occ, border_value=0)
        return grid_centres(self.origin, self.spacing, np.argwhere(occ & ~inner))


def grid_centres(origin: np.ndarray, spacing: float, index: np.ndarray) -> np.ndarray:
    """Centres [n, 3] [m] of voxels ``index`` [n, 3] (int) of a grid with lower corner ``origin`` [3] [m] and
    edge ``spacing`` [m]."""
    return np.asarray(origin, dtype=np.float64) + (index + 0.5) * float(spacing)


def object_mask(mask: np.ndarray) -> np.ndarray:
    """Where a mask (bool, uint8 or floats in [0, 1], any shape) marks the object: bool, same shape (uint8
    ≥ 128, floats > 0.5)."""
    mask = np.asarray(mask)
    if mask.dtype == np.bool_:
        return mask
    if mask.dtype == np.uint8:
        return mask >= 128
    return mask > 0.5


def _cameras(K: ArrayLike, world_to_camera: ArrayLike, C: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    K = np.asarray(K, dtype=np.float64)
    T = np.asarray(world_to_camera, dtype=np.float64)
    if K.ndim == 2:
        K, T = K[None], T[None]
    if K.ndim != 3 or K.shape[1:] != (3, 3) or T.shape != (K.shape[0], 4, 4):
        raise ValueError(
            f"cameras: expected K [C, 3, 3] and world_to_camera [C, 4, 4], got {K.shape} and {T.shape}"
        )
    if C is not None and K.shape[0] != C:
        raise ValueError(f"cameras: {K.shape[0]} cameras (K) but masks for {C}; give one mask per camera")
    return K, T


def project(points: ArrayLike, K: ArrayLike, world_to_camera: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Project world points into one camera (OpenCV convention, pixel centres at integers).

    The same arithmetic as pliant's rasteriser (``fx · x / z + cx``, ``fy · y / z + cy`` on the camera-space
    point ``R p + t``), so carving and rendering agree on which pixel a point falls in.

    Args:
        points: [N, 3] world positions [m].
        K: [3, 3] intrinsics ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` [px].
        world_to_camera: [4, 4] rigid world → camera transform [m].

    Returns:
        (uv [N, 2] pixel coordinates (u right, v down) [px], z [N] camera depth [m]); uv is NaN where
        z ≤ 0 (behind the camera).
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    u, v, z = _project_xyz(p[:, 0], p[:, 1], p[:, 2], np.asarray(K, dtype=np.float64), world_to_camera)
    return np.stack([u, v], axis=1), z


def _project_xyz(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, K: np.ndarray, world_to_camera: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, camera z) of world coordinates x, y, z [m] (any broadcastable shapes: a grid's axes give the
    grid). Written per component, not as ``p @ R.T``: NumPy's [N, 3] @ [3, 3] is ~50× slower here."""
    T = np.asarray(world_to_camera, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    qx = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]
    qy = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]
    qz = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
    qz = np.broadcast_to(qz, np.broadcast_shapes(np.shape(qx), np.shape(qy), np.shape(qz)))
    with np.errstate(divide="ignore", invalid="ignore"):
        iz = np.where(qz > 0.0, 1.0 / qz, np.nan)
    with np.errstate(over="ignore", invalid="ignore"):  # a huge focal length: ±inf, outside as NaN is
        return K[0, 0] * qx * iz + K[0, 2], K[1, 1] * qy * iz + K[1, 2], np.array(qz)


def _pixel(u: np.ndarray, v: np.ndarray, H: int, W: int) -> tuple[np.ndarray, np.ndarray]:
    """(flat pixel index row · W + column, inside) of the pixels that points (u, v) fall in; NaN (behind the
    camera) is outside, and its index 0."""
    with np.errstate(invalid="ignore", over="ignore"):  # rows far outside (a huge focal length): index 0
        col = np.floor(u + 0.5)
        row = np.floor(v + 0.5)
        inside = (col >= 0) & (col < W) & (row >= 0) & (row < H)
        return np.where(inside, row * W + col, 0).astype(np.intp), inside


def carve(
    K: ArrayLike,
    world_to_camera: ArrayLike,
    masks: ArrayLike,
    lo: ArrayLike,
    hi: ArrayLike,
    spacing: float,
    *,
    depth: ArrayLike | None = None,
    depth_tol: float | None = None,
    footprint: bool = False,
) -> Voxels:
    """Space carving: the voxels of the box [lo, hi] that every view sees as the object.

    A voxel is removed when its centre projects onto a background pixel of ANY view. A voxel whose centre
    projects outside an image (or lies behind the camera) is NOT removed by that view: the camera saw
    nothing there, and an object partly out of one camera's frame must keep the parts the other cameras
    see. With ``depth``, a voxel is also removed when, in a view whose depth reading at its pixel is valid
    (> 0), its centre lies in front of the observed surface by more than ``depth_tol`` (free-space carving:
    the camera saw through it). Depth is used at object pixels only. A reading behind the true surface
    (noise, a sensor's flying pixels at silhouettes) carves the object itself, so ``depth_tol`` must cover
    the depth's error: pliant's own rasteriser returns the alpha-blended depth of splat centres, 1–3 cm
    inside a 0.3 m soft box of surface splats.

    Only the centre is tested (default): a voxel straddling the silhouette is kept when its centre is
    inside, so the kept set is the voxels whose centres lie in the visual hull, within half a voxel of it.
    With ``footprint=True`` a view removes a voxel only when its projected footprint (the square of
    half-width max(fx, fy) · (√3/2 · spacing) / z around its centre's projection, the circumscribed
    sphere's image near the optical axis, clipped to the image) holds no object pixel: a conservative hull
    that keeps parts thinner than a voxel.

    Args:
        K: [C, 3, 3] intrinsics [px] of each camera.
        world_to_camera: [C, 4, 4] rigid world → camera transforms [m].
        masks: [C, H, W] object masks (bool, uint8 ≥ 128 or floats > 0.5 are the object).
        lo: [3] lower corner of the search box [m].
        hi: [3] upper corner [m]; the grid covers [lo, lo + n · spacing] with n = ceil((hi − lo) / spacing).
        spacing: Voxel edge [m], > 0.
        depth: [C, H, W] camera z [m] of the observed surface, 0 where there is no reading, or None.
        depth_tol: Free space carved only beyond this distance in front of the surface [m] (default half a
            voxel: a voxel whose centre lies closer than that may still hold some of the surface).
        footprint: Test each voxel's projected footprint instead of its centre (silhouettes only).

    Returns:
        The kept :class:`Voxels`.

    Raises:
        ValueError: bad shapes, a non-positive spacing, an empty box, more than 255 cameras, or a grid of
            more than 2.5 · 10⁸ voxels.
    """
    m = np.asarray(masks)
    if m.ndim != 3:
        raise ValueError(f"carve: masks: expected [C, H, W] (one frame per camera), got shape {m.shape}")
    C, H, W = m.shape
    K, T = _cameras(K, world_to_camera, C)
    if C > 255:
        raise ValueError(f"carve: {C} cameras; at most 255 are supported")
    obj = object_mask(m)
    d = None if depth is None else _object_depth(depth, obj)
    if not spacing > 0.0:
        raise ValueError(f"carve: spacing: expected a voxel edge > 0 m, got {spacing}")
    tol = 0.5 * spacing if depth_tol is None else float(depth_tol)
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    if lo.shape != (3,) or hi.shape != (3,) or not np.all(hi > lo):
        raise ValueError(f"carve: expected lo < hi, two [3] corners in metres, got {lo} and {hi}")
    nx, ny, nz = (int(v) for v in np.maximum(np.ceil((hi - lo) / spacing - 1e-9), 1))
    shape = (nx, ny, nz)
    total = shape[0] * shape[1] * shape[2]
    if total > 250_000_000:
        raise ValueError(f"carve: {shape} is {total:.3g} voxels; use a larger spacing or a smaller box")
    # Summed-area tables of the object pixels (one row and column of zeros in front): a footprint's object
    # pixel count in O(1) per voxel.
    sat = None
    if footprint:
        sat = np.zeros((C, H + 1, W + 1), dtype=np.int64)
        sat[:, 1:, 1:] = obj.cumsum(axis=1).cumsum(axis=2)
    half_diag = 0.5 * np.sqrt(3.0) * spacing
    # Per voxel: how many views removed it and the last one that did (2 bytes a voxel, not C).
    n_removed = np.zeros(total, dtype=np.uint8)
    seen_by = np.zeros(total, dtype=np.uint8)
    remover = np.zeros(total, dtype=np.uint8)
    obj_flat = obj.reshape(C, H * W)
    d_flat = None if d is None else d.reshape(C, H * W)
    axes = [lo[a] + (np.arange(shape[a]) + 0.5) * spacing for a in range(3)]
    slab = max(1, _CHUNK // (shape[1] * shape[2]))  # whole x-slabs per chunk: the grid by broadcasting
    for i0 in range(0, shape[0], slab):
        flat = slice(i0 * shape[1] * shape[2], min(i0 + slab, shape[0]) * shape[1] * shape[2])
        x = axes[0][i0 : i0 + slab, None, None]
        for c in range(C):
            u, v, z = (a.ravel() for a in _project_xyz(x, axes[1][:, None], axes[2], K[c], T[c]))
            pix, inside = _pixel(u, v, H, W)
            seen_by[flat] += inside
            if sat is None:
                out = inside & ~obj_flat[c, pix]
            else:
                out = _footprint_empty(u, v, z, inside, K[c], half_diag, sat[c])
            if d_flat is not None:
                dc = d_flat[c, pix]
                out |= inside & (dc > 0.0) & (z < dc - tol)
            n_removed[flat] += out
            remover[flat][out] = c
    once = n_removed == 1
    sole = np.bincount(remover[once], minlength=C)
    occupied = (n_removed == 0).reshape(shape)
    return Voxels(
        centres=grid_centres(lo, spacing, np.argwhere(occupied)),
        origin=lo.copy(),
        spacing=float(spacing),
        shape=shape,
        occupied=occupied,
        seen_by=seen_by.reshape(shape),
        sole=sole.astype(np.int64),
    )


def _object_depth(depth: ArrayLike, obj: np.ndarray) -> np.ndarray:
    """Depth readings [C, H, W] (m) kept at the object pixels of ``obj`` [C, H, W] (bool), 0 elsewhere and
    where not finite."""
    C, H, W = obj.shape
    d = np.asarray(depth, dtype=np.float64)
    if d.shape != (C, H, W):
        raise ValueError(f"carve: depth: expected [C={C}, H={H}, W={W}] like masks, got {d.shape}")
    # Depth counts at object pixels only: the silhouettes already carve along background rays, and
    # a floor's readings there would cut into the footprint test's margin. (Eroding the masks against
    # silhouette pixels that mix object and background was tried: it leaves the visual hull's bulges,
    # whose voxels project near silhouettes, uncarved.)
    d = np.where(np.isfinite(d) & obj, d, 0.0)
    return d


def _footprint_empty(
    u: np.ndarray,
    v: np.ndarray,
    z: np.ndarray,
    inside: np.ndarray,
    Kc: np.ndarray,
    half_diag: float,
    sat_c: np.ndarray,
) -> np.ndarray:
    """Voxels whose projected footprint holds no object pixel in one view: centres projected to pixel
    coordinates ``u``, ``v`` (px) at camera depth ``z`` (m), ``inside`` the image, intrinsics ``Kc`` [3, 3]
    (px), circumscribed radius ``half_diag`` (m), ``sat_c`` [H + 1, W + 1] the view's summed-area table."""
    H, W = sat_c.shape[0] - 1, sat_c.shape[1] - 1
    # the footprint's square [u ± r] × [v ± r], clipped to the image: a view judges what it saw
    with np.errstate(invalid="ignore", divide="ignore"):
        r = max(Kc[0, 0], Kc[1, 1]) * half_diag / z
        c0, c1 = np.floor(u - r + 0.5).clip(0, W - 1), np.floor(u + r + 0.5).clip(0, W - 1)
        r0, r1 = np.floor(v - r + 0.5).clip(0, H - 1), np.floor(v + r + 0.5).clip(0, H - 1)
        seen = inside & (z > half_diag)
    c0, c1, r0, r1 = (np.where(seen, a, 0).astype(np.intp) for a in (c0, c1, r0, r1))
    count = sat_c[r1 + 1, c1 + 1] - sat_c[r0, c1 + 1] - sat_c[r1 + 1, c0] + sat_c[r0, c0]
    return seen & (count == 0)


def _footprints(
    points: np.ndarray, spacing: float, K: np.ndarray, T: np.ndarray, H: int, W: int
) -> np.ndarray:
    """[H, W] bool: the pixels that the footprints (the square around the projection of each voxel's
    circumscribed sphere) of voxels centred at ``points`` [n, 3] [m] cover in one view. Drawn as a 2-D
    difference array (+1/−1 at each square's corners, then cumulative sums): no loop over voxels."""
    u, v, z = _project_xyz(points[:, 0], points[:, 1], points[:, 2], K, T)
    half_diag = 0.5 * np.sqrt(3.0) * spacing
    front = z > half_diag
    u, v, z = u[front], v[front], z[front]
    r = max(K[0, 0], K[1, 1]) * half_diag / z
    c0 = np.floor(u - r + 0.5).clip(0, W)
    c1 = np.floor(u + r + 0.5).clip(-1, W - 1)
    r0 = np.floor(v - r + 0.5).clip(0, H)
    r1 = np.floor(v + r + 0.5).clip(-1, H - 1)
    ok = (c0 <= c1) & (r0 <= r1)
    c0, c1, r0, r1 = (a[ok].astype(np.intp) for a in (c0, c1, r0, r1))
    diff = np.zeros((H + 1, W + 1), dtype=np.int64)
    np.add.at(diff, (r0, c0), 1)
    np.add.at(diff, (r0, c1 + 1), -1)
    np.add.at(diff, (r1 + 1, c0), -1)
    np.add.at(diff, (r1 + 1, c1 + 1), 1)
    return diff.cumsum(axis=0).cumsum(axis=1)[:H, :W] > 0


def view_agreement(
    K: ArrayLike,
    world_to_camera: ArrayLike,
    masks: ArrayLike,
    lo: ArrayLike,
    hi: ArrayLike,
    spacing: float,
) -> np.ndarray:
    """How well each view's mask agrees with the other views: the fraction of its object pixels that the
    hull carved by all the OTHER views covers when projected into it (each voxel's footprint).

    The other views' hull contains the object, so with consistent cameras and masks it covers the whole
    silhouette (≈ 1). A camera with a wrong pose or intrinsics, or masks of another frame or object, has
    object pixels that nothing the others kept projects onto, so its agreement drops, and so does that of
    the views whose hull it cut (often the one facing it): a low value says the views disagree, the lowest
    points at the culprit or its partner. Four views carve loosely, so small errors pass unseen (with the
    box of the tests: a 5 px shift or a 3° roll of one camera; a 25 px shift gives 0.78–0.83).

    Args:
        K: [C, 3, 3] intrinsics [px], C ≥ 2.
        world_to_camera: [C, 4, 4] rigid world → camera transforms [m].
        masks: [C, H, W] object masks (bool, uint8 or floats in [0, 1]).
        lo: [3] lower corner of the carving box [m].
        hi: [3] upper corner [m].
        spacing: Voxel edge [m].

    Returns:
        [C] fractions in [0, 1] (1 for a camera without object pixels: nothing to contradict).
    """
    m = object_mask(np.asarray(masks))
    if m.ndim != 3:
        raise ValueError(f"view_agreement: masks: expected [C, H, W], got shape {m.shape}")
    C, H, W = m.shape
    Ks, Ts = _cameras(K, world_to_camera, C)
    if C < 2:
        raise ValueError("view_agreement: needs at least two cameras (one view cannot disagree with itself)")
    out = np.ones(C)
    for c in range(C):
        others = np.arange(C) != c
        vox = carve(Ks[others], Ts[others], m[others], lo, hi, spacing)
        n = int(m[c].sum())
        if n:
            out[c] = float((_footprints(vox.centres, spacing, Ks[c], Ts[c], H, W) & m[c]).sum()) / n
    return out


def _camera_centres_and_rays(K: np.ndarray, T: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera centres [C, 3] [m] and unit world directions [C, 3] of the rays through pixels ``uv`` [C, 2]."""
    R = T[:, :3, :3]
    o = -np.einsum("cji,cj->ci", R, T[:, :3, 3])
    q = np.stack(
        [(uv[:, 0] - K[:, 0, 2]) / K[:, 0, 0], (uv[:, 1] - K[:, 1, 2]) / K[:, 1, 1], np.ones(len(K))], 1
    )
    d = np.einsum("cji,cj->ci", R, q)
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def hull_bounds(
    K: ArrayLike,
    world_to_camera: ArrayLike,
    masks: ArrayLike,
    *,
    grid: int = 32,
    margin: float = 0.1,
    max_grow: int = 6,
) -> tuple[np.ndarray, np.ndarray]:
    """A search box for carving from the masks alone, when nothing else gives one.

    The rays through each view's mask centroid are triangulated (least squares) to a centre; each view's
    mask extent [px] times its depth over its focal length gives a radius, and twice the largest radius a
    first box. That box is carved coarsely (``grid`` voxels along its edge, each view testing the voxel's
    footprint, so no object part is lost) and the kept voxels seen by all views but one (both of two) give
    the bounds. Where they touch the box, the box is doubled and carved again.

    Args:
        K: [C, 3, 3] intrinsics [px].
        world_to_camera: [C, 4, 4] rigid world → camera transforms [m].
        masks: [C, H, W] object masks, or [C, T, H, W] (their union over the frames: the box of the motion).
        grid: Coarse voxels along the box's edge.
        margin: Extra room on every side [fraction of the box's largest edge] (at least one coarse voxel).
        max_grow: Doublings of the box allowed before giving up.

    Returns:
        (lo [3], hi [3]) corners [m].

    Raises:
        ValueError: fewer than two cameras with distinct viewing directions, a mask without object pixels,
            a centre behind a camera, views whose hulls share nothing, or a hull that never closes.
    """
    m: np.ndarray = object_mask(np.asarray(masks))
    if m.ndim == 4:
        m = np.asarray(m.any(axis=1))
    if m.ndim != 3:
        raise ValueError(f"hull_bounds: masks: expected [C, H, W] or [C, T, H, W], got shape {m.shape}")
    C, H, W = m.shape
    K, T = _cameras(K, world_to_camera, C)
    counts = m.sum(axis=(1, 2))
    if np.any(counts == 0):
        c = int(np.flatnonzero(counts == 0)[0])
        raise ValueError(f"hull_bounds: masks: camera {c} has no object pixel; drop that camera")
    rows, cols = np.arange(H, dtype=np.float64), np.arange(W, dtype=np.float64)
    uv = (
        np.stack([(m.sum(axis=1) * cols).sum(axis=1), (m.sum(axis=2) * rows).sum(axis=1)], 1)
        / counts[:, None]
    )
    o, d = _camera_centres_and_rays(K, T, uv)
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]  # projectors orthogonal to each ray
    A, b = P.sum(axis=0), np.einsum("cij,cj->i", P, o)
    if C < 2 or np.linalg.cond(A) > 1e8:
        raise ValueError(
            "hull_bounds: the object's centre needs at least two cameras with different viewing directions; "
            "give the search box (lo, hi) instead"
        )
    centre = np.linalg.solve(A, b)
    radius = 0.0
    for c in range(C):
        _, z = project(centre[None], K[c], T[c])
        if z[0] <= 0.0:
            raise ValueError(f"hull_bounds: the masks' centre lies behind camera {c}; check its pose")
        v, u = np.nonzero(m[c])
        r_px = float(np.sqrt(((u - uv[c, 0]) ** 2 + (v - uv[c, 1]) ** 2).max())) + 1.0
        radius = max(radius, r_px * float(z[0]) / min(K[c, 0, 0], K[c, 1, 1]))
    half = 2.0 * radius
    # Kept voxels count when all views but one saw them (both views of two): a voxel outside most frames
    # is kept for want of evidence, and two opposite cameras alone share a whole line through the object.
    need = max(min(C, 2), C - 1)
    for _ in range(max_grow + 1):
        lo, hi = centre - half, centre + half
        vox = carve(K, T, m, lo, hi, 2.0 * half / grid, footprint=True)
        keep = vox.occupied & (vox.seen_by >= need)
        if not keep.any():
            worst = int(np.argmax(vox.sole))
            raise ValueError(
                f"hull_bounds: the views share no object region (camera {worst} removed the most that the "
                "others kept); check that camera's pose, intrinsics and masks"
            )
        idx = np.argwhere(keep)
        if idx.min() > 0 and np.all(idx.max(axis=0) < np.array(vox.shape) - 1):
            h = 0.5 * vox.spacing
            klo = grid_centres(lo, vox.spacing, idx.min(axis=0)) - h
            khi = grid_centres(lo, vox.spacing, idx.max(axis=0)) + h
            pad = max(vox.spacing, margin * float((khi - klo).max()))
            return klo - pad, khi + pad
        centre = 0.5 * (
            grid_centres(lo, vox.spacing, idx.min(axis=0)) + grid_centres(lo, vox.spacing, idx.max(axis=0))
        )
        half = 2.0 * half
    raise ValueError(
        f"hull_bounds: the views' hull does not close within {half:.3g} m of the centre (too few or too "
        "similar viewing directions); give the search box (lo, hi) instead"
    )


def backproject(
    depth: ArrayLike, K: ArrayLike, world_to_camera: ArrayLike, mask: ArrayLike | None = None
) -> np.ndarray:
    """World points [m] of the valid (depth > 0, finite) pixels of one depth image, inside ``mask`` if given.

    Pixel (row i, column j) at depth z is the camera point (z (j − cx) / fx, z (i − cy) / fy, z), the
    inverse of :func:`project`.

    Args:
        depth: [H, W] camera z [m] (along the optical axis), 0 where there is no reading.
        K: [3, 3] intrinsics [px].
        world_to_camera: [4, 4] rigid world → camera transform [m].
        mask: [H, W] object mask (bool, uint8 or floats in [0, 1]), or None for every valid pixel.

    Returns:
        [M, 3] world points [m], in raster order (row by row).
    """
    z = np.asarray(depth, dtype=np.float64)
    if z.ndim != 2:
        raise ValueError(f"backproject: depth: expected [H, W] metres, got shape {z.shape}")
    valid = np.isfinite(z) & (z > 0.0)
    if mask is not None:
        mk = object_mask(np.asarray(mask))
        if mk.shape != z.shape:
            raise ValueError(f"backproject: mask: expected {z.shape} like depth, got {mk.shape}")
        valid &= mk
    K = np.asarray(K, dtype=np.float64)
    T = np.asarray(world_to_camera, dtype=np.float64)
    i, j = np.nonzero(valid)
    zz = z[i, j]
    q = np.stack([zz * (j - K[0, 2]) / K[0, 0], zz * (i - K[1, 2]) / K[1, 1], zz], axis=1)
    return (q - T[:3, 3]) @ T[:3, :3]


__all__ = [
    "Voxels",
    "backproject",
    "carve",
    "grid_centres",
    "hull_bounds",
    "object_mask",
    "project",
    "view_agreement",
]
