"""Appearance fitting: Adam on all Gaussian parameters against calibrated images (visual correction, which
reuses the helpers here, lives in ``_correct.py``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import warp as wp

from .._warp import vec3_type
from ._camera import Camera
from ._gaussians import Gaussians
from ._optim import Adam, image_to_warp, photometric_loss
from ._render import render

#: Default learning rates per parameter (those of 3D Gaussian splatting's reference training, with the means'
#: rate for a scene of about 1 m).
DEFAULT_LRS = {"means": 1.6e-3, "quats": 1e-3, "log_scales": 5e-3, "opacity_logits": 2.5e-2, "sh": 2.5e-3}


def _views(cameras: Sequence[Camera], images: Sequence[Any], masks, dtype: str, device: str):
    if len(cameras) != len(images):
        raise ValueError(f"{len(cameras)} cameras but {len(images)} images")
    if masks is not None and len(masks) != len(cameras):
        raise ValueError(f"{len(cameras)} cameras but {len(masks)} masks")
    out = []
    for i, cam in enumerate(cameras):
        img = image_to_warp(images[i], cam, dtype, device, f"image {i}")
        if img.ndim != 2 or img.dtype != vec3_type(dtype):
            raise ValueError(f"image {i} must have shape [H, W, 3]")
        mask = None if masks is None else image_to_warp(masks[i], cam, dtype, device, f"mask {i}")
        out.append((cam, img, mask))
    return out


def _accumulate(g: Gaussians, views, background, mask_weight: float) -> float:
    """Render every view under a tape and add ∂loss/∂parameters into the parameters' gradients."""
    total = 0.0
    for cam, img, mask in views:
        tape = wp.Tape()
        with tape:
            c, a, _ = render(g, cam, background)
        loss, gc, ga = photometric_loss(c, a, img, mask, mask_weight=mask_weight)
        tape.backward(grads={c: gc, a: ga})
        total += loss
    return total / len(views)


def fit_appearance(
    init: Gaussians,
    cameras: Sequence[Camera],
    images: Sequence[Any],
    *,
    masks: Sequence[Any] | None = None,
    iterations: int = 500,
    lrs: dict[str, float] | None = None,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    mask_weight: float = 1.0,
) -> tuple[Gaussians, list[float]]:
    """Fit a Gaussian set to calibrated images by Adam on every parameter (no densification or pruning).

    Args:
        init: Starting Gaussians (copied; e.g. Gaussians at the simulation's particles).
        cameras: One camera per image.
        images: Observed RGB images [H, W, 3] in [0, 1] (NumPy or Warp).
        masks: Optional object masks [H, W] in [0, 1], compared with the rendered alpha.
        iterations: Adam steps (each uses every view).
        lrs: Learning rates by parameter name (defaults :data:`DEFAULT_LRS`; 0 freezes one).
        background: RGB behind the Gaussians.
        mask_weight: Weight of the mask term.

    Returns:
        (fitted Gaussians, mean loss before each step).

    Raises:
        ValueError: counts differ, or an image/mask has the wrong size or holds NaN.
    """
    views = _views(cameras, images, masks, init.dtype, init.device)
    g = init.copy(requires_grad=True)
    rates = dict(DEFAULT_LRS, **(lrs or {}))
    names = ["means", "quats", "log_scales", "opacity_logits", "sh"]
    opt = Adam(g.parameters(), [rates[n] for n in names])
    history = []
    for _ in range(iterations):
        for p in g.parameters():
            p.grad.zero_()
        history.append(_accumulate(g, views, background, mask_weight))
        opt.step()
    return g, history
