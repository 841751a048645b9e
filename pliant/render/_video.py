"""MP4/GIF writing and trajectory-to-video rendering."""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol

import numpy as np

from ._camera import Camera
from ._renderer import Renderer, default_point_radius

__all__ = ["FPS_RANGE", "VideoError", "VideoWriter", "check_fps", "write_video", "render_video", "video"]

_VIDEO_EXTS = {".mp4", ".m4v", ".mov", ".mkv"}

#: Frame rates [1/s] a video may have: ffmpeg takes the rate as a rational with bounded terms.
FPS_RANGE = (0.01, 1000.0)


class VideoError(OSError):
    """The video could not be written (ffmpeg or Pillow failed); the message says why and what to do."""


def check_fps(fps: float) -> float:
    """``fps`` as a float if it lies in :data:`FPS_RANGE`, else a ValueError saying so.

    Call it before any work (simulation, rendering) so a bad rate fails at once.
    """
    try:
        value = float(fps)
    except (TypeError, ValueError):
        raise ValueError(f"fps must be a number of frames per second, got {fps!r}") from None
    if not FPS_RANGE[0] <= value <= FPS_RANGE[1]:
        raise ValueError(f"fps must be in [{FPS_RANGE[0]}, {FPS_RANGE[1]}] frames per second, got {fps}")
    return value


