"""How well a twin predicts: its rollout against every frame's pictures, on the training and the held-out
frames.

- **Chamfer** [mm]: for each observed point of a frame's cloud, the distance to the nearest simulated
  particle, averaged (one-sided, observed → twin, as PhysTwin's future-prediction metric), beside the same
  figure for a twin that does not move (its frame-0 particles held still): a twin that predicts must beat it.
- **IoU**: the twin's splats rendered into each camera (alpha > 0.5) against the object's mask.
- **PSNR** [dB]: the rendered colour over black against the image times its mask (the object's pixels;
  the footage's background is not the twin's to predict).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial import cKDTree

from ..io import Observations

if TYPE_CHECKING:
    from ..scene import Scene, SceneConfig

#: Fraction of the training frames (the last ones) on which the model choice is validated.
VALIDATION = 0.2


def chamfer_per_frame(x: np.ndarray, clouds: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Mean distance [m] from each frame's observed points to the nearest simulated particle.

    Args:
        x: [T, N, 3] simulated positions [m].
        clouds: [T', P, 3] padded observed clouds [m].
        counts: [T'] valid points per frame.

    Returns:
        [min(T, T')] distances (NaN for a frame with no observed point).
    """
    T = min(len(x), len(clouds))
    out = np.full(T, np.nan)
    for f in range(T):  # one KD-tree per frame, every observed point queried at once
        n = int(counts[f])
        if n:
            out[f] = float(cKDTree(x[f]).query(clouds[f, :n])[0].mean())
    return out


def validation_loss(cfg: SceneConfig, obs: Observations, n_train: int) -> float:
    """Mean Chamfer distance [m] of the scene's open-loop rollout on the last :data:`VALIDATION` of the
    training frames (the model choice: a prediction, never seen as a fitted frame)."""
    from ..scene import build_scene
    from ..sim import DivergenceError

    assert obs.cloud is not None and obs.cloud_count is not None
    lo = max(1, n_train - max(1, int(round(VALIDATION * n_train))))
    try:
        x = build_scene(cfg).simulator().run(n_train - 1, progress=False).x
    except DivergenceError:
        return math.inf
    return float(np.nanmean(chamfer_per_frame(x, obs.cloud, obs.cloud_count)[lo:n_train]))


def _split(v: np.ndarray, n_train: int, scale: float = 1.0) -> dict[str, float]:
    train, test = v[1:n_train], v[n_train:]
    return {
        "train": float(np.nanmean(train)) * scale if np.isfinite(train).any() else math.nan,
        "test": float(np.nanmean(test)) * scale if np.isfinite(test).any() else math.nan,
    }


def render_scores(
    scene: Scene, x: np.ndarray, obs: Observations, frames: range | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Mask IoU and PSNR [dB] of the scene's splats at positions ``x`` [T, N, 3] in every camera of ``obs``.

    Returns:
        (iou [C, T], psnr [C, T]); NaN where a frame was not rendered.
    """
    import warp as wp

    from ..gaussians import Camera, iou, psnr, scene_gaussians

    assert obs.K is not None and obs.world_to_camera is not None and obs.images is not None
    splats = scene_gaussians(scene)
    m = scene.model
    H, W = obs.images.shape[2:4]
    cams = [Camera(obs.K[c], obs.world_to_camera[c], W, H) for c in range(obs.cameras)]
    T = min(len(x), obs.frames)
    frames = range(T) if frames is None else frames
    ious = np.full((len(cams), T), np.nan)
    psnrs = np.full((len(cams), T), np.nan)
    section = getattr(scene.config, "gaussians", None)  # a registered section: not a SceneConfig field
    bg = np.asarray(section.background if section is not None else (1.0, 1.0, 1.0), dtype=np.float64)
    for f in frames:
        q: wp.array = wp.array(np.ascontiguousarray(x[f]), dtype=m.vec3, device=m.device)
        for c, cam in enumerate(cams):
            colour, alpha, _ = splats.render(q, cam)
            mask = obs.mask(c, f)
            a = alpha.numpy().astype(np.float64)
            if mask is not None:
                ious[c, f] = iou(a, mask)
                # The object's pixels only, as the splat stage scores them: the observed image times its mask
                # against the render over black (the footage's background is not the twin's to predict).
                over_black = colour.numpy() - (1.0 - a)[..., None] * bg
                psnrs[c, f] = psnr(over_black, obs.image(c, f) * mask[..., None])
            else:
                psnrs[c, f] = psnr(colour.numpy(), obs.image(c, f))
    return ious, psnrs


def evaluate(
    cfg: SceneConfig, obs: Observations, clouds: np.ndarray, counts: np.ndarray, n_train: int
) -> dict[str, Any]:
    """The twin's rollout over every observed frame, scored on the training and the held-out frames.

    Args:
        cfg: The twin's scene.
        obs: The observations (images, masks).
        clouds: [T, P, 3] observed clouds [m]; counts: [T] their sizes.
        counts: [T] valid points per frame.
        n_train: Frames 0 … n_train − 1 trained the fit.

    Returns:
        ``chamfer_mm`` and ``chamfer_still_mm`` (train / test), ``iou``, ``psnr_db`` (train / test), the
        per-frame curves (``per_frame``), and the rollout's positions' file.
    """
    from ..scene import build_scene

    scene = build_scene(cfg)
    x = scene.simulator().run(obs.frames - 1, progress=False).x
    cd = chamfer_per_frame(x, clouds, counts)
    still = chamfer_per_frame(np.broadcast_to(x[:1], x.shape), clouds, counts)
    ious, psnrs = render_scores(scene, x, obs)
    return {
        "chamfer_mm": _split(cd, n_train, 1e3),
        "chamfer_still_mm": _split(still, n_train, 1e3),
        "iou": _split(np.nanmean(ious, axis=0), n_train),
        "psnr_db": _split(np.nanmean(psnrs, axis=0), n_train),
        "per_frame": {
            "chamfer_mm": (cd * 1e3).tolist(),
            "chamfer_still_mm": (still * 1e3).tolist(),
            "iou": np.nanmean(ious, axis=0).tolist(),
            "psnr_db": np.nanmean(psnrs, axis=0).tolist(),
        },
        "positions": x,
    }


__all__ = ["VALIDATION", "chamfer_per_frame", "evaluate", "render_scores", "validation_loss"]
