"""Synthetic camera videos of a simulation (``pliant observe --cameras``): the object drawn as Gaussians bound
to its particles (the scene's ``[gaussians]`` section, else generated deterministically from its surface:
:func:`pliant.gaussians._scene.scene_gaussians`, as the photometric fit does), rendered by pliant's rasteriser
from a ring of cameras. Synthetic data for tutorials, tests and known-truth studies, never a substitute for
footage."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from ..io import Observations, available_memory

if TYPE_CHECKING:
    from ..scene import Scene


def observe_images(
    scene: Scene,
    *,
    frames: int | None = None,
    cameras: int = 3,
    image_size: tuple[int, int] = (96, 72),
    noise: float = 0.0,
    masks: bool = False,
    depth: bool = False,
    uint8: bool = False,
    per_triangle: int = 1,
    seed: int = 0,
    tracks: Observations | None = None,
    progress: bool = False,
) -> Observations:
    """Simulate ``scene`` and render its object from ``cameras`` cameras at every frame.

    Args:
        scene: A built scene (``pl.scene.build_scene``).
        frames: Observed frames including frame 0 (default: the scene's ``frames`` + 1).
        cameras: Number of cameras, evenly spaced around the motion's bounding sphere
            (:func:`pliant.gaussians._surface.ring_cameras`), each seeing all of it.
        image_size: (width, height) [px].
        noise: Standard deviation of Gaussian pixel noise (in [0, 1] units; the images are clipped to [0, 1]).
        masks: Also write ``masks``: the rendered alpha (a soft object mask in [0, 1]).
        depth: Also write ``depth`` [m]: the splats' expected depth along each camera's axis where the
            rendered alpha exceeds one half, 0 elsewhere (no reading), as an RGB-D camera reports it.
        uint8: Store 8-bit images (quantised) instead of float32.
        per_triangle: Gaussians per surface triangle (1 or 3) of generated splats; ``pliant fit`` renders 1
            (3 here gives videos drawn with other splats than the fit's). A scene with a ``[gaussians]``
            section is drawn with the section's splats and background (``per_triangle`` must be 1).
        seed: Seed of the pixel noise.
        tracks: Track observations of the same scene and frames to keep in the file (``points``,
            ``visible``, ``particle``, ``controls``, ``cloud``), or None for images only.
        progress: Show the simulation's progress bar.

    Returns:
        Observations with ``images`` [C, T, H, W, 3], ``K``, ``world_to_camera`` (and ``masks``).

    Raises:
        ValueError: a bad size, noise or frame count, or a ``[gaussians]`` section that cannot be built
            (:class:`pliant.gaussians._scene.SplatSceneError`, naming the scene file and the field).
    """
    from ..gaussians import ring_cameras, scene_gaussians

    width, height = (int(v) for v in image_size)
    if width < 1 or height < 1:
        raise ValueError(f"--image-size: expected a positive WxH, got {width}x{height}")
    if not noise >= 0.0 or not np.isfinite(noise):
        raise ValueError(f"--image-noise: expected a standard deviation >= 0, got {noise}")
    frames = scene.frames + 1 if frames is None else frames
    if frames < 2:
        raise ValueError(f"--frames: observations need at least 2 frames, got {frames}")
    # Colour, alpha and depth in float32, and about as much again for the noise and the file: before
    # np.empty of an absurd size raises MemoryError (a traceback) or, below the memory, thrashes.
    need, have = 2.0 * 4.0 * 5.0 * cameras * frames * float(height) * float(width), available_memory()
    if have is not None and need > have:
        raise ValueError(
            f"--image-size: {cameras} camera videos of {frames} frames at {width}x{height} px need about "
            f"{need / 2**30:.3g} GiB and {have / 2**30:.3g} GiB is available; use fewer cameras or frames, "
            "or a smaller --image-size"
        )
    splats = scene_gaussians(scene, per_triangle=per_triangle)  # before simulating: fail early
    x = scene.simulator().run(frames - 1, progress=progress).x
    m = scene.model
    cams = ring_cameras(x[:, splats.lo : splats.hi], cameras, width=width, height=height)
    images = np.empty((cameras, frames, height, width, 3), dtype=np.float32)
    alpha = np.empty((cameras, frames, height, width), dtype=np.float32)
    z = np.zeros((cameras, frames, height, width), dtype=np.float32)
    for f in range(frames):
        q: wp.array = wp.array(np.ascontiguousarray(x[f]), dtype=m.vec3, device=m.device)
        for c, cam in enumerate(cams):
            colour, a, d = splats.render(q, cam)
            images[c, f] = colour.numpy()
            alpha[c, f] = a.numpy()
            if depth:
                z[c, f] = np.where(alpha[c, f] > 0.5, d.numpy(), 0.0)
    if noise > 0:
        rng = np.random.default_rng(seed)
        images = np.clip(images + rng.normal(scale=noise, size=images.shape), 0.0, 1.0).astype(np.float32)
    if uint8:
        images = np.round(np.clip(images, 0.0, 1.0) * 255.0).astype(np.uint8)
    else:
        images = np.clip(images, 0.0, 1.0)  # float32 rounding can step a hair outside [0, 1]
    kw: dict[str, Any] = {}
    if tracks is not None:
        kw = {"points": tracks.points, "visible": tracks.visible, "particle": tracks.particle}
        for k in ("controls", "cloud", "cloud_count"):
            if getattr(tracks, k) is not None:
                kw[k] = getattr(tracks, k)
    elif scene.control_points:
        from ._observe import _controls

        kw["controls"] = _controls(scene, frames)
    return Observations.from_arrays(
        t=np.arange(frames) * scene.frame_dt,
        images=images,
        K=np.stack([c.K for c in cams]),
        world_to_camera=np.stack([c.world_to_camera for c in cams]),
        masks=np.clip(alpha, 0.0, 1.0) if masks else None,
        depth=z if depth else None,
        source="<observe>",
        **kw,
    )


__all__ = ["observe_images"]