def _as_frame(frame: object) -> np.ndarray:
    """Converts a frame to contiguous uint8 RGB [H, W, 3] (floats are taken in [0, 1])."""
    arr = np.asarray(frame)
    if arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    if arr.ndim != 3 or arr.shape[2] not in (3, 4):
        raise ValueError(f"frame must have shape [H, W, 3] (or [H, W] / [H, W, 4]), got {arr.shape}")
    arr = arr[:, :, :3]
    if arr.dtype != np.uint8:
        if np.issubdtype(arr.dtype, np.floating):
            arr = np.clip(np.nan_to_num(arr), 0.0, 1.0) * 255.0 + 0.5
        arr = np.clip(arr, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(arr)


class VideoWriter:
    """Streaming video writer: H.264 MP4 (yuv420p, plays everywhere) or animated GIF.

    The format follows the file extension (``.mp4``/``.m4v``/``.mov``/``.mkv`` or ``.gif``). All
    frames must have the size of the first one; odd widths/heights are padded by one
    replicated row/column because yuv420p needs even dimensions. MP4 frames are streamed to
    ffmpeg; GIF frames are palette-quantised and kept in memory until ``close`` (Pillow merges
    identical consecutive GIF frames into one longer frame). Nothing is written if no frame
    was appended.

    Used as a context manager, the file is finalised on exit even when the block raises, so
    the frames written so far are kept.

    Args:
        path: Output file.
        fps: Frames per second (GIF stores delays in 1/100 s, so it is rounded there).
        crf: H.264 constant rate factor (0 = lossless, 18 = visually lossless, 51 = worst).

    Example:
        >>> with VideoWriter("out.mp4", fps=30) as vw:  # doctest: +SKIP
        ...     for img in frames:
        ...         vw.append_frame(img)
    """

    def __init__(self, path: str | os.PathLike, fps: float = 30, *, crf: int = 18) -> None:
        self.path = Path(path)
        self.fps = check_fps(fps)
        self.crf = int(crf)
        ext = self.path.suffix.lower()
        if ext == ".gif":
            self._kind = "gif"
        elif ext in _VIDEO_EXTS:
            self._kind = "mp4"
        else:
            raise ValueError(f"unsupported video extension {ext!r}; use .mp4 or .gif")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.frame_count = 0
        self._size: tuple[int, int] | None = None  # (H, W) of the input frames
        self._gen: Any = None
        self._gif_frames: list[Any] = []
        self._closed = False

    def append_frame(self, frame: np.ndarray) -> None:
        """Appends one RGB frame (uint8 [H, W, 3], or floats in [0, 1])."""
        if self._closed:
            raise RuntimeError("VideoWriter is closed")
        img = _as_frame(frame)
        if self._size is None:
            self._size = img.shape[:2]
            if self._kind == "mp4":
                self._open_ffmpeg()
        elif img.shape[:2] != self._size:
            raise ValueError(f"frame size {img.shape[:2]} differs from the first frame's {self._size}")
        if self._kind == "mp4":
            h, w = img.shape[:2]
            if h % 2 or w % 2:
                img = np.pad(img, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
            self._ffmpeg(self._gen.send, np.ascontiguousarray(img))
        else:
            from PIL import Image

            # Per-frame adaptive palette; 1 byte/pixel keeps long GIFs affordable in memory.
            self._gif_frames.append(Image.fromarray(img).quantize(colors=256))
        self.frame_count += 1

    def _ffmpeg(self, fn: Any, *args: Any, **kwargs: Any) -> Any:
        """Call into imageio-ffmpeg; its failures (no binary, a broken pipe, ffmpeg's own errors with its
        whole command line) become one :class:`VideoError` naming the file."""
        try:
            return fn(*args, **kwargs)
        except (ImportError, OSError, RuntimeError, StopIteration, ValueError) as exc:
            text = str(exc).strip().splitlines()
            why = text[-1] if text else type(exc).__name__
            raise VideoError(
                f"could not write the video {self.path}: ffmpeg failed ({why[:300]}); check that the folder "
                "is writable and has space, that imageio-ffmpeg is installed (pip install imageio-ffmpeg), "
                "or write a .gif instead"
            ) from None

    def _open_ffmpeg(self) -> None:
        import imageio_ffmpeg

        h, w = self._size  # type: ignore[misc]
        self._gen = self._ffmpeg(
            imageio_ffmpeg.write_frames,
            str(self.path),
            (w + w % 2, h + h % 2),
            fps=self.fps,
            codec="libx264",
            pix_fmt_in="rgb24",
            pix_fmt_out="yuv420p",
            quality=None,
            macro_block_size=2,  # we pad to even sizes ourselves: no rescaling by ffmpeg
            ffmpeg_log_level="error",
            output_params=["-crf", str(self.crf), "-preset", "medium", "-movflags", "+faststart"],
        )
        self._ffmpeg(self._gen.send, None)  # start the generator (launches ffmpeg)

    def close(self) -> None:
        """Finalises the file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if self._kind == "mp4":
            if self._gen is not None:
                gen, self._gen = self._gen, None
                self._ffmpeg(gen.close)
        elif self._gif_frames:
            first, *rest = self._gif_frames
            self._gif_frames = []
            try:
                first.save(
                    self.path,
                    save_all=True,
                    append_images=rest,
                    duration=max(int(round(1000.0 / self.fps)), 10),
                    loop=0,
                )
            except (OSError, ValueError) as exc:
                raise VideoError(f"could not write the GIF {self.path}: {exc}") from None

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def write_video(frames: Iterable[np.ndarray], path: str | os.PathLike, fps: float = 30, **kw: Any) -> Path:
    """Writes frames to an MP4 (H.264, yuv420p) or GIF file, chosen by extension.

    Args:
        frames: RGB frames, uint8 [H, W, 3] (or floats in [0, 1]), all the same size.
        path: Output path (``.mp4`` or ``.gif``).
        fps: Frames per second.
        **kw: Passed to :class:`VideoWriter` (e.g. ``crf``).

    Returns:
        The output path.
    """
    with VideoWriter(path, fps, **kw) as vw:
        for f in frames:
            vw.append_frame(f)
    if vw.frame_count == 0:
        raise ValueError("write_video got no frames")
    return vw.path


def _auto_ground(x: np.ndarray) -> float:
    """Ground height for ``ground="auto"``: y = 0 unless the object goes clearly below it."""
    pts = x.reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        return 0.0
    lo = float(pts[:, 1].min())
    extent = max(float(np.ptp(pts, axis=0).max()), 1e-6)
    if lo >= -0.01 * extent:
        return 0.0
    return lo - 0.05 * extent


def render_video(
    x: np.ndarray,
    path: str | os.PathLike,
    *,
    faces: np.ndarray | None = None,
    fps: float = 30,
    camera: Camera | None = None,
    progress: bool = True,
    width: int = 640,
    height: int = 480,
    colors: np.ndarray | Sequence[float] | None = None,
    point_radius: float | np.ndarray | None = None,
    point_radius_px: float | None = None,
    ground: bool | float | str | None = "auto",
    frame_indices: Sequence[int] | np.ndarray | None = None,
    **renderer_options: Any,
) -> Path:
    """Renders a trajectory to an MP4 or GIF.

    One camera is fitted to all frames so the object stays in view, and one ground height and
    particle radius are used throughout, so the only thing that moves is the object.

    Args:
        x: Positions [T, N, 3] in metres (a single frame [N, 3] is accepted too).
        path: Output ``.mp4`` or ``.gif``.
        faces: Triangles [F, 3] (None: particles).
        fps: Frames per second of the output.
        camera: Camera to use; default ``Camera.fit(x, width=width, height=height)``.
        progress: Show a tqdm progress bar.
        width: Image width in pixels (ignored when ``camera`` is given).
        height: Image height in pixels (ignored when ``camera`` is given).
        colors: RGB triple, per-vertex colours [N, 3], or per-frame colours [T, N, 3].
        point_radius: Particle radius in metres (default: from frame 0's particle spacing).
        point_radius_px: Particle radius in pixels (used if ``point_radius`` is None).
        ground: ``"auto"`` (y = 0, or just below the lowest point if the object goes below
            0), a height, ``True`` (y = 0) or ``False``/``None`` (no ground).
        frame_indices: Frames of ``x`` to render, in order (repeats allowed); default all.
        **renderer_options: Passed to :class:`Renderer` (``background``, ``light_dir``,
            ``shading``, ``shadows``, ``edges``, ``supersample``, ``color``, ...).

    Returns:
        The output path.
    """
    fps = check_fps(fps)  # before any rendering
    if hasattr(x, "numpy") and not isinstance(x, np.ndarray):
        x = x.numpy()
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 2:
        x = x[None]
    if x.ndim != 3 or x.shape[2] != 3:
        raise ValueError(f"x must have shape [T, N, 3], got {x.shape}")
    idx = np.arange(len(x)) if frame_indices is None else np.asarray(frame_indices, dtype=np.int64)
    if idx.size == 0:
        raise ValueError("no frames to render")
    used = x[np.unique(idx)]
    if camera is None:
        camera = Camera.fit(used, width=width, height=height)
    if isinstance(ground, str):
        if ground != "auto":
            raise ValueError(f"ground must be 'auto', a bool, a float or None, got {ground!r}")
        ground = _auto_ground(used)
    if faces is None and point_radius is None and point_radius_px is None:
        r = default_point_radius(x[idx[0]])
        point_radius = r if r > 0.0 else 0.01 * camera.distance
    col = None if colors is None else np.asarray(colors)
    renderer = Renderer(camera, ground=ground, **renderer_options)

    from tqdm.auto import tqdm

    last_i, last_img = -1, None
    with VideoWriter(path, fps) as vw:
        for i in tqdm(idx, desc="render", unit="frame", disable=not progress):
            if i != last_i:  # repeated indices (real-time resampling) reuse the frame
                last_img = renderer.render(
                    x[i],
                    faces,
                    colors=col[i] if col is not None and col.ndim == 3 else col,  # per-frame colours
                    point_radius=point_radius,
                    point_radius_px=point_radius_px,
                )
                last_i = int(i)
            assert last_img is not None  # the first index always renders
            vw.append_frame(last_img)
    return vw.path


def link_beads(x: np.ndarray, segments: np.ndarray, per_link: int) -> np.ndarray:
    """Points spaced evenly inside each link (``per_link`` per segment, ends excluded), so that particles
    drawn as spheres together with these beads show a rope as a continuous line rather than loose dots.

    Args:
        x: Positions [T, N, 3] (or [N, 3]) in metres.
        segments: Particle-index pairs [S, 2] (a rope's links).
        per_link: Beads per link (>= 0).

    Returns:
        Bead positions [T, S·per_link, 3] (or [S·per_link, 3]).
    """
    seg = np.asarray(segments, dtype=np.int64).reshape(-1, 2)
    s = (np.arange(1, per_link + 1) / (per_link + 1))[None, :, None]  # fractions along each link
    a, b = x[..., seg[:, 0], None, :], x[..., seg[:, 1], None, :]
    beads = a + s * (b - a)  # [..., S, per_link, 3]
    return beads.reshape(*x.shape[:-2], len(seg) * per_link, 3)


def realtime_indices(t: np.ndarray, fps: float, speed: float = 1.0) -> np.ndarray:
    """Frame indices that play a trajectory sampled at times ``t`` at ``speed`` x real time.

    Args:
        t: Sample times [T] in seconds, non-decreasing.
        fps: Output frames per second.
        speed: Playback speed factor (2.0 = twice as fast as real time).

    Returns:
        Indices [K] into ``t`` (nearest sample at each output time; repeats when ``t`` is
        sampled more coarsely than the video).
    """
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    if len(t) < 2 or not np.all(np.isfinite(t)) or t[-1] <= t[0] or np.any(np.diff(t) < 0):
        return np.arange(len(t))
    step = speed / fps
    times = t[0] + step * np.arange(int(np.floor((t[-1] - t[0]) / step + 1e-9)) + 1)
    hi = np.clip(np.searchsorted(t, times), 1, len(t) - 1)
    lo = hi - 1
    return np.where(times - t[lo] <= t[hi] - times, lo, hi)


class TrajectoryLike(Protocol):
    """What :func:`video` reads: ``x`` [T, N, 3] [m]; ``faces``, ``tets`` and ``t`` when present
    (a :class:`pliant.io.Trajectory` has them all)."""

    @property
    def x(self) -> np.ndarray: ...


def video(
    traj: TrajectoryLike,
    path: str | os.PathLike,
    *,
    fps: float = 30,
    realtime: bool = True,
    speed: float = 1.0,
    **kw: Any,
) -> Path:
    """Renders any trajectory-like object with ``.x`` [T, N, 3], ``.faces`` and ``.t`` [T].

    Args:
        traj: Object with attributes ``x`` (positions [T, N, 3] in metres), optionally
            ``faces`` ([F, 3] or None), ``tets`` ([E, 4]; its boundary is drawn when there are
            no faces) and ``t`` (times [T] in seconds). Without faces or tets: particles.
        path: Output ``.mp4`` or ``.gif``.
        fps: Output frames per second.
        realtime: If ``traj.t`` is available, pick frames so playback runs at ``speed`` x real
            time; otherwise every stored frame becomes one video frame.
        speed: Playback speed factor for ``realtime``.
        **kw: Passed to :func:`render_video` (``camera``, ``colors``, ``ground``, ...).

    Returns:
        The output path.
    """
    x = traj.x
    faces = kw.pop("faces", getattr(traj, "faces", None))
    tets = getattr(traj, "tets", None)
    if faces is None and tets is not None:
        from ..geometry import surface_from_tets  # a volumetric mesh is drawn by its boundary

        faces = surface_from_tets(tets)
    t = getattr(traj, "t", None)
    if realtime and t is not None and "frame_indices" not in kw:
        kw["frame_indices"] = realtime_indices(np.asarray(t), fps, speed)
    return render_video(x, path, faces=faces, fps=fps, **kw)
