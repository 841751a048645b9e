"""The appearance stage: the colours, opacities and scales of splats bound to a simulated object, the
background and a simple light, fitted to camera images with the object held at known positions (the observed
initial state), by Adam through the rasteriser — before any physics is fitted, as PhysTwin (a static 3DGS on
the first frame) and Physically Embodied Gaussians (colours from the first images) do.

What is fitted, and why only this: the splats' *placement* comes from the binding (the simulation decides
where they are), so their means and rotations are held; their colours (degree-1 spherical harmonics when
several cameras see them, so view-dependent effects such as a specular sheen can be absorbed; RGB with one
camera, where degree 1 is not constrained), opacity logits and log-scales, the background colour and the
shading (:func:`pliant.gaussians.render`'s ``light``: ambient, a directional light and a headlight, Lambertian
on the splat normals) are free. Every gradient is the rasteriser's (``wp.Tape``; the background's and the
light's are checked against float64 central differences in ``tests/test_gaussians_appearance.py``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from .._warp import vec3_type
from ._camera import Camera
from ._gaussians import SH_C0, Gaussians, vec4_type
from ._optim import Adam, image_to_warp, photometric_loss, psnr
from ._render import render

if TYPE_CHECKING:
    from ._scene import SceneSplats

#: Learning rates of the appearance stage's Adam (per parameter; sh in SH units: colour = 0.28 · sh).
APPEARANCE_LRS = {
    "sh": 0.03,
    "opacity_logits": 0.05,
    "log_scales": 0.01,
    "background": 0.01,
    "light": 0.03,
}


@dataclass
class AppearanceResult:
    """What :func:`fit_splat_appearance` found (the splats themselves are updated in place).

    Attributes:
        background: Fitted background RGB.
        light: Fitted shading (ambient, Lx, Ly, Lz, headlight), or None when unlit.
        sh_degree: Spherical-harmonic degree of the fitted colours.
        psnr_before: PSNR [dB] of the colour over the training views before the stage.
        psnr_after: The same after it.
        psnr_views: PSNR [dB] of each training view (frame-major, then camera) after it.
        history: Mean loss before each Adam step.
        iterations: Adam steps taken (it stops earlier when the loss stops improving).
        wall_time: Seconds.
    """

    background: tuple[float, float, float]
    light: tuple[float, ...] | None
    sh_degree: int
    psnr_before: float
    psnr_after: float
    psnr_views: list[float] = field(default_factory=list)
    history: list[float] = field(default_factory=list)
    iterations: int = 0
    wall_time: float = 0.0


def sample_colours(
    means: np.ndarray,
    cameras: Sequence[Camera],
    images: Sequence[np.ndarray],
    masks: Sequence[np.ndarray] | None = None,
) -> np.ndarray:
    """Mean observed colour [N, 3] at the pixel each point ``means`` [m] projects to, over the cameras that
    see it in front (occlusion ignored) and, with ``masks``, only where that pixel is the object's; 0.5 grey
    where no camera sees it. A starting value for the fit.

    Args:
        means: Points [m], shape [N, 3].
        cameras: The cameras.
        images: One RGB image [H, W, 3] in [0, 1] per camera.
        masks: One object mask [H, W] per camera (pixels > 0.5 are the object's), or None: every pixel counts.
    """
    mu = np.asarray(means, dtype=np.float64).reshape(-1, 3)
    acc = np.zeros((len(mu), 3))
    cnt = np.zeros(len(mu))
    for c, (cam, img) in enumerate(zip(cameras, images, strict=True)):
        p = mu @ cam.rotation.T + cam.translation
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.round(cam.fx * p[:, 0] / z + cam.cx)
            v = np.round(cam.fy * p[:, 1] / z + cam.cy)
        ok = (z > 1e-6) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        vi, ui = v[ok].astype(int), u[ok].astype(int)
        if masks is not None:
            inside = np.asarray(masks[c], dtype=np.float64)[vi, ui] > 0.5
            ok[ok] = inside
            vi, ui = vi[inside], ui[inside]
        acc[ok] += np.asarray(img, dtype=np.float64)[vi, ui]
        cnt[ok] += 1
    out = np.full((len(mu), 3), 0.5)
    seen = cnt > 0
    out[seen] = acc[seen] / cnt[seen, None]
    return out


def fit_splat_appearance(
    splats: SceneSplats,
    cameras: Sequence[Camera],
    positions: Sequence[np.ndarray],
    images: Sequence[Sequence[np.ndarray]],
    masks: Sequence[Sequence[np.ndarray | None]] | None = None,
    *,
    sh_degree: int | None = None,
    shading: bool = True,
    iterations: int = 300,
    rtol: float = 1e-3,
    patience: int = 20,
    lrs: dict[str, float] | None = None,
    mask_weight: float = 1.0,
) -> AppearanceResult:
    """Fit the appearance of bound splats to images of known poses; updates ``splats`` in place, or keeps
    the starting appearance when that drew the images better (the stage never lowers the PSNR).

    The splats' colours start at the observed colour under each splat's centre (:func:`sample_colours`) and
    the background at the median colour of the pixels no splat covers, so Adam only refines them.

    Args:
        splats: A :class:`pliant.gaussians._scene.SceneSplats` (its binding's Gaussians are replaced by the
            fitted set; its ``background`` and ``light`` are set).
        cameras: The C cameras.
        positions: Model particle positions [m], [N, 3], of each training frame (the observed initial state).
        images: ``images[f][c]``: RGB [H, W, 3] in [0, 1] of frame f seen by camera c.
        masks: ``masks[f][c]``: object masks [H, W] in [0, 1] (compared with the rendered alpha), or None.
        sh_degree: Degree of the fitted colours (None: 1 with several cameras, else 0).
        shading: Fit a light (ambient, directional, headlight); else the splats are unlit.
        iterations: Most Adam steps.
        rtol: Stop when the loss improved by less than this fraction over the last ``patience`` steps.
        patience: Steps over which the improvement is measured.
        lrs: Learning rates by name (defaults :data:`APPEARANCE_LRS`).
        mask_weight: Weight of the mask term.

    Returns:
        :class:`AppearanceResult`.

    Raises:
        ValueError: counts of frames, cameras, images or masks differ, or an image has the wrong size.
    """
    t0 = time.perf_counter()
    if len(positions) != len(images) or not len(positions):
        raise ValueError(f"appearance: {len(positions)} frames of positions but {len(images)} of images")
    if any(len(row) != len(cameras) for row in images):
        raise ValueError(f"appearance: every frame needs one image per camera ({len(cameras)})")
    b = splats.binding
    g0 = b.gaussians
    dtype, dev = g0.dtype, g0.device
    degree = (1 if len(cameras) > 1 else 0) if sh_degree is None else int(sh_degree)
    rates = dict(APPEARANCE_LRS, **(lrs or {}))

    # Where the splats are in each training frame (the binding at the known positions), and the views.
    placed = [splats.place(x) for x in positions]
    views = []
    for f, row in enumerate(images):
        for c, cam in enumerate(cameras):
            img = image_to_warp(row[c], cam, dtype, dev, f"frame {f} camera {c} image")
            raw = None if masks is None else masks[f][c]
            mk = None if raw is None else image_to_warp(raw, cam, dtype, dev, f"frame {f} camera {c} mask")
            views.append((f, cam, img, mk))

    def psnrs(
        gs: list[Gaussians], bg: tuple[float, float, float], light: Sequence[float] | None
    ) -> list[float]:
        return [psnr(render(gs[f], cam, bg, light=light).colour, img) for f, cam, img, _ in views]

    before = psnrs(placed, splats.background, getattr(splats, "light", None))

    # Starting values: observed colours under the splats, the uncovered pixels' median as background.
    first = [np.asarray(im, dtype=np.float64) for im in images[0]]
    rgb = sample_colours(placed[0].means.numpy(), cameras, first)
    bg0 = _uncovered_median(placed[0], cameras, first)
    g = _coloured(g0, rgb, degree)
    b.gaussians = g
    placed = [splats.place(x) for x in positions]
    background: wp.array = wp.array([bg0], dtype=vec3_type(dtype), device=dev, requires_grad=True)
    params = [g.sh, g.opacity_logits, g.log_scales, background]
    names = ["sh", "opacity_logits", "log_scales", "background"]
    light: wp.array | None = None
    if shading:
        light = _starting_light(placed[0], cameras)
        params.append(light)
        names.append("light")
    opt = Adam(params, [rates[n] for n in names])
    history = _descend(opt, params, views, placed, background, light, iterations, rtol, patience, mask_weight)
    bg_r, bg_g, bg_b = (float(v) for v in background.numpy().reshape(3))
    bg = (bg_r, bg_g, bg_b)
    lt = None
    if light is not None:
        lv = light.numpy().astype(np.float64)
        lt = (*(float(v) for v in lv[0]), float(lv[1, 0]))
    fitted = g.copy()  # off the optimiser's arrays (g has dtype `dtype`, on dev)
    bg_start, light_start = splats.background, getattr(splats, "light", None)
    b.gaussians = fitted
    splats.background = bg
    splats.light = lt
    placed = [splats.place(x) for x in positions]
    after = psnrs(placed, bg, lt)
    if _mean_psnr(after) < _mean_psnr(before):
        # The splats already drew the images better (e.g. the footage was rendered from them): keep them,
        # so that the stage can only help the physics fit that follows.
        b.gaussians, splats.background, splats.light = g0, bg_start, light_start
        bg, lt, after = bg_start, light_start, before
    return AppearanceResult(
        background=bg,
        light=lt,
        sh_degree=degree,
        psnr_before=_mean_psnr(before),
        psnr_after=_mean_psnr(after),
        psnr_views=after,
        history=history,
        iterations=len(history),
        wall_time=time.perf_counter() - t0,
    )


def _uncovered_median(placed: Gaussians, cameras: Sequence[Camera], first: list[np.ndarray]) -> np.ndarray:
    """The starting background RGB [3]: the median colour of the pixels of the first frame's images
    ``first`` that no splat covers (alpha < 0.01), else of the images' top and bottom rows."""
    uncovered = [im[render(placed, cam).alpha.numpy() < 0.01] for cam, im in zip(cameras, first, strict=True)]
    pool = (
        np.concatenate(uncovered)
        if sum(len(u) for u in uncovered)
        else np.concatenate([im[[0, -1]].reshape(-1, 3) for im in first])
    )
    return np.median(pool, axis=0)


def _coloured(g0: Gaussians, rgb: np.ndarray, degree: int) -> Gaussians:
    """A copy of ``g0`` that records gradients, with SH colours of ``degree`` whose constant term is the
    sampled colour ``rgb`` [G, 3] (clipped to [0.02, 0.98]) and higher terms zero."""
    p = g0.numpy()
    sh = np.zeros((g0.count, (degree + 1) ** 2, 3))
    sh[:, 0] = (np.clip(rgb, 0.02, 0.98) - 0.5) / SH_C0
    return Gaussians(
        p["means"],
        p["quats"],
        p["log_scales"],
        p["opacity_logits"],
        sh,
        dtype=g0.dtype,
        device=g0.device,
        requires_grad=True,
    )


def _starting_light(placed: Gaussians, cameras: Sequence[Camera]) -> wp.array:
    """The light to fit, as two vec4 ((ambient, L), (headlight, 0, 0, 0)) that record gradients."""
    # Unlit at the start (shade ≈ 1, the sampled colours already carry the light), with a small light
    # towards the cameras so that max(0, n·L) has a slope.
    centre = placed.means.numpy().mean(axis=0)
    towards = np.mean([cam.position for cam in cameras], axis=0) - centre
    towards /= max(np.linalg.norm(towards), 1e-12)
    return wp.array(
        [[0.98, *(0.01 * towards)], [0.01, 0.0, 0.0, 0.0]],
        dtype=vec4_type(placed.dtype),
        device=placed.device,
        requires_grad=True,
    )


def _descend(
    opt: Adam,
    params: list[wp.array],
    views: list[tuple[int, Camera, wp.array, wp.array | None]],
    placed: list[Gaussians],
    background: wp.array,
    light: wp.array | None,
    iterations: int,
    rtol: float,
    patience: int,
    mask_weight: float,
) -> list[float]:
    """Adam steps on the photometric loss over ``views`` (frame, camera, image, mask) until ``iterations``
    or a relative improvement below ``rtol`` over ``patience`` steps; the loss history."""
    history: list[float] = []
    for _ in range(iterations):
        for a in params:
            a.grad.zero_()
        total = 0.0
        for f, cam, img, mk in views:
            tape = wp.Tape()
            with tape:
                colour, alpha, _ = render(placed[f], cam, background, light=light)
            loss, gc, ga = photometric_loss(colour, alpha, img, mk, mask_weight=mask_weight)
            tape.backward(grads={colour: gc, alpha: ga})
            total += loss / len(views)
        for a in params:
            ga = a.grad.numpy()
            if not np.all(np.isfinite(ga)):
                raise FloatingPointError("appearance: a non-finite gradient (check the images and cameras)")
        history.append(total)
        opt.step()
        if len(history) > patience and history[-1 - patience] - history[-1] < rtol * history[-1 - patience]:
            break
    return history


def _mean_psnr(values: Sequence[float]) -> float:
    """PSNR of the mean squared error over views (not the mean of the views' PSNRs)."""
    mse = [10.0 ** (-v / 10.0) for v in values if math.isfinite(v)]
    if len(mse) < len(values):  # a view matched exactly
        mse += [0.0] * (len(values) - len(mse))
    m = float(np.mean(mse)) if mse else 0.0
    return float("inf") if m == 0.0 else -10.0 * math.log10(m)


__all__ = ["APPEARANCE_LRS", "AppearanceResult", "fit_splat_appearance", "sample_colours"]
