"""Tile binning, depth sort and front-to-back alpha compositing, with a hand-written adjoint.

Compositing (Kerbl et al. 2023, eq. 3): along a pixel's depth-sorted list, α_i = min(0.99, o_i G_i(p)),
G_i(p) = exp(−½ dᵀ Σ'_i⁻¹ d), d = p − μ'_i; contributions with α_i < 1/255 are skipped and the walk stops
before the transmittance T would fall below 1e-4. Outputs C = Σ c_i α_i T_i + T_end·background,
alpha = 1 − T_end and expected depth Σ z_i α_i T_i / alpha, with T_i = Π_{j<i}(1 − α_j).

The adjoint walks the same list front to back again and uses the suffix sums S_i = Σ_{j>i} c_j α_j T_j
(= total − prefix, no division by 1 − α), from
∂C/∂α_i = c_i T_i − S_i / (1 − α_i) and ∂T_end/∂α_i = −T_end / (1 − α_i).
Warp's automatic adjoint is not used here: the loop carries T, which its reverse mode handles unreliably.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ._project import TILE

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1.0e-4
_KEY_SHIFT = 4294967296  # 2**32: key = tile · 2³² + depth rank


@wp.kernel
def depth_keys_kernel(
    depth: wp.array(dtype=Any),
    tile_count: wp.array(dtype=wp.int32),
    keys_out: wp.array(dtype=Any),
    vals_out: wp.array(dtype=wp.int32),
):
    g = wp.tid()
    d = depth[g]
    if tile_count[g] == 0:
        d = type(d)(1.0e30)
    keys_out[g] = d
    vals_out[g] = g


@wp.kernel
def ranks_kernel(sorted_vals: wp.array(dtype=wp.int32), rank_out: wp.array(dtype=wp.int32)):
    i = wp.tid()
    rank_out[sorted_vals[i]] = i


@wp.kernel
def duplicate_kernel(
    rect: wp.array(dtype=wp.vec4i),
    tile_count: wp.array(dtype=wp.int32),
    offsets: wp.array(dtype=wp.int32),
    rank: wp.array(dtype=wp.int32),
    tiles_x: int,
    keys_out: wp.array(dtype=wp.int64),
    vals_out: wp.array(dtype=wp.int32),
):
    g = wp.tid()
    if tile_count[g] == 0:
        return
    r = rect[g]
    k = offsets[g]
    for ty in range(r[1], r[3]):
        for tx in range(r[0], r[2]):
            keys_out[k] = wp.int64(ty * tiles_x + tx) * wp.int64(_KEY_SHIFT) + wp.int64(rank[g])
            vals_out[k] = g
            k += 1


@wp.kernel
def ranges_kernel(keys: wp.array(dtype=wp.int64), count: int, ranges_out: wp.array(dtype=wp.vec2i)):
    i = wp.tid()
    tile = int(keys[i] // wp.int64(_KEY_SHIFT))
    if i == 0:
        ranges_out[tile] = wp.vec2i(i, ranges_out[tile][1])
    else:
        prev = int(keys[i - 1] // wp.int64(_KEY_SHIFT))
        if prev != tile:
            ranges_out[tile] = wp.vec2i(i, ranges_out[tile][1])
    if i == count - 1:
        ranges_out[tile] = wp.vec2i(ranges_out[tile][0], i + 1)
    else:
        nxt = int(keys[i + 1] // wp.int64(_KEY_SHIFT))
        if nxt != tile:
            ranges_out[tile] = wp.vec2i(ranges_out[tile][0], i + 1)


@wp.func
def _gauss_alpha(px: Any, py: Any, m: Any, q: Any, o: Any):
    """(α before the 0.99 clamp, G, power) of one Gaussian at pixel (px, py)."""
    dx = px - m[0]
    dy = py - m[1]
    power = type(px)(-0.5) * (q[0] * dx * dx + q[2] * dy * dy) - q[1] * dx * dy
    G = wp.exp(power)
    return o * G, G, power


@wp.kernel
def composite_kernel(
    ranges: wp.array(dtype=wp.vec2i),
    vals: wp.array(dtype=wp.int32),
    mean2d: wp.array(dtype=Any),
    conic: wp.array(dtype=Any),
    opacity: wp.array(dtype=Any),
    colour: wp.array(dtype=Any),
    depth: wp.array(dtype=Any),
    background: Any,
    tiles_x: int,
    image_colour_out: wp.array2d(dtype=Any),
    image_alpha_out: wp.array2d(dtype=Any),
    image_depth_out: wp.array2d(dtype=Any),
    T_out: wp.array2d(dtype=Any),
    C_out: wp.array2d(dtype=Any),
    D_out: wp.array2d(dtype=Any),
    last_out: wp.array2d(dtype=wp.int32),
):
    y, x = wp.tid()
    px = type(background[0])(float(x))
    py = type(background[0])(float(y))
    zero = type(background[0])(0.0)
    one = type(background[0])(1.0)
    rg = ranges[(y // wp.int32(TILE)) * tiles_x + x // wp.int32(TILE)]
    T = one
    C = background * zero
    D = zero
    last = rg[0]
    for k in range(rg[0], rg[1]):
        g = vals[k]
        a_raw, G, power = _gauss_alpha(px, py, mean2d[g], conic[g], opacity[g])
        alpha = wp.min(type(background[0])(ALPHA_MAX), a_raw)
        if power <= zero and alpha >= type(background[0])(ALPHA_MIN):
            t_next = T * (one - alpha)
            if t_next < type(background[0])(T_MIN):
                break
            C = C + colour[g] * (alpha * T)
            D = D + depth[g] * (alpha * T)
            T = t_next
            last = k + 1
    T_out[y, x] = T
    C_out[y, x] = C
    D_out[y, x] = D
    last_out[y, x] = last
    image_colour_out[y, x] = C + background * T
    image_alpha_out[y, x] = one - T
    if one - T > zero:
        image_depth_out[y, x] = D / (one - T)
    else:
        image_depth_out[y, x] = zero


@wp.kernel
def composite_backward_kernel(
    ranges: wp.array(dtype=wp.vec2i),
    vals: wp.array(dtype=wp.int32),
    mean2d: wp.array(dtype=Any),
    conic: wp.array(dtype=Any),
    opacity: wp.array(dtype=Any),
    colour: wp.array(dtype=Any),
    depth: wp.array(dtype=Any),
    background: Any,
    tiles_x: int,
    T_in: wp.array2d(dtype=Any),
    C_in: wp.array2d(dtype=Any),
    D_in: wp.array2d(dtype=Any),
    last_in: wp.array2d(dtype=wp.int32),
    adj_image_colour_in: wp.array2d(dtype=Any),
    adj_image_alpha_in: wp.array2d(dtype=Any),
    adj_image_depth_in: wp.array2d(dtype=Any),
    adj_mean2d_out: wp.array(dtype=Any),
    adj_conic_out: wp.array(dtype=Any),
    adj_opacity_out: wp.array(dtype=Any),
    adj_colour_out: wp.array(dtype=Any),
    adj_depth_out: wp.array(dtype=Any),
):
    y, x = wp.tid()
    px = type(background[0])(float(x))
    py = type(background[0])(float(y))
    zero = type(background[0])(0.0)
    one = type(background[0])(1.0)
    half = type(background[0])(0.5)
    rg = ranges[(y // wp.int32(TILE)) * tiles_x + x // wp.int32(TILE)]
    T_end = T_in[y, x]
    C_tot = C_in[y, x]
    D_tot = D_in[y, x]
    A = one - T_end
    dC = adj_image_colour_in[y, x]
    dD = zero
    dT_end = wp.dot(dC, background) - adj_image_alpha_in[y, x]
    if A > zero:
        dD = adj_image_depth_in[y, x] / A
        dT_end = dT_end + adj_image_depth_in[y, x] * D_tot / (A * A)
    T = one
    C_pre = C_tot * zero
    D_pre = zero
    for k in range(rg[0], last_in[y, x]):
        g = vals[k]
        m = mean2d[g]
        q = conic[g]
        o = opacity[g]
        a_raw, G, power = _gauss_alpha(px, py, m, q, o)
        alpha = wp.min(type(background[0])(ALPHA_MAX), a_raw)
        if power <= zero and alpha >= type(background[0])(ALPHA_MIN):
            c = colour[g]
            z = depth[g]
            w = alpha * T
            wp.atomic_add(adj_colour_out, g, dC * w)
            wp.atomic_add(adj_depth_out, g, dD * w)
            C_pre = C_pre + c * w
            D_pre = D_pre + z * w
            S_C = C_tot - C_pre
            S_D = D_tot - D_pre
            d_alpha = T * (wp.dot(dC, c) + dD * z) - (wp.dot(dC, S_C) + dD * S_D + dT_end * T_end) / (
                one - alpha
            )
            T = T * (one - alpha)
            if a_raw < type(background[0])(ALPHA_MAX):
                wp.atomic_add(adj_opacity_out, g, d_alpha * G)
                d_pow = d_alpha * a_raw
                dx = px - m[0]
                dy = py - m[1]
                wp.atomic_add(
                    adj_mean2d_out,
                    g,
                    type(m)(d_pow * (q[0] * dx + q[1] * dy), d_pow * (q[1] * dx + q[2] * dy)),
                )
                wp.atomic_add(
                    adj_conic_out,
                    g,
                    type(q)(-half * d_pow * dx * dx, -d_pow * dx * dy, -half * d_pow * dy * dy),
                )


@wp.kernel
def background_adjoint_kernel(
    adj_image_colour_in: wp.array2d(dtype=Any),
    T_in: wp.array2d(dtype=Any),
    adj_background_out: wp.array(dtype=Any),
):
    # colour = C + background · T_end per pixel, so ∂L/∂background = Σ_pixels ∂L/∂colour · T_end.
    y, x = wp.tid()
    wp.atomic_add(adj_background_out, 0, adj_image_colour_in[y, x] * T_in[y, x])
