"""Training of a splat set against calibrated pictures, for :mod:`pliant.gaussians._init`: the inputs'
checks, the training views (observed object pixels over a random background), the scores (PSNR, mask IoU)
and the Adam loop with a step hook."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
import warp as wp

from .._warp import np_dtype, scalar_type, vec3_type
from ._appearance import _mean_psnr
from ._camera import Camera
from ._gaussians import Gaussians
from ._optim import Adam, photometric_loss, psnr
from ._render import render


@wp.kernel
def _clamp_kernel(a_io: wp.array(dtype=Any), lo: Any, hi: Any):
    i = wp.tid()
    a_io[i] = wp.clamp(a_io[i], lo, hi)


class _View:
    """One training view: its camera, the observed object pixels (image × mask), the background weight
    (1 − mask) and the mask, as NumPy and on the device."""

    def __init__(self, cam: Camera, image: np.ndarray, mask: np.ndarray, dtype: str, device: str) -> None:
        self.cam = cam
        self.obj = image * mask[..., None]
        self.empty = 1.0 - mask
        self.mask = mask
        self.v3 = vec3_type(dtype)
        self.nd = np_dtype(dtype)
        self.device = device
        self.mask_wp: wp.array = wp.array(mask.astype(self.nd), dtype=scalar_type(dtype), device=device)

    def target(self, background: np.ndarray) -> wp.array:
        """The observed image with its background pixels replaced by ``background`` (RGB)."""
        t = self.obj + self.empty[..., None] * background
        return wp.array(t.astype(self.nd), dtype=self.v3, device=self.device)


def _check_inputs(
    points: npt.ArrayLike,
    cameras: Sequence[Camera],
    images: Sequence[Any],
    masks: Sequence[Any],
    radius: float,
) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
    """Validated float64 points, images [H, W, 3] in [0, 1] (uint8 scaled) and masks [H, W] in [0, 1]."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise ValueError(f"splats_from_particles: points must have shape [N, 3] with N > 0, got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("splats_from_particles: points hold NaN or inf; drop those rows")
    if not (isinstance(radius, int | float) and radius > 0.0 and math.isfinite(radius)):
        raise ValueError(f"splats_from_particles: radius must be a positive length [m], got {radius!r}")
    if not len(cameras) or len(images) != len(cameras) or len(masks) != len(cameras):
        raise ValueError(
            f"splats_from_particles: {len(cameras)} cameras, {len(images)} images and {len(masks)} masks; "
            "give one image and one mask per camera (at least one camera)"
        )
    imgs, mks = [], []
    for c, cam in enumerate(cameras):
        if not isinstance(cam, Camera):
            raise TypeError(f"splats_from_particles: cameras[{c}] must be a pliant.gaussians.Camera")
        raw = np.asarray(images[c])
        img = cam.check_image(raw / 255.0 if raw.dtype == np.uint8 else raw, f"images[{c}]")
        if img.ndim != 3:
            raise ValueError(f"splats_from_particles: images[{c}] must have shape [H, W, 3], got {img.shape}")
        m = cam.check_image(np.asarray(masks[c], dtype=np.float64), f"masks[{c}]")
        if m.ndim != 2:
            raise ValueError(f"splats_from_particles: masks[{c}] must have shape [H, W], got {m.shape}")
        if not np.any(m > 0.5):
            raise ValueError(f"splats_from_particles: masks[{c}] is empty; drop camera {c} or fix its mask")
        imgs.append(np.clip(img, 0.0, 1.0))
        mks.append(np.clip(m, 0.0, 1.0))
    return pts, imgs, mks


def _scores(g: Gaussians, views: Sequence[_View]) -> tuple[float, float]:
    """(PSNR [dB] of the object pixels over all views, mean mask IoU) of ``g``."""
    ps, ious = [], []
    for v in views:
        colour, alpha, _ = render(g, v.cam, (0.0, 0.0, 0.0))
        ps.append(psnr(colour, v.obj))
        a, m = alpha.numpy() > 0.5, v.mask > 0.5
        ious.append(float(np.sum(a & m)) / max(float(np.sum(a | m)), 1.0))
    return _mean_psnr(ps), float(np.mean(ious))


def _train(
    g: Gaussians,
    params: list[wp.array],
    rates: list[float],
    views: Sequence[_View],
    iterations: int,
    rng: np.random.Generator,
    mask_weight: float,
    after_step,
) -> list[float]:
    """Adam on ``params`` of ``g`` against ``views`` over a random background per step; ``after_step()``
    runs after each update (collision projection, scale clamping). Returns the loss before each step."""
    opt = Adam(params, rates)
    history: list[float] = []
    for _ in range(iterations):
        for p in g.parameters():
            p.grad.zero_()
        bg = rng.uniform(0.0, 1.0, 3)
        total = 0.0
        for v in views:
            target = v.target(bg)
            tape = wp.Tape()
            with tape:
                colour, alpha, _ = render(g, v.cam, (float(bg[0]), float(bg[1]), float(bg[2])))
            loss, gc, ga = photometric_loss(colour, alpha, target, v.mask_wp, mask_weight=mask_weight)
            tape.backward(grads={colour: gc, alpha: ga})
            total += loss / len(views)
        history.append(total)
        opt.step()
        after_step()
    return history
