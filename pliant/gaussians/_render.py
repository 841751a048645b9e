"""`render`: project, bin, sort and composite a Gaussian set for one camera; differentiable under wp.Tape."""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import warp as wp

from .._warp import active_tape, mat33_type, scalar_type, vec3_type
from ._camera import Camera
from ._composite import (
    background_adjoint_kernel,
    composite_backward_kernel,
    composite_kernel,
    depth_keys_kernel,
    duplicate_kernel,
    ranges_kernel,
    ranks_kernel,
)
from ._gaussians import Gaussians, vec2_type, vec4_type
from ._project import TILE, project_kernel


class RenderOutput(NamedTuple):
    """What :func:`render` returns (unpacks as ``colour, alpha, depth``).

    Attributes:
        colour: RGB [H, W] of vec3 (``.numpy()`` gives [H, W, 3]), background composited behind.
        alpha: Accumulated opacity 1 − T_end in [0, 1], [H, W].
        depth: Expected camera-space depth [m] of the visible Gaussians, Σ z_i α_i T_i / alpha (0 where alpha
            is 0), [H, W].
    """

    colour: wp.array
    alpha: wp.array
    depth: wp.array


class _Frame:
    """What one render keeps for its backward pass (projected Gaussians, sorted lists, per-pixel sums)."""

    mean2d: wp.array  # per Gaussian, filled by project_kernel
    conic: wp.array
    depth: wp.array
    opacity: wp.array
    colour: wp.array
    ranges: wp.array  # per tile, then the depth-sorted Gaussian ids of every tile
    vals: wp.array
    T: wp.array  # per pixel: transmittance, colour and depth sums, last Gaussian composited
    C: wp.array
    D: wp.array
    last: wp.array
    background: wp.vec3 | wp.vec3d  # of the render's dtype
    tiles_x: int


