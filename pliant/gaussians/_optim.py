"""Photometric losses and a small Adam for Gaussian parameters (Warp kernels, any float dtype, any device)."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
import warp as wp

from .._warp import scalar_type, vec3_type
from ._camera import Camera


@wp.kernel
def _mse_kernel(
    colour: wp.array2d(dtype=Any),
    target: wp.array2d(dtype=Any),
    alpha: wp.array2d(dtype=Any),
    mask: wp.array2d(dtype=Any),
    has_mask: int,
    colour_weight: Any,
    mask_weight: Any,
    loss_out: wp.array(dtype=Any),
    adj_colour_out: wp.array2d(dtype=Any),
    adj_alpha_out: wp.array2d(dtype=Any),
):
    y, x = wp.tid()
    d = colour[y, x] - target[y, x]
    l = colour_weight * wp.dot(d, d)
    adj_colour_out[y, x] = (colour_weight + colour_weight) * d
    if has_mask != 0:
        e = alpha[y, x] - mask[y, x]
        l = l + mask_weight * e * e
        adj_alpha_out[y, x] = (mask_weight + mask_weight) * e
    wp.atomic_add(loss_out, 0, l)


def photometric_loss(
    colour: wp.array,
    alpha: wp.array,
    target: wp.array,
    mask: wp.array | None = None,
    *,
    mask_weight: float = 1.0,
) -> tuple[float, wp.array, wp.array]:
    """Mean squared colour error (plus ``mask_weight`` · mean squared alpha−mask error) and its gradients.

    Args:
        colour: Rendered RGB [H, W] vec3.
        alpha: Rendered alpha [H, W].
        target: Observed RGB [H, W] vec3, same dtype and device.
        mask: Observed object mask [H, W] in [0, 1], or ``None``.
        mask_weight: Weight of the mask term.

    Returns:
        (loss, ∂loss/∂colour, ∂loss/∂alpha), the gradients as Warp arrays for ``tape.backward(grads=...)``.
    """
    H, W = colour.shape
    s = _scalar(colour.dtype)
    loss = wp.zeros(1, dtype=s, device=colour.device)
    adj_c = wp.zeros_like(colour, requires_grad=False)
    adj_a = wp.zeros_like(alpha, requires_grad=False)
    m = mask if mask is not None else alpha
    wp.launch(
        _mse_kernel,
        dim=(H, W),
        inputs=[
            colour,
            target,
            alpha,
            m,
            int(mask is not None),
            s(1.0 / (3 * H * W)),
            s(mask_weight / (H * W)),
        ],
        outputs=[loss, adj_c, adj_a],
        device=colour.device,
        record_tape=False,
    )
    return float(loss.numpy()[0]), adj_c, adj_a


def image_to_warp(
    image: np.ndarray, camera: Camera, dtype: str, device: str, name: str = "image"
) -> wp.array:
    """Validate an observed image [H, W, 3] (or a mask [H, W]) for ``camera`` and copy it to the device."""
    a = camera.check_image(image, name)
    if a.ndim == 3:
        return wp.array(a, dtype=vec3_type(dtype), device=device)
    return wp.array(a, dtype=scalar_type(dtype), device=device)


def psnr(rendered: wp.array | npt.ArrayLike, target: wp.array | npt.ArrayLike) -> float:
    """Peak signal-to-noise ratio [dB] of two images in [0, 1]: −10 log₁₀ MSE."""
    a = np.asarray(rendered.numpy() if hasattr(rendered, "numpy") else rendered, dtype=np.float64)
    b = np.asarray(target.numpy() if hasattr(target, "numpy") else target, dtype=np.float64)
    mse = float(np.mean((a - b) ** 2))
    return float("inf") if mse == 0.0 else -10.0 * np.log10(mse)


def iou(
    rendered: wp.array | npt.ArrayLike, target: wp.array | npt.ArrayLike, threshold: float = 0.5
) -> float:
    """Intersection over union of two silhouettes: the pixels where ``rendered`` > ``threshold`` against
    those where ``target`` > ``threshold`` (e.g. a rendered alpha in [0, 1] against an object mask; bool
    masks count as 0 / 1). Arrays of the same shape, any number of dimensions (a stack of frames pools
    their pixels). 1.0 when both silhouettes are empty (they agree everywhere).

    Args:
        rendered: alpha or mask values (NumPy or a Warp array).
        target: mask values, the same shape.
        threshold: the value a pixel must exceed to count as the object's.
    """
    a = np.asarray(rendered.numpy() if hasattr(rendered, "numpy") else rendered, dtype=np.float64)
    b = np.asarray(target.numpy() if hasattr(target, "numpy") else target, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"iou: rendered {a.shape} and target {b.shape} must have the same shape")
    pa, pb = a > threshold, b > threshold
    union = int(np.count_nonzero(pa | pb))
    return 1.0 if union == 0 else int(np.count_nonzero(pa & pb)) / union


@wp.kernel
def _adam_kernel(
    g: wp.array(dtype=Any),
    p_io: wp.array(dtype=Any),
    m_io: wp.array(dtype=Any),
    v_io: wp.array(dtype=Any),
    lr: Any,
    b1: Any,
    b2: Any,
    c1: Any,
    c2: Any,
    eps: Any,
):
    i = wp.tid()
    one = type(lr)(1.0)
    gi = g[i]
    m_io[i] = b1 * m_io[i] + (one - b1) * gi
    v_io[i] = b2 * v_io[i] + (one - b2) * gi * gi
    p_io[i] = p_io[i] - lr * (m_io[i] / c1) / (wp.sqrt(v_io[i] / c2) + eps)


def _flat(a: wp.array) -> wp.array:
    """A 1-d scalar view of a Warp array of scalars, vectors or matrices (no copy)."""
    return a.flatten().view(_scalar(a.dtype)).flatten()


def _scalar(dtype: type) -> type:
    """The scalar type of a Warp vector or matrix dtype; a scalar dtype is its own."""
    return dtype._wp_scalar_type_ if hasattr(dtype, "_wp_scalar_type_") else dtype


class Adam:
    """Adam (Kingma & Ba 2015) on Warp arrays, each with its own learning rate; updates in place.

    Args:
        params: Arrays to optimise (``requires_grad``; their ``.grad`` is read by :meth:`step`).
        lrs: Learning rate of each array.
        betas: Moment decay rates.
        eps: Denominator guard.
    """

    def __init__(
        self, params: list[wp.array], lrs: list[float], betas=(0.9, 0.999), eps: float = 1e-15
    ) -> None:
        self.params = params
        self.lrs = lrs
        self.b1, self.b2 = betas
        self.eps = eps
        self.t = 0
        self.m = [wp.zeros_like(_flat(p), requires_grad=False) for p in params]
        self.v = [wp.zeros_like(_flat(p), requires_grad=False) for p in params]

    def step(self) -> None:
        """One update from the parameters' current gradients."""
        self.t += 1
        for p, lr, m, v in zip(self.params, self.lrs, self.m, self.v, strict=True):
            fp, fg = _flat(p), _flat(p.grad)
            s = fp.dtype
            c1, c2 = 1.0 - self.b1**self.t, 1.0 - self.b2**self.t
            wp.launch(
                _adam_kernel,
                dim=fp.shape[0],
                inputs=[fg, fp, m, v, s(lr), s(self.b1), s(self.b2), s(c1), s(c2), s(self.eps)],
                device=p.device,
                record_tape=False,
            )
