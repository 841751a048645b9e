"""The memory of an image fit, estimated before it starts (issue 41): printed in the fit's plan, and the fit
refused above the available memory unless ``--force``.

With s bytes per scalar (4 in float32, 8 in float64), C cameras, T frames of H × W pixels (P = H·W), G
Gaussians, N particles, S substeps per frame and F = n_train − 1 training frames:

- targets: every observed image (and mask) becomes a device array once a loss reads it, and the fit reads
  them all (the held-out PSNR, fit.json's per-frame losses): C·T·P·(3 + m)·s, m = 1 with masks;
- one view of the rasteriser (pliant/gaussians/_render.py): per pixel the colour, alpha and depth outputs
  and the compositing's T, C, D (9 scalars) and its last index (4 bytes); per Gaussian the projected mean,
  conic, depth, opacity and colour (10 scalars), the tile rectangle and count (20 bytes) and the tile sort's
  keys and values (2 × 12 bytes per tile a Gaussian touches, TILES_PER_GAUSSIAN);
- the gradient stage's tape (image-gradient refinement): the whole training rollout on one ``wp.Tape``, so
  every view's buffers are kept, with adjoints of the 5 output scalars per pixel and the 10 per Gaussian, for
  the C·F views, and every substep's state (positions, velocities, forces: 9 scalars per particle) and its
  adjoint, for the F·S substeps.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from ..io import available_memory
from ..scene import format_bytes

if TYPE_CHECKING:
    from ._problem import Problem

#: Tiles (16 × 16 px) a projected Gaussian touches, for the tile sort's buffers: a splat a few pixels wide
#: straddles up to 4 tiles; wider ones are few in the generated surface splats.
TILES_PER_GAUSSIAN = 4


@dataclass(frozen=True)
class ImageFitMemory:
    """What an image fit allocates beyond the scene's model [bytes].

    Attributes:
        targets: the observed images and masks as device arrays, all cameras and frames.
        per_view: one render's buffers (a forward evaluation holds one at a time).
        tape: the image-gradient stage's tape (every training view and substep); 0 without that stage.
    """

    targets: float
    per_view: float
    tape: float

    @property
    def total(self) -> float:
        """Targets, one view and the tape [bytes]."""
        return self.targets + self.per_view + self.tape

    def describe(self) -> str:
        """One line: ``about 1.2 GB (targets 800 MB, rasteriser 2 MB per view, gradient tape 400 MB)``."""
        tape = f", gradient tape {format_bytes(self.tape)}" if self.tape else ""
        return (
            f"about {format_bytes(self.total)} (targets {format_bytes(self.targets)}, rasteriser "
            f"{format_bytes(self.per_view)} per view{tape})"
        )


def image_fit_memory(
    *,
    cameras: int,
    frames: int,
    height: int,
    width: int,
    masks: bool,
    scalar_bytes: int,
    gaussians: int,
    particles: int,
    train_frames: int,
    substeps: int,
    gradient: bool,
) -> ImageFitMemory:
    """The memory formula of the module docstring.

    Args:
        cameras: C, camera videos.
        frames: T, observed frames.
        height: H [px].
        width: W [px].
        masks: whether the observations carry masks.
        scalar_bytes: s, 4 (float32) or 8 (float64).
        gaussians: G, Gaussians rendered.
        particles: N, particles simulated.
        train_frames: F, training frames with a loss (n_train − 1).
        substeps: S, solver substeps per frame.
        gradient: whether the image-gradient stage runs (the tape).

    Returns:
        The :class:`ImageFitMemory` [bytes].
    """
    s = float(scalar_bytes)
    pixels = float(height) * float(width)
    targets = cameras * float(frames) * pixels * (3 + int(masks)) * s
    per_view = pixels * (9 * s + 4) + gaussians * (10 * s + 20 + 24 * TILES_PER_GAUSSIAN)
    tape = 0.0
    if gradient:
        views = float(cameras) * train_frames
        tape = views * (per_view + pixels * 5 * s + gaussians * 10 * s)
        tape += float(train_frames) * substeps * particles * 18 * s
    return ImageFitMemory(targets, per_view, tape)


def problem_memory(problem: Problem, gradient: bool) -> ImageFitMemory | None:
    """:func:`image_fit_memory` of a photometric ``problem`` (None for a track fit), ``gradient``: whether
    its image-gradient stage will run."""
    obs = problem.obs
    if obs.images is None or not getattr(problem, "photometric", False):
        return None
    C, T, H, W = (int(n) for n in obs.images.shape[:4])
    return image_fit_memory(
        cameras=C,
        frames=T,
        height=H,
        width=W,
        masks=obs.masks is not None,
        scalar_bytes=8 if getattr(problem, "dtype_name", "float32") == "float64" else 4,
        gaussians=int(problem.gaussians.count),  # type: ignore[attr-defined]
        particles=int(problem.x0.shape[0]),
        train_frames=max(problem.n_train - 1, 0),
        substeps=int(problem.cfg.scene.substeps),
        gradient=gradient,
    )


def device_memory(device: str) -> float | None:
    """Memory free for arrays on Warp ``device`` [bytes]: a CUDA device's free memory, else the host's
    available memory (:func:`pliant.io.available_memory`, ``PLIANT_MEMORY_GB`` if set); None if unknown."""
    if device.startswith("cuda"):
        try:
            import warp as wp

            return float(wp.get_device(device).free_memory)
        except Exception:  # noqa: BLE001 - no driver, an old Warp: say nothing rather than guess
            return None
    return available_memory()


def memory_problem(mem: ImageFitMemory, available: float | None) -> str | None:
    """Why an image fit of ``mem`` cannot run in ``available`` bytes (None when it fits or that is unknown):
    one line with the estimate and the advice."""
    if available is None or mem.total <= available:
        return None
    return (
        f"this image fit needs {mem.describe()} and {format_bytes(available)} is available; use fewer "
        "frames (a shorter observation file, or a smaller --train-fraction), fewer cameras or a lower image "
        "resolution, or pass --force to go on"
    )


__all__ = [
    "ImageFitMemory",
    "TILES_PER_GAUSSIAN",
    "device_memory",
    "image_fit_memory",
    "memory_problem",
    "problem_memory",
]