def render(
    gaussians: Gaussians,
    camera: Camera,
    background: tuple[float, float, float] | wp.array = (0.0, 0.0, 0.0),
    *,
    near: float = 0.01,
    eps2d: float = 0.3,
    light: wp.array | Sequence[float] | None = None,
) -> RenderOutput:
    """Rasterise ``gaussians`` seen by ``camera`` (3D Gaussian splatting, tiles of 16×16 pixels).

    Under an active ``wp.Tape`` the result is differentiable: ``tape.backward(grads={colour: ...})`` (or a
    loss computed from the outputs by Warp kernels) fills the gradients of the Gaussians' means, quats,
    log_scales, opacity_logits and sh, and of whatever produced them on the tape (a binding, a simulation),
    and of ``background`` and ``light`` when they are Warp arrays with ``requires_grad``.

    Args:
        gaussians: The Gaussian set (its dtype and device are the render's).
        camera: Intrinsics, pose and image size.
        background: RGB behind the Gaussians, each in [0, 1]: three numbers, or a Warp array of one vec3 of
            the Gaussians' dtype (differentiable: ∂L/∂background = Σ_pixels ∂L/∂colour · T_end).
        near: Gaussians with camera depth ≤ ``near`` [m] are culled.
        eps2d: Low-pass dilation [px²] added to the diagonal of every 2D covariance (as in 3DGS).
        light: None (unlit: colour = SH colour), or Lambertian shading of each splat's SH colour by
            shade = ambient + max(0, n·L) + headlight · |n·v| with n the splat's normal (its thinnest axis,
            turned towards the camera) and v the unit viewing direction: 5 numbers (ambient, Lx, Ly, Lz,
            headlight) with L the light's direction × intensity (world frame, pointing towards the light),
            or a Warp array of two vec4 of the Gaussians' dtype ((ambient, Lx, Ly, Lz), (headlight, 0, 0,
            0)), differentiable under the tape.

    Returns:
        :class:`RenderOutput` (colour [H, W, 3], alpha [H, W], depth [H, W]) as Warp arrays.
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a pliant.gaussians.Camera, got {type(camera).__name__}")
    dev, dtype = gaussians.device, gaussians.dtype
    s, v2, v3, v4 = scalar_type(dtype), vec2_type(dtype), vec3_type(dtype), vec4_type(dtype)
    m33 = mat33_type(dtype)
    bg_array, bg = _background(background, v3)
    light_array = _light_array(light, v4, dev)
    n = gaussians.count
    H, W = camera.height, camera.width
    tiles_x, tiles_y = (W + TILE - 1) // TILE, (H + TILE - 1) // TILE
    tape = active_tape()
    extra = [a for a in (bg_array, light_array if light is not None else None) if a is not None]
    grad = tape is not None and (gaussians.requires_grad or any(a.requires_grad for a in extra))

    f = _Frame()
    f.mean2d = wp.zeros(n, dtype=v2, device=dev, requires_grad=grad)
    f.conic = wp.zeros(n, dtype=v3, device=dev, requires_grad=grad)
    f.depth = wp.zeros(n, dtype=s, device=dev, requires_grad=grad)
    f.opacity = wp.zeros(n, dtype=s, device=dev, requires_grad=grad)
    f.colour = wp.zeros(n, dtype=v3, device=dev, requires_grad=grad)
    rect = wp.zeros(n, dtype=wp.vec4i, device=dev)
    tile_count = wp.zeros(n, dtype=wp.int32, device=dev)
    # Perspective Jacobians are evaluated with x/z, y/z clamped to 1.3× the field of view (as 3DGS does), so
    # Gaussians far outside the image do not get huge footprints.
    lim = (
        (camera.cx + 0.3 * W) / camera.fx,
        (W - camera.cx + 0.3 * W) / camera.fx,
        (camera.cy + 0.3 * H) / camera.fy,
        (H - camera.cy + 0.3 * H) / camera.fy,
    )
    transforms = gaussians.transforms
    if transforms is None:
        transforms = wp.array([np.eye(3)], dtype=m33, device=dev)
    if n > 0:
        wp.launch(
            project_kernel,
            dim=n,
            inputs=[
                gaussians.means,
                gaussians.quats,
                gaussians.log_scales,
                gaussians.opacity_logits,
                gaussians.sh,
                gaussians.sh_degree,
                transforms,
                int(gaussians.transforms is not None),
                light_array,
                int(light is not None),
                m33(*camera.rotation.flatten()),
                v3(*camera.translation),
                v3(*camera.position),
                s(camera.fx),
                s(camera.fy),
                s(camera.cx),
                s(camera.cy),
                *(s(v) for v in lim),
                s(near),
                s(eps2d),
                tiles_x,
                tiles_y,
            ],
            outputs=[f.mean2d, f.conic, f.depth, f.opacity, f.colour, rect, tile_count],
            device=dev,
        )
    f.ranges, f.vals = _bin(f.depth, rect, tile_count, tiles_x, tiles_x * tiles_y, n, s, dev)

    out_colour = wp.zeros((H, W), dtype=v3, device=dev, requires_grad=grad)
    out_alpha = wp.zeros((H, W), dtype=s, device=dev, requires_grad=grad)
    out_depth = wp.zeros((H, W), dtype=s, device=dev, requires_grad=grad)
    f.T = wp.zeros((H, W), dtype=s, device=dev)
    f.C = wp.zeros((H, W), dtype=v3, device=dev)
    f.D = wp.zeros((H, W), dtype=s, device=dev)
    f.last = wp.zeros((H, W), dtype=wp.int32, device=dev)
    f.background = v3(*bg)
    f.tiles_x = tiles_x
    wp.launch(
        composite_kernel,
        dim=(H, W),
        inputs=[f.ranges, f.vals, f.mean2d, f.conic, f.opacity, f.colour, f.depth, f.background, tiles_x],
        outputs=[out_colour, out_alpha, out_depth, f.T, f.C, f.D, f.last],
        device=dev,
        record_tape=False,
    )
    if grad and tape is not None:  # grad implies a tape; the second test tells mypy so
        _record_backward(tape, f, out_colour, out_alpha, out_depth, bg_array, dev)
    return RenderOutput(out_colour, out_alpha, out_depth)


def _background(
    background: tuple[float, float, float] | wp.array, v3: type
) -> tuple[wp.array | None, np.ndarray]:
    """The background as (its Warp array when it is one, else None; its RGB [3] in [0, 1] as float64),
    checked: a Warp array holds one ``v3``, and the colour is 3 finite numbers."""
    bg_array = background if isinstance(background, wp.array) else None
    if bg_array is not None:
        if bg_array.shape != (1,) or bg_array.dtype != v3:
            raise ValueError(f"background as a Warp array must hold one {v3.__name__}, got {bg_array}")
        bg = bg_array.numpy().reshape(3).astype(np.float64)
    else:
        bg = np.asarray(background, dtype=np.float64)
    if bg.shape != (3,) or not np.all(np.isfinite(bg)):
        raise ValueError(f"background must be 3 finite numbers, got {background!r}")
    return bg_array, bg


def _record_backward(
    tape: wp.Tape,
    f: _Frame,
    out_colour: wp.array,
    out_alpha: wp.array,
    out_depth: wp.array,
    bg_array: wp.array | None,
    dev: str,
) -> None:
    """Record the composite's adjoint on ``tape``: from the image gradients [H, W] to the splats'
    projected quantities in ``f`` (and to ``bg_array`` when it records gradients)."""

    def backward() -> None:
        wp.launch(
            composite_backward_kernel,
            dim=out_alpha.shape,
            inputs=[
                f.ranges,
                f.vals,
                f.mean2d,
                f.conic,
                f.opacity,
                f.colour,
                f.depth,
                f.background,
                f.tiles_x,
                f.T,
                f.C,
                f.D,
                f.last,
                out_colour.grad,
                out_alpha.grad,
                out_depth.grad,
                f.mean2d.grad,
                f.conic.grad,
                f.opacity.grad,
                f.colour.grad,
                f.depth.grad,
            ],
            device=dev,
            record_tape=False,
        )
        if bg_array is not None and bg_array.requires_grad:
            wp.launch(
                background_adjoint_kernel,
                dim=out_alpha.shape,
                inputs=[out_colour.grad, f.T, bg_array.grad],
                device=dev,
                record_tape=False,
            )

    tape.record_func(
        backward=backward,
        arrays=[out_colour, out_alpha, out_depth, f.mean2d, f.conic, f.opacity, f.colour, f.depth],
    )


def _light_array(light: wp.array | Sequence[float] | None, v4: type, dev: str) -> wp.array:
    """The shading parameters as a Warp array of two vec4 (see :func:`render`); zeros when unlit."""
    if light is None:
        return wp.zeros(2, dtype=v4, device=dev)
    if isinstance(light, wp.array):
        if light.shape != (2,) or light.dtype != v4:
            raise ValueError(f"light as a Warp array must hold two {v4.__name__}, got {light}")
        if str(light.device) != dev:
            raise ValueError(f"light is on {light.device} but the Gaussians are on {dev}")
        return light
    a = np.asarray(light, dtype=np.float64).reshape(-1)
    if a.shape != (5,) or not np.all(np.isfinite(a)):
        raise ValueError(f"light must be 5 finite numbers (ambient, Lx, Ly, Lz, headlight), got {light!r}")
    return wp.array([a[:4], [a[4], 0.0, 0.0, 0.0]], dtype=v4, device=dev)


def _bin(depth, rect, tile_count, tiles_x: int, tile_total: int, n: int, s, dev):
    """Per-tile lists of Gaussian ids sorted front to back: (ranges [tiles] vec2i, ids [entries] int32)."""
    ranges = wp.zeros(tile_total, dtype=wp.vec2i, device=dev)
    if n == 0:
        return ranges, wp.zeros(1, dtype=wp.int32, device=dev)
    offsets = wp.zeros(n, dtype=wp.int32, device=dev)
    wp.utils.array_scan(tile_count, offsets, inclusive=False)
    total = int(offsets[n - 1 : n].numpy()[0] + tile_count[n - 1 : n].numpy()[0])
    if total == 0:
        return ranges, wp.zeros(1, dtype=wp.int32, device=dev)
    # 1. order the Gaussians by depth (radix sort on the float depth), 2. key every (tile, Gaussian) pair by
    # tile · 2³² + depth rank and sort once more: each tile's list comes out front to back.
    dkeys = wp.empty(2 * n, dtype=s, device=dev)
    dvals = wp.empty(2 * n, dtype=wp.int32, device=dev)
    wp.launch(
        depth_keys_kernel, dim=n, inputs=[depth, tile_count, dkeys, dvals], device=dev, record_tape=False
    )
    wp.utils.radix_sort_pairs(dkeys, dvals, n)
    rank = wp.empty(n, dtype=wp.int32, device=dev)
    wp.launch(ranks_kernel, dim=n, inputs=[dvals, rank], device=dev, record_tape=False)
    keys = wp.empty(2 * total, dtype=wp.int64, device=dev)
    vals = wp.empty(2 * total, dtype=wp.int32, device=dev)
    wp.launch(
        duplicate_kernel,
        dim=n,
        inputs=[rect, tile_count, offsets, rank, tiles_x, keys, vals],
        device=dev,
        record_tape=False,
    )
    end_bit = 32 + max(1, int(tile_total).bit_length())
    wp.utils.radix_sort_pairs(keys, vals, total, 0, end_bit)
    wp.launch(ranges_kernel, dim=total, inputs=[keys, total, ranges], device=dev, record_tape=False)
    return ranges, vals
