"""Argument checks shared by the builder's element and shape methods (host side, NumPy)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt


def _as_index_array(indices: npt.ArrayLike, width: int, what: str) -> np.ndarray:
    arr = np.asarray(indices)
    if arr.size == 0:
        return np.zeros((0, width), np.int32)
    if not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{what} indices must be integers, got dtype {arr.dtype}")
    arr = arr.reshape(-1, width) if arr.ndim == 1 and width > 1 else arr
    if arr.ndim != 2 or arr.shape[1] != width:
        raise ValueError(f"{what} indices must have shape [n, {width}], got {arr.shape}")
    return arr.astype(np.int32)


def _per_item(value: npt.ArrayLike, n: int, what: str, unit: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if np.ndim(value) == 0:
        arr = np.full(n, arr[0])
    elif arr.shape[0] != n:
        raise ValueError(f"{what} has {arr.shape[0]} values for {n} items; give one value or {n} [{unit}]")
    if not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.isfinite(arr))
        raise ValueError(f"{what} contains NaN/inf at {bad[:5].tolist()}; give finite values [{unit}]")
    return arr
