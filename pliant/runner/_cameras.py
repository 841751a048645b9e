"""Rendering a run's splats from a camera file's cameras (``pliant run --cameras``), one video per camera,
and scoring the renderings against the file's images and masks: PSNR [dB] (:func:`pliant.gaussians.psnr`)
and mask IoU (:func:`pliant.gaussians.iou`, rendered alpha > 0.5 against mask > 0.5)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..gaussians import Camera, SplatSession
    from ..io import CameraFile


@dataclass
class CameraScore:
    """One camera of a camera file, rendered over a run.

    Attributes:
        camera: its index in the file.
        video: the video written (``camera_<c>.mp4``).
        frames: frames compared with the file's images (0 when it has none).
        psnr: PSNR [dB] of the renderings against the images over those frames (of their mean squared
            error, all pixels pooled; inf when all are identical), or None without images.
        iou: mean mask IoU over those frames (rendered alpha > 0.5 against mask > 0.5), or None without
            masks.
    """

    camera: int
    video: Path
    frames: int = 0
    psnr: float | None = None
    iou: float | None = None

    def summary(self) -> str:
        """One line: the camera, its scores (or that there were no images to score against)."""
        if self.psnr is None:
            return f"camera {self.camera}: rendered (no images to compare)"
        line = f"camera {self.camera}: PSNR {self.psnr:.2f} dB"
        line += f", mask IoU {self.iou:.3f}" if self.iou is not None else " (no masks: no IoU)"
        return line + f" over {self.frames} frames"


def compared_frames(cams: CameraFile, times: np.ndarray) -> tuple[int, list[str]]:
    """How many leading frames the run (at ``times`` [s], frame 0 first) and the file's images share, and
    warnings: a frame-count mismatch (the common prefix is used), times that differ from the file's ``t``."""
    if cams.images is None:
        return 0, []
    n = min(cams.frames, len(times))
    notes = []
    if cams.frames != len(times):
        notes.append(
            f"{cams.path}: images has {cams.frames} frames per camera, the run {len(times)} (frame 0 "
            f"included); compared the first {n}"
        )
    if cams.t is not None and n:
        gap = float(np.max(np.abs(cams.t[:n] - np.asarray(times[:n], np.float64))))
        if gap > 1e-6 * max(1.0, float(np.max(np.abs(cams.t[:n])))):
            notes.append(
                f"{cams.path}: t differs from the run's frame times by up to {gap:.4g} s; frames are matched "
                "by index"
            )
    return n, notes


def _frames(
    session: SplatSession,
    x: np.ndarray,
    cam: Camera,
    cams: CameraFile,
    c: int,
    n: int,
    psnrs: list[float],
    ious: list[float],
) -> Iterator[np.ndarray]:
    """Camera ``c``'s RGB frames of the run ``x``, appending the first ``n`` frames' PSNR and IoU."""
    from ..gaussians import iou, psnr
    from ..io import to_unit_float

    for i, xf in enumerate(x):
        out = session.render(xf, cam)
        rgb = out.colour.numpy()
        if cams.images is not None and i < n:
            psnrs.append(psnr(rgb, to_unit_float(cams.images[c, i])))
            if cams.masks is not None:
                ious.append(iou(out.alpha.numpy(), to_unit_float(cams.masks[c, i])))
        yield rgb


def render_cameras(
    session: SplatSession,
    x: np.ndarray,
    cams: CameraFile,
    videos: list[Path],
    fps: float,
    *,
    compare: int | None = None,
    progress: bool = False,
) -> list[CameraScore]:
    """Render the run ``x`` ([T, N, 3], metres) from every camera of ``cams`` into ``videos`` (one per
    camera), scoring the first ``compare`` frames against the file's images and masks.

    Args:
        session: the scene's splats (:class:`pliant.gaussians.SplatSession`).
        x: particle positions of every frame, frame 0 first.
        cams: the validated camera file.
        videos: one output path per camera.
        fps: the videos' frame rate [1/s].
        compare: frames to score (default: all that both have); 0 scores none.
        progress: a progress bar per camera.

    Returns:
        One :class:`CameraScore` per camera.
    """
    from ..gaussians import Camera
    from ..render import write_video

    n = min(cams.frames, len(x)) if compare is None else compare
    scores = []
    for c in range(cams.count):
        cam = Camera(cams.K[c], cams.world_to_camera[c], cams.width, cams.height)
        score = CameraScore(c, videos[c], frames=n if cams.images is not None else 0)
        psnrs: list[float] = []
        ious: list[float] = []

        it = _frames(session, x, cam, cams, c, n, psnrs, ious)
        if progress:
            from tqdm.auto import tqdm

            it = tqdm(it, total=len(x), unit="frame", desc=f"rendering camera {c}", leave=False)
        write_video(it, videos[c], fps=fps)
        if psnrs:
            # The PSNR of the frames' mean squared error (pixels pooled): inf only when every frame is
            # identical, where a mean of per-frame PSNRs would be inf as soon as one frame is.
            mse = float(np.mean(10.0 ** (-np.asarray(psnrs) / 10.0)))
            score.psnr = float("inf") if mse == 0.0 else -10.0 * float(np.log10(mse))
        if ious:
            score.iou = float(np.mean(ious))
        scores.append(score)
    return scores
