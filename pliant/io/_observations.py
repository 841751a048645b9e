"""Observation files (NPZ): tracked 3D points, and optionally depth clouds and control points, of a moving
deformable object, the input of fitting (:mod:`pliant.fit`, ``pliant fit``).

The format is a contract (issue 13); every array is plain NumPy, loaded with ``allow_pickle=False``:

- ``t`` [T] seconds from the scene's start, at the scene's frame times;
- ``points`` [T, K, 3] metres, the scene's axes: K tracked points; unseen entries may be NaN;
- ``visible`` [T, K] bool, optional (default: where ``points`` is finite);
- ``particle`` [K] int, optional: the particle each track follows (default: nearest to its first visible
  position, see :meth:`Observations.bind`);
- ``controls`` [T, C, 3], optional: positions of control points (a hand, a gripper) [m];
- ``cloud`` [T, P, 3] and ``cloud_count`` [T], optional: depth point clouds, padded to P points per frame;
- ``images`` [C, T, H, W, 3], optional: C calibrated camera videos, uint8 (0-255) or floats in [0, 1], one
  image per camera at every time of ``t``; they need ``K`` [C, 3, 3] (OpenCV intrinsics [px]: fx, fy > 0, no
  skew, principal point inside the image) and ``world_to_camera`` [C, 4, 4] (rigid, metres, OpenCV axes:
  x right, y down, z forward), and may carry ``masks`` [C, T, H, W] (object masks, bool / uint8 / [0, 1];
  a pixel is the object's where the value is above one half, and every camera must see the object in at
  least one frame) and ``depth`` [C, T, H, W] (each pixel's depth along its camera's optical axis z, as
  uint16 millimetres or float32 / float64 metres; 0 where there is no reading, never NaN, inf or negative).

``points`` may be left out when ``images`` are given (a photometric fit from the videos alone) or ``cloud``
(a fit to depth clouds alone, as ``pliant twin`` makes from the pictures); a file must carry one of the
three. Files without images read and write exactly as before.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ._npz import read_npz
from ._observation_images import IMAGE_ARRAYS, check_image_arrays, depth_metres, to_unit_float
from ._trajectory import atomic_savez

_KNOWN = ("t", "points", "visible", "particle", "controls", "cloud", "cloud_count", *IMAGE_ARRAYS)


class ObservationError(ValueError):
    """A bad observation file or a mismatch with the scene; the message names the file, the array and the
    fix."""


@dataclass
class Observations:
    """Observed motion: K tracks over T frames (and optional clouds and control points).

    Attributes:
        t: [T] observation times [s] from the scene's start.
        points: [T, K, 3] tracked positions [m]; entries that are not ``visible`` are ignored (may be NaN).
        visible: [T, K] bool, where a track was seen.
        particle: [K] int, the particle each track follows, or None until :meth:`bind` sets it.
        controls: [T, C, 3] control-point positions [m], or None.
        cloud: [T, P, 3] padded depth clouds [m], or None.
        cloud_count: [T] valid points of each frame's cloud, or None.
        images: [C, T, H, W, 3] camera videos (uint8 or floats in [0, 1], kept as stored), or None.
        K: [C, 3, 3] intrinsics [px] of each camera, or None.
        world_to_camera: [C, 4, 4] rigid world → camera transforms [m], or None.
        masks: [C, T, H, W] object masks, or None.
        depth: [C, T, H, W] depth along each camera's optical axis (uint16 mm or float m, kept as stored; 0 =
            no reading), or None; :meth:`depth_m` reads it in metres.
        source: file name for messages.

    Without ``points`` in the file (images only) there are no tracks: ``points`` is [T, 0, 3].
    """

    t: np.ndarray
    points: np.ndarray
    visible: np.ndarray
    particle: np.ndarray | None = None
    controls: np.ndarray | None = None
    cloud: np.ndarray | None = None
    cloud_count: np.ndarray | None = None
    images: np.ndarray | None = None
    K: np.ndarray | None = None
    world_to_camera: np.ndarray | None = None
    masks: np.ndarray | None = None
    depth: np.ndarray | None = None
    source: str = "<observations>"

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_arrays(
        cls,
        t: np.ndarray,
        points: np.ndarray | None = None,
        visible: np.ndarray | None = None,
        particle: np.ndarray | None = None,
        controls: np.ndarray | None = None,
        cloud: np.ndarray | None = None,
        cloud_count: np.ndarray | None = None,
        images: np.ndarray | None = None,
        K: np.ndarray | None = None,
        world_to_camera: np.ndarray | None = None,
        masks: np.ndarray | None = None,
        depth: np.ndarray | None = None,
        source: str = "<observations>",
    ) -> Observations:
        """Validated observations from arrays (units as in the module docstring).

        Raises:
            ObservationError: wrong shapes or dtypes, non-finite visible points, all tracks invisible, neither
                points nor images, bad cameras or images (see :mod:`pliant.io._observation_images`).
        """

        def fail(array: str, msg: str) -> ObservationError:
            return ObservationError(f"{source}: {array}: {msg}")

        t = np.asarray(t)
        if t.ndim != 1 or t.shape[0] < 2 or t.dtype.kind not in "fiu":
            raise fail("t", f"expected times [T] in seconds with T >= 2, got shape {t.shape} ({t.dtype})")
        if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise fail("t", "times must be finite and strictly increasing (one per frame, in seconds)")
        T = t.shape[0]
        images, K, world_to_camera, masks, depth = check_image_arrays(
            T, images, K, world_to_camera, masks, depth, fail
        )
        if points is None:
            if images is None and cloud is None:
                raise fail(
                    "points",
                    "missing: an observation file needs points [T, K, 3], images [C, T, H, W, 3] or cloud "
                    "[T, P, 3]",
                )
            if visible is not None or particle is not None:
                raise fail("visible" if visible is not None else "particle", "given without points; drop it")
            points = np.zeros((T, 0, 3))
        points = np.asarray(points)
        no_tracks = (images is not None or cloud is not None) and points.ndim == 3 and points.shape[1] == 0
        if (
            points.ndim != 3
            or points.shape[0] != T
            or points.shape[2] != 3
            or (points.shape[1] < 1 and not no_tracks)
        ):
            raise fail("points", f"expected [T={T}, K, 3] positions in metres, got shape {points.shape}")
        if not np.issubdtype(points.dtype, np.floating):
            raise fail("points", f"expected floating-point positions, got {points.dtype}")
        n_tracks = points.shape[1]
        finite = np.all(np.isfinite(points), axis=2)
        if visible is None:
            visible = finite
        else:
            visible = np.asarray(visible)
            if visible.shape != (T, n_tracks) or visible.dtype != np.bool_:
                raise fail(
                    "visible",
                    f"expected a bool array [T={T}, K={n_tracks}], got {visible.dtype} {visible.shape}",
                )
            bad = visible & ~finite
            if bad.any():
                f, k = np.argwhere(bad)[0]
                raise fail(
                    "points",
                    f"point {k} at frame {f} is NaN or inf but marked visible ({int(bad.sum())} such); "
                    "set visible[f, k] = False where a track was not seen",
                )
        if not visible.any() and not no_tracks:
            raise fail("visible", "every track is invisible at every frame: nothing to fit to")
        if particle is not None:
            particle = np.asarray(particle)
            if (
                particle.shape != (n_tracks,)
                or not np.issubdtype(particle.dtype, np.integer)
                or (particle.size and particle.min() < 0)
            ):
                raise fail(
                    "particle", f"expected K={n_tracks} particle indices >= 0 (int), got {particle.shape}"
                )
            particle = particle.astype(np.int64)
        controls = _check_controls(T, controls, fail)
        cloud, cloud_count = _check_cloud(T, cloud, cloud_count, fail)
        return cls(
            t=t.astype(float),
            points=np.where(visible[..., None], points, np.nan).astype(float),
            visible=visible.astype(bool),
            particle=particle,
            controls=controls,
            cloud=cloud,
            cloud_count=cloud_count,
            images=images,
            K=K,
            world_to_camera=world_to_camera,
            masks=masks,
            depth=depth,
            source=source,
        )

    @classmethod
    def load(cls, path: str | os.PathLike) -> Observations:
        """Read and validate an observation NPZ (``allow_pickle=False``).

        Raises:
            FileNotFoundError: no such file.
            ObservationError: arrays whose headers declare more than the available memory holds, unreadable
                file, missing ``t``/``points``, unknown arrays, bad shapes or values.
        """
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"observation file not found: {path}")
        data = read_npz(path, "observation", ObservationError)
        if "t" not in data:
            raise ObservationError(
                f"{path}: t: missing; an observation file needs t [T] and points [T, K, 3]"
            )
        if "points" not in data and "images" not in data:
            raise ObservationError(
                f"{path}: points: missing; an observation file needs t [T] and points [T, K, 3] (or camera "
                "images [C, T, H, W, 3] with K and world_to_camera)"
            )
        unknown = sorted(set(data) - set(_KNOWN))
        if unknown:
            raise ObservationError(
                f"{path}: {unknown[0]}: unknown array; the known ones are {', '.join(_KNOWN)}"
            )
        return cls.from_arrays(**data, source=str(path))

    def save(self, path: str | os.PathLike) -> Path:
        """Write the observations as an NPZ (atomically); optional arrays only when present (no ``points``
        when there are no tracks but images)."""
        arrays = {"t": self.t}
        if self.tracks or self.images is None:
            arrays.update(points=self.points, visible=self.visible)
        for k in ("particle", "controls", "cloud", "cloud_count", *IMAGE_ARRAYS):
            if getattr(self, k) is not None:
                arrays[k] = getattr(self, k)
        return atomic_savez(path, **arrays)

    # ------------------------------------------------------------------ scene checks
    @property
    def frames(self) -> int:
        """Number of observed frames T."""
        return int(self.t.shape[0])

    @property
    def tracks(self) -> int:
        """Number of tracks K (0 for images only)."""
        return int(self.points.shape[1])

    @property
    def cameras(self) -> int:
        """Number of cameras C (0 without images)."""
        return 0 if self.images is None else int(self.images.shape[0])

    def image(self, camera: int, frame: int) -> np.ndarray:
        """Camera ``camera``'s RGB image at ``frame`` as float64 [H, W, 3] in [0, 1]."""
        if self.images is None:
            raise ObservationError(f"{self.source}: images: this file has no camera images")
        return to_unit_float(self.images[camera, frame])

    def mask(self, camera: int, frame: int) -> np.ndarray | None:
        """Camera ``camera``'s object mask at ``frame`` as float64 [H, W] in [0, 1], or None."""
        return None if self.masks is None else to_unit_float(self.masks[camera, frame])

    def depth_m(self, camera: int, frame: int) -> np.ndarray:
        """Camera ``camera``'s depth at ``frame`` as float32 [H, W] metres along its optical axis, 0 where
        there is no reading (uint16 files are millimetres, converted here).

        Args:
            camera: Camera index, 0 … C − 1.
            frame: Frame index, 0 … T − 1.
        """
        if self.depth is None:
            raise ObservationError(f"{self.source}: depth: this file has no depth images")
        return depth_metres(self.depth[camera, frame])

    def check_times(self, frame_dt: float, what: str = "the scene") -> None:
        """Raise unless ``t[i] = i · frame_dt`` (every frame from t = 0, within 1e-6 of a frame).

        Args:
            frame_dt: the scene's frame duration [s].
            what: how to name the scene in the message.
        """
        expect = np.arange(self.frames) * frame_dt
        bad = np.flatnonzero(np.abs(self.t - expect) > 1e-6 * frame_dt + 1e-9)
        if bad.size:
            i = int(bad[0])
            raise ObservationError(
                f"{self.source}: t: t[{i}] = {self.t[i]:.6g} s but frame {i} of {what} is at "
                f"{expect[i]:.6g} s "
                f"(frame_dt {frame_dt:.6g} s); record one observation per frame from t = 0, or set the "
                "scene's frame_dt to the observations' interval"
            )

    def bind(self, x: np.ndarray) -> Observations:
        """Observations whose tracks are bound to particles.

        Tracks without ``particle`` are bound to the particle nearest to their first visible position; with
        ``particle`` given, the indices are checked against the particle count.

        Args:
            x: particle positions [m]: [N, 3] at t = 0, or [T', N, 3] per frame (a nominal simulation), in
                which case each track is compared with the particles at its first visible frame (frame 0
                positions are used beyond T').
        """
        x = np.asarray(x, dtype=float)
        xs = x[None] if x.ndim == 2 else x
        n = xs.shape[1]
        if self.tracks == 0:
            return replace(self, particle=np.zeros(0, dtype=np.int64))
        if self.particle is not None:
            if self.particle.max() >= n:
                raise ObservationError(
                    f"{self.source}: particle: index {int(self.particle.max())} but the scene has {n} "
                    "particles; bind the tracks to this scene's particles or drop the array"
                )
            return self
        seen = np.asarray(self.visible.any(axis=0))
        first = np.argmax(self.visible, axis=0)  # first visible frame of each track
        p = self.points[first, np.arange(self.tracks)]
        p = np.where(seen[:, None], p, xs[0].mean(axis=0))  # never-seen tracks: bound anywhere, never used
        at = np.where(first < xs.shape[0], first, 0)
        # [K, N] distances: binding runs once per fit, K and N are at most a few thousand.
        d2 = np.sum((xs[at] - p[:, None, :]) ** 2, axis=2)
        return replace(self, particle=np.argmin(d2, axis=1).astype(np.int64))

    def subset(self, frames: int) -> Observations:
        """The first ``frames`` frames (a training split)."""
        sl = slice(0, frames)

        def cut(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[sl]

        return replace(
            self,
            t=self.t[sl],
            points=self.points[sl],
            visible=self.visible[sl],
            controls=cut(self.controls),
            cloud=cut(self.cloud),
            cloud_count=cut(self.cloud_count),
            images=None if self.images is None else self.images[:, sl],
            masks=None if self.masks is None else self.masks[:, sl],
            depth=None if self.depth is None else self.depth[:, sl],
        )


def _real(array: str, a: np.ndarray, fail: Callable[[str, str], Exception]) -> np.ndarray:
    """``a`` as floats, or ``fail(array, ...)`` unless it holds real numbers (complex values would lose their
    imaginary part in astype(float); strings would raise NumPy's words, not the file's)."""
    a = np.asarray(a)
    if a.dtype.kind not in "fiu":
        raise fail(array, f"expected real numbers, got {a.dtype}")
    return a.astype(float)


def _check_controls(
    T: int, controls: np.ndarray | None, fail: Callable[[str, str], Exception]
) -> np.ndarray | None:
    """Control-point positions [T, C, 3] (m) as floats, checked for shape and finiteness; None passes."""
    if controls is not None:
        controls = _real("controls", controls, fail)
        if controls.ndim != 3 or controls.shape[0] != T or controls.shape[2] != 3:
            raise fail("controls", f"expected [T={T}, C, 3] positions in metres, got {controls.shape}")
        if not np.all(np.isfinite(controls)):
            raise fail("controls", "control-point positions must all be finite")
    return controls


def _check_cloud(
    T: int, cloud: np.ndarray | None, cloud_count: np.ndarray | None, fail: Callable[[str, str], Exception]
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Padded point clouds [T, P, 3] (m) and their counts [T], checked together (both or neither); the
    first ``cloud_count[t]`` points of each frame must be finite."""
    if (cloud is None) != (cloud_count is None):
        raise fail("cloud", "give both cloud [T, P, 3] and cloud_count [T], or neither")
    if cloud is not None:
        cloud = _real("cloud", cloud, fail)
        cloud_count = np.asarray(cloud_count)
        if cloud.ndim != 3 or cloud.shape[0] != T or cloud.shape[2] != 3:
            raise fail("cloud", f"expected padded clouds [T={T}, P, 3] in metres, got {cloud.shape}")
        if cloud_count.shape != (T,) or not np.issubdtype(cloud_count.dtype, np.integer):
            raise fail("cloud_count", f"expected [T={T}] integer counts, got {cloud_count.shape}")
        if cloud_count.min() < 0 or cloud_count.max() > cloud.shape[1]:
            raise fail("cloud_count", f"counts must lie in [0, P={cloud.shape[1]}]")
        used = np.arange(cloud.shape[1])[None, :] < cloud_count[:, None]
        if not np.all(np.isfinite(cloud[used])):
            raise fail("cloud", "the first cloud_count[t] points of each frame must be finite")
        cloud_count = cloud_count.astype(np.int64)
    return cloud, cloud_count


__all__ = ["ObservationError", "Observations"]
