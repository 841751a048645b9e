"""Appearance fitting (Adam on all Gaussian parameters against calibrated images) and visual correction
(Physically Embodied Gaussians: per-frame optimiser steps on the means turned into particle forces)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import warp as wp

from .._warp import vec3_type
from ._bind import Binding
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


@wp.kernel
def _spread_kernel(
    link_gauss: wp.array(dtype=wp.int32),
    link_particle: wp.array(dtype=wp.int32),
    link_weight: wp.array(dtype=Any),
    means: wp.array(dtype=Any),
    means0: wp.array(dtype=Any),
    opacity_logits: wp.array(dtype=Any),
    gain: Any,
    forces: wp.array(dtype=Any),
):
    k = wp.tid()
    g = link_gauss[k]
    one = type(gain)(1.0)
    o = one / (one + wp.exp(-opacity_logits[g]))
    wp.atomic_add(forces, link_particle[k], (link_weight[k] * gain * o) * (means[g] - means0[g]))


class VisualCorrector:
    """Corrective particle forces from images (Physically Embodied Gaussians' "visual forces").

    Each call places the Gaussians with the binding, takes ``iterations`` Adam steps of the photometric loss
    with respect to their means only, and turns each displacement Δμ_g into a force
    f_g = gain · opacity_g · Δμ_g, spread onto the particles with the binding's weights.

    Args:
        binding: Gaussians bound to the simulated particles.
        cameras: The calibrated cameras the images come from.
        iterations: Optimiser steps per frame (EG: 3).
        lr_means: Adam learning rate of the means [m] (EG: 1.5e-3).
        gain: k_p [N/m] (EG: 4).
        background: RGB behind the Gaussians in the images.
    """

    def __init__(
        self,
        binding: Binding,
        cameras: Sequence[Camera],
        *,
        iterations: int = 3,
        lr_means: float = 1.5e-3,
        gain: float = 4.0,
        background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        self.binding = binding
        self.cameras = list(cameras)
        self.iterations = int(iterations)
        self.lr_means = float(lr_means)
        self.gain = float(gain)
        self.background = background
        gi, pi, w = binding.particle_weights()
        g = binding.gaussians
        dev = g.device
        self._links = (
            wp.array(gi.astype(np.int32), dtype=wp.int32, device=dev),
            wp.array(pi.astype(np.int32), dtype=wp.int32, device=dev),
            wp.array(w, dtype=g.opacity_logits.dtype, device=dev),
        )

    def forces(self, particle_q: wp.array, images: Sequence[Any]) -> wp.array:
        """Corrective forces [N] per particle (vec3 [particle_count]) for positions ``particle_q`` [m]."""
        g = self.binding.gaussians
        views = _views(self.cameras, images, None, g.dtype, g.device)
        placed = self.binding.deform(wp.clone(particle_q, requires_grad=False))
        means = wp.clone(placed.means, requires_grad=True)
        moving = placed.with_means(means, transforms=placed.transforms)
        opt = Adam([means], [self.lr_means])
        for _ in range(self.iterations):
            means.grad.zero_()
            _accumulate(moving, views, self.background, 0.0)
            opt.step()
        f = wp.zeros(self.binding.particle_count, dtype=vec3_type(g.dtype), device=g.device)
        s = g.opacity_logits.dtype
        wp.launch(
            _spread_kernel,
            dim=self._links[0].shape[0],
            inputs=[*self._links, means, placed.means, g.opacity_logits, s(self.gain)],
            outputs=[f],
            device=g.device,
        )
        return f

    def apply(self, particle_q: wp.array, control: Any, images: Sequence[Any]) -> wp.array:
        """Add the corrective forces to ``control.particle_f`` (a :class:`pliant.Control`); returns them."""
        f = self.forces(particle_q, images)
        cur = control.particle_f
        if cur.shape != f.shape or cur.dtype != f.dtype:
            raise ValueError(f"control.particle_f is {cur.shape} {cur.dtype.__name__}, forces are {f.shape}")
        wp.launch(_add_kernel, dim=f.shape[0], inputs=[cur, f], device=f.device, record_tape=False)
        return f


@wp.kernel
def _add_kernel(a: wp.array(dtype=Any), b: wp.array(dtype=Any)):
    i = wp.tid()
    a[i] = a[i] + b[i]
