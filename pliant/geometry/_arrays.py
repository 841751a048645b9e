"""Shared input coercion and checks for the geometry helpers."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray


def as_points(points: ArrayLike, what: str = "points") -> NDArray[np.float64]:
    """Return ``points`` as a C-contiguous float64 array of shape [N, 3]."""
    arr = np.ascontiguousarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{what} must have shape [N, 3], got {arr.shape}")
    return arr


def as_cells(cells: ArrayLike, k: int, what: str) -> NDArray[np.int32]:
    """Return ``cells`` as a C-contiguous int32 array of shape [M, k].

    Float input is accepted only if it holds whole numbers, so that an accidental
    coordinate array passed as indices fails loudly instead of being truncated.
    """
    arr = np.asarray(cells)
    if arr.size == 0:
        arr = arr.reshape(0, k)
    if arr.ndim != 2 or arr.shape[1] != k:
        raise ValueError(f"{what} must have shape [M, {k}], got {arr.shape}")
    if not np.issubdtype(arr.dtype, np.integer):
        if not np.all(np.isfinite(arr)) or not np.all(arr == np.round(arr)):
            raise ValueError(f"{what} must hold integer vertex indices, got dtype {arr.dtype}")
    if arr.size and (arr.min() < 0 or arr.max() > np.iinfo(np.int32).max):
        raise ValueError(f"{what} holds indices outside [0, 2^31): min {arr.min()}, max {arr.max()}")
    return np.ascontiguousarray(arr, dtype=np.int32)


def check_in_range(cells: NDArray[np.integer], n_points: int, what: str) -> None:
    """Raise ``ValueError`` if any index in ``cells`` is not a valid vertex of ``n_points``."""
    if cells.size == 0:
        return
    bad = np.flatnonzero(np.any((cells < 0) | (cells >= n_points), axis=1))
    if bad.size:
        raise ValueError(
            f"{what}: {bad.size} element(s) reference vertices outside [0, {n_points}) "
            f"(first bad elements: {bad[:5].tolist()}, max index {int(cells.max())})"
        )


def as_vec3(v: ArrayLike, what: str) -> NDArray[np.float64]:
    """Return a length-3 float64 vector."""
    arr = np.asarray(v, dtype=np.float64).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be 3 finite numbers, got {v!r}")
    return arr
