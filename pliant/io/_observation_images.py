"""Image observations (calibrated camera videos) in an observation NPZ: validation of ``images``, ``K``,
``world_to_camera``, ``masks`` and ``depth`` (the contract is in :mod:`pliant.io._observations`).

Checked here, each with a one-line error naming the file, the array and the fix: shapes and dtypes,
non-positive focal lengths, skew, non-rigid poses (scale, shear, reflection), NaN or inf in images or masks,
values outside [0, 1], principal points outside the images (a K made for another image size), a frame
count that differs from the observation times, a camera whose mask holds no object pixel in any frame, and
depth that is not uint16 millimetres or float metres, or holds NaN, inf or negative values.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: Arrays of an image observation (all optional in the file; images, K and world_to_camera come together).
IMAGE_ARRAYS = ("images", "K", "world_to_camera", "masks", "depth")

#: A mask value above this is an object pixel (bool True, uint8 >= 128, float > 0.5).
MASK_THRESHOLD = 0.5

#: Largest deviation of R Rᵀ from the identity accepted for a rigid pose (OpenCV calibrations print ~1e-9).
RIGID_TOL = 1e-5


def _unit_range(a: np.ndarray, array: str, fail: Callable[[str, str], Exception], what: str) -> np.ndarray:
    """Check an image-like array (uint8, bool or float in [0, 1]); returns it unchanged (no copy)."""
    if a.dtype == np.uint8 or a.dtype == np.bool_:
        return a
    if not np.issubdtype(a.dtype, np.floating):
        raise fail(array, f"expected {what} as uint8 (0-255) or floats in [0, 1], got {a.dtype}")
    bad = ~np.isfinite(a)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise fail(
            array,
            f"{int(bad.sum())} values are NaN or inf (first at camera {idx[0]}, frame {idx[1]}, pixel "
            f"y={idx[2]} x={idx[3]}); fill or drop those frames before fitting",
        )
    lo, hi = float(a.min()), float(a.max())
    if lo < 0.0 or hi > 1.0:
        raise fail(
            array,
            f"float values must lie in [0, 1], got [{lo:.4g}, {hi:.4g}]; divide 8-bit values by 255 or "
            "store them as uint8",
        )
    return a


def check_cameras(
    K: np.ndarray,
    world_to_camera: np.ndarray,
    C: int,
    W: int,
    H: int,
    fail: Callable[[str, str], Exception],
) -> tuple[np.ndarray, np.ndarray]:
    """Validate C OpenCV cameras for W x H images: shapes, positive focal lengths, no skew, principal points
    inside the images, rigid poses.

    Args:
        K: [C, 3, 3] intrinsics [px].
        world_to_camera: [C, 4, 4] rigid world → camera transforms (OpenCV axes, metres).
        C: the number of cameras (of the images, or of K).
        W: image width [px].
        H: image height [px].
        fail: ``fail(array, message)`` builds the exception (it names the file).

    Returns:
        (K, world_to_camera) as float64.
    """
    for name, a in (("K", K), ("world_to_camera", world_to_camera)):
        # Complex entries would lose their imaginary part in the cast below, strings raise NumPy's words.
        if np.asarray(a).dtype.kind not in "fiu":
            raise fail(name, f"expected real numbers, got {np.asarray(a).dtype}")
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (C, 3, 3):
        raise fail("K", f"expected [C={C}, 3, 3] intrinsic matrices (one per camera), got shape {K.shape}")
    T_wc = np.asarray(world_to_camera, dtype=np.float64)
    if T_wc.shape != (C, 4, 4):
        raise fail(
            "world_to_camera", f"expected [C={C}, 4, 4] rigid transforms (one per camera), got {T_wc.shape}"
        )
    for c in range(C):
        k = K[c]
        if not np.all(np.isfinite(k)):
            raise fail("K", f"camera {c}: non-finite entries")
        # A subnormal focal length (5e-324) is "positive" but its inverse, the pixel footprint, overflows.
        if not min(k[0, 0], k[1, 1]) >= np.finfo(np.float64).tiny:
            raise fail(
                "K",
                f"camera {c}: focal lengths must be positive pixels, got fx={k[0, 0]:.6g}, fy={k[1, 1]:.6g}; "
                "K is [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]",
            )
        if k[0, 1] != 0.0 or k[1, 0] != 0.0 or not np.allclose(k[2], [0.0, 0.0, 1.0]):
            raise fail(
                "K", f"camera {c}: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew), got {k.tolist()}"
            )
        if not (0.0 <= k[0, 2] <= W and 0.0 <= k[1, 2] <= H):
            raise fail(
                "K",
                f"camera {c}: principal point ({k[0, 2]:.6g}, {k[1, 2]:.6g}) px lies outside the {W}x{H} "
                "images; K must be for this image size (scale fx, fy, cx, cy by the resize factor)",
            )
        t = T_wc[c]
        if not np.all(np.isfinite(t)):
            raise fail("world_to_camera", f"camera {c}: non-finite entries")
        if not np.allclose(t[3], [0.0, 0.0, 0.0, 1.0]):
            raise fail(
                "world_to_camera", f"camera {c}: the last row must be [0, 0, 0, 1], got {t[3].tolist()}"
            )
        R = t[:3, :3]
        with np.errstate(over="ignore", invalid="ignore"):  # huge entries: inf or NaN, refused just below
            ortho = float(np.abs(R @ R.T - np.eye(3)).max())
            det = float(np.linalg.det(R))
        if not ortho <= RIGID_TOL or not det >= 0.0:
            raise fail(
                "world_to_camera",
                f"camera {c}: not a rigid transform (|R Rᵀ − I| = {ortho:.3g}, det R = {det:.6g}); its 3x3 "
                "block must be a rotation (no scale, shear or reflection), in metres",
            )
    return K, T_wc


def check_image_arrays(
    T: int,
    images: np.ndarray | None,
    K: np.ndarray | None,
    world_to_camera: np.ndarray | None,
    masks: np.ndarray | None,
    depth: np.ndarray | None,
    fail: Callable[[str, str], Exception],
) -> tuple[np.ndarray | None, ...]:
    """Validate the image arrays of an observation file with T observation times.

    Args:
        T: Number of observation times (``t``).
        images: [C, T, H, W, 3] RGB, uint8 or floats in [0, 1], or None.
        K: [C, 3, 3] OpenCV intrinsics [px] of each camera, or None.
        world_to_camera: [C, 4, 4] rigid world → camera transforms (OpenCV axes, metres), or None.
        masks: [C, T, H, W] object masks (bool, uint8 or floats in [0, 1]), or None.
        depth: [C, T, H, W] depth along each camera's optical axis (z): uint16 millimetres or float metres,
            0 where there is no reading, or None.
        fail: ``fail(array, message)`` builds the exception (it names the file).

    Returns:
        (images, K as float64, world_to_camera as float64, masks, depth), unchanged dtypes for the images,
        masks and depth.
    """
    arrays = (images, K, world_to_camera, masks, depth)
    given = {n: a is not None for n, a in zip(IMAGE_ARRAYS, arrays, strict=True)}
    if not given["images"]:
        extra = [n for n in IMAGE_ARRAYS[1:] if given[n]]
        if extra:
            raise fail(extra[0], "given without images [C, T, H, W, 3]; add the camera images or drop it")
        return None, None, None, None, None
    for n in ("K", "world_to_camera"):
        if not given[n]:
            raise fail(
                n, f"missing: images need K [C, 3, 3] and world_to_camera [C, 4, 4] (the {n} of each camera)"
            )
    images = np.asarray(images)
    if images.ndim != 5 or images.shape[4] != 3 or min(images.shape[:4]) < 1:
        raise fail("images", f"expected RGB videos [C, T={T}, H, W, 3], got shape {images.shape}")
    C, Ti, H, W = images.shape[:4]
    if Ti != T:
        raise fail(
            "images",
            f"{Ti} frames per camera but t has {T} times; one image per camera at every observation time",
        )
    if images.dtype == np.bool_:
        raise fail("images", "expected uint8 or float RGB, got bool (a mask belongs in masks)")
    _unit_range(images, "images", fail, "RGB")
    K, T_wc = check_cameras(np.asarray(K), np.asarray(world_to_camera), C, W, H, fail)
    if masks is not None:
        masks = np.asarray(masks)
        if masks.shape != (C, T, H, W):
            raise fail("masks", f"expected [C={C}, T={T}, H={H}, W={W}] like images, got shape {masks.shape}")
        _unit_range(masks, "masks", fail, "masks")
        seen = np.array([object_pixels(masks[c]).any() for c in range(C)])
        if not seen.all():
            c = int(np.flatnonzero(~seen)[0])
            raise fail(
                "masks",
                f"camera {c} has no object pixel in any frame (none above {MASK_THRESHOLD}); mark the "
                "object's pixels True / 255 / 1.0, or drop that camera's images, K, pose and masks",
            )
    if depth is not None:
        depth = _check_depth(np.asarray(depth), (C, T, H, W), fail)
    return images, K, T_wc, masks, depth


def _check_depth(
    depth: np.ndarray, shape: tuple[int, ...], fail: Callable[[str, str], Exception]
) -> np.ndarray:
    """Check a depth video [C, T, H, W]: uint16 mm or finite float metres >= 0 (0 = no reading)."""
    if depth.shape != shape:
        C, T, H, W = shape
        raise fail("depth", f"expected [C={C}, T={T}, H={H}, W={W}] like images, got shape {depth.shape}")
    if depth.dtype == np.uint16:
        return depth
    if depth.dtype not in (np.float32, np.float64):
        raise fail(
            "depth",
            f"expected uint16 millimetres or float32/float64 metres, got {depth.dtype}; convert it, e.g. "
            "np.round(d_mm).astype(np.uint16) or d_m.astype(np.float32)",
        )
    bad = ~np.isfinite(depth)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise fail(
            "depth",
            f"{int(bad.sum())} values are NaN or inf (first at camera {idx[0]}, frame {idx[1]}, pixel "
            f"y={idx[2]} x={idx[3]}); use 0 for no reading",
        )
    big = np.abs(depth) > np.finfo(np.float32).max  # depth_m reads float32: these would become inf
    if big.any():
        raise fail(
            "depth",
            f"{int(big.sum())} values exceed float32's range (3.4e38 m), which depth is read in; depth is "
            "metres along the optical axis, 0 for no reading",
        )
    neg = depth < 0.0
    if neg.any():
        idx = tuple(int(i) for i in np.argwhere(neg)[0])
        raise fail(
            "depth",
            f"{int(neg.sum())} values are negative (first {float(depth[idx]):.4g} at camera {idx[0]}, frame "
            f"{idx[1]}, pixel y={idx[2]} x={idx[3]}); depth is metres along the optical axis, 0 for no "
            "reading",
        )
    return depth


def object_pixels(mask: np.ndarray) -> np.ndarray:
    """Where a mask (bool, uint8 or floats in [0, 1], any shape) marks the object: bool, same shape."""
    if mask.dtype == np.bool_:
        return mask
    if mask.dtype == np.uint8:
        return mask >= 128
    return mask > MASK_THRESHOLD


def depth_metres(depth: np.ndarray) -> np.ndarray:
    """A depth image (uint16 mm or float m, any shape) as float32 metres, 0 where there is no reading."""
    if depth.dtype == np.uint16:
        return depth.astype(np.float32) * np.float32(1e-3)
    return depth.astype(np.float32)


def to_unit_float(a: np.ndarray) -> np.ndarray:
    """An image or mask as float64 in [0, 1] (uint8 / 255, bool as 0 / 1)."""
    if a.dtype == np.uint8:
        return a.astype(np.float64) / 255.0
    return a.astype(np.float64)


__all__ = [
    "check_cameras",
    "IMAGE_ARRAYS",
    "MASK_THRESHOLD",
    "check_image_arrays",
    "depth_metres",
    "object_pixels",
    "to_unit_float",
]
