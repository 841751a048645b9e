"""Camera files: calibrated cameras a scene has never seen, to render a run from (``pliant run --cameras``),
optionally with the images and masks those cameras took, to score the rendering against.

An NPZ (``allow_pickle=False``) with:

- ``K`` [C, 3, 3]: OpenCV intrinsics [px] of each camera;
- ``world_to_camera`` [C, 4, 4]: rigid world → camera transforms (OpenCV axes: x right, y down, z forward;
  metres);
- either ``image_size`` [2]: (width, height) [px] of every camera's images, or ``images`` [C, T, H, W, 3]:
  RGB (uint8, or floats in [0, 1]), frame ``i`` taken at the run's frame ``i``;
- with ``images``, optionally ``masks`` [C, T, H, W] (bool, uint8 or floats in [0, 1]: the object's pixels),
  ``depth`` [C, T, H, W] (checked as an observation file's, not scored: an RGB-D camera's file can be given
  as it is) and ``t`` [T] (times [s], only compared with the run's).

The same conventions and checks as the image arrays of an observation file
(:func:`pliant.io._observation_images.check_image_arrays`); each error is one line naming the file and the
array.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._npz import read_npz
from ._observation_images import check_cameras, check_image_arrays

#: The arrays a camera file may hold.
CAMERA_FILE_ARRAYS = ("K", "world_to_camera", "image_size", "images", "masks", "depth", "t")
#: Largest image side [px] a camera file may ask for (a typo such as 64000 would allocate gigabytes).
MAX_IMAGE_SIDE = 16384


class CameraFileError(ValueError):
    """A camera file that cannot be used; the message names the file, the array and the fix."""


@dataclass
class CameraFile:
    """The validated contents of a camera file (:func:`load_camera_file`).

    Attributes:
        path: the file.
        K: [C, 3, 3] intrinsics [px], float64.
        world_to_camera: [C, 4, 4] rigid transforms, float64.
        width: image width [px].
        height: image height [px].
        images: [C, T, H, W, 3] RGB as stored (uint8 or floats in [0, 1]), or None.
        masks: [C, T, H, W] as stored, or None.
        t: [T] times [s], or None.
    """

    path: Path
    K: np.ndarray
    world_to_camera: np.ndarray
    width: int
    height: int
    images: np.ndarray | None = None
    masks: np.ndarray | None = None
    t: np.ndarray | None = None

    @property
    def count(self) -> int:
        """The number of cameras C."""
        return int(self.K.shape[0])

    @property
    def frames(self) -> int:
        """Frames of images per camera (0 without images)."""
        return 0 if self.images is None else int(self.images.shape[1])


def _image_size(value: np.ndarray, fail) -> tuple[int, int]:
    a = np.asarray(value)
    if a.shape != (2,) or not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise fail("image_size", f"expected [2] numbers (width, height) in pixels, got {a.dtype} {a.shape}")
    w, h = (float(v) for v in a)
    if not all(np.isfinite(v) and v == int(v) and 1 <= v <= MAX_IMAGE_SIDE for v in (w, h)):
        raise fail(
            "image_size", f"expected whole numbers of pixels in [1, {MAX_IMAGE_SIDE}], got [{w:g}, {h:g}]"
        )
    return int(w), int(h)


def load_camera_file(path: str | os.PathLike) -> CameraFile:
    """Read and validate a camera file (the format is in this module's docstring).

    Args:
        path: the NPZ file.

    Raises:
        FileNotFoundError: no such file.
        CameraFileError: unreadable file, unknown or missing arrays, bad shapes, dtypes or values; the
            message is one line naming the file and the array.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"camera file not found: {path}")
    data = read_npz(path, "camera", CameraFileError)

    def fail(array: str, msg: str) -> CameraFileError:
        return CameraFileError(f"{path}: {array}: {msg}")

    unknown = sorted(set(data) - set(CAMERA_FILE_ARRAYS))
    if unknown:
        raise fail(unknown[0], f"unknown array; a camera file holds {', '.join(CAMERA_FILE_ARRAYS)}")
    for name in ("K", "world_to_camera"):
        if name not in data:
            raise fail(name, "missing; a camera file needs K [C, 3, 3] and world_to_camera [C, 4, 4]")
    for name in ("K", "world_to_camera"):
        if not (np.issubdtype(data[name].dtype, np.floating) or np.issubdtype(data[name].dtype, np.integer)):
            raise fail(name, f"expected numbers, got {data[name].dtype}")
    images = data.get("images")
    if images is None:
        for name in ("masks", "depth", "t"):
            if name in data:
                raise fail(name, "given without images [C, T, H, W, 3]; add the camera images or drop it")
        if "image_size" not in data:
            raise fail(
                "image_size", "missing; give image_size [2] (width, height) or the images [C, T, H, W, 3]"
            )
        W, H = _image_size(data["image_size"], fail)
        k = np.asarray(data["K"])
        if k.ndim != 3 or k.shape[0] < 1:
            raise fail("K", f"expected [C, 3, 3] intrinsic matrices (one per camera), got shape {k.shape}")
        return CameraFile(path, *check_cameras(k, data["world_to_camera"], k.shape[0], W, H, fail), W, H)
    if np.asarray(images).ndim != 5:
        raise fail("images", f"expected RGB videos [C, T, H, W, 3], got shape {np.asarray(images).shape}")
    t = data.get("t")
    T = int(images.shape[1])
    if t is not None:
        t = np.asarray(t)
        if t.ndim != 1 or not np.issubdtype(t.dtype, np.number) or np.iscomplexobj(t):
            raise fail("t", f"expected [T] times [s], got {t.dtype} {t.shape}")
        if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise fail("t", "times must be finite and strictly increasing [s]")
        T = len(t)  # check_image_arrays compares it with the images' frame count
    images, K, T_wc, masks, _ = check_image_arrays(
        T, images, data["K"], data["world_to_camera"], data.get("masks"), data.get("depth"), fail
    )
    assert images is not None and K is not None and T_wc is not None  # images were given
    H, W = int(images.shape[2]), int(images.shape[3])
    if "image_size" in data and _image_size(data["image_size"], fail) != (W, H):
        raise fail(
            "image_size",
            f"{_image_size(data['image_size'], fail)} differs from the images' (width, height) ({W}, {H}); "
            "drop image_size or make it match",
        )
    return CameraFile(path, K, T_wc, W, H, images, masks, None if t is None else np.asarray(t, np.float64))


__all__ = ["CAMERA_FILE_ARRAYS", "CameraFile", "CameraFileError", "load_camera_file"]
