"""Per-Gaussian projection: world → camera → image, the EWA 2D covariance and view-dependent SH colour.

Written from the equations of Zwicker et al. 2002 (EWA splatting: Σ' = J W Σ Wᵀ Jᵀ with J the Jacobian of the
perspective map) and Kerbl et al. 2023 (3D Gaussian splatting: Σ = R S Sᵀ Rᵀ from a quaternion and scales, a
low-pass dilation of Σ', the conic Σ'⁻¹, a 3σ screen radius, real SH colours of degree ≤ 3). The kernel is
straight-line code, so Warp's automatic adjoint differentiates it (no loop-carried state).
"""

from __future__ import annotations

from typing import Any

import warp as wp

#: Tile edge [px] of the binning.
TILE = 16


@wp.func
def quat_to_matrix(q: Any):
    """Rotation matrix of the quaternion q = (w, x, y, z), normalised here (so any non-zero q is valid)."""
    n = wp.length(q)
    w = q[0] / n
    x = q[1] / n
    y = q[2] / n
    z = q[3] / n
    one = type(n)(1.0)
    two = type(n)(2.0)
    return wp.matrix(
        one - two * (y * y + z * z),
        two * (x * y - w * z),
        two * (x * z + w * y),
        two * (x * y + w * z),
        one - two * (x * x + z * z),
        two * (y * z - w * x),
        two * (x * z - w * y),
        two * (y * z + w * x),
        one - two * (x * x + y * y),
        shape=(3, 3),
    )


@wp.func
def sh_colour(sh: Any, g: int, degree: int, d: Any):
    """Real SH (degree ≤ 3, the constants of Y_lm in the order 3DGS files use).

    RGB = Σ_k Y_k(d) sh[g, k] + 0.5, clamped at 0; d is the unit viewing direction (camera → Gaussian)."""
    zero = type(d[0])(0.0)
    c = type(d[0])(0.28209479177387814) * sh[g, 0]
    if degree > 0:
        x = d[0]
        y = d[1]
        z = d[2]
        c1 = type(x)(0.4886025119029199)
        c = c - c1 * y * sh[g, 1] + c1 * z * sh[g, 2] - c1 * x * sh[g, 3]
        if degree > 1:
            xx = x * x
            yy = y * y
            zz = z * z
            c = (
                c
                + type(x)(1.0925484305920792) * x * y * sh[g, 4]
                + type(x)(-1.0925484305920792) * y * z * sh[g, 5]
                + type(x)(0.31539156525252005) * (type(x)(2.0) * zz - xx - yy) * sh[g, 6]
                + type(x)(-1.0925484305920792) * x * z * sh[g, 7]
                + type(x)(0.5462742152960396) * (xx - yy) * sh[g, 8]
            )
            if degree > 2:
                three = type(x)(3.0)
                four = type(x)(4.0)
                c = (
                    c
                    + type(x)(-0.5900435899266435) * y * (three * xx - yy) * sh[g, 9]
                    + type(x)(2.890611442640554) * x * y * z * sh[g, 10]
                    + type(x)(-0.4570457994644658) * y * (four * zz - xx - yy) * sh[g, 11]
                    + type(x)(0.3731763325901154)
                    * z
                    * (type(x)(2.0) * zz - three * xx - three * yy)
                    * sh[g, 12]
                    + type(x)(-0.4570457994644658) * x * (four * zz - xx - yy) * sh[g, 13]
                    + type(x)(1.445305721320277) * z * (xx - yy) * sh[g, 14]
                    + type(x)(-0.5900435899266435) * x * (xx - three * yy) * sh[g, 15]
                )
    half = type(zero)(0.5)
    return wp.max(c + type(c)(half, half, half), type(c)(zero, zero, zero))


@wp.kernel
def project_kernel(
    means: wp.array(dtype=Any),
    quats: wp.array(dtype=Any),
    log_scales: wp.array(dtype=Any),
    opacity_logits: wp.array(dtype=Any),
    sh: wp.array2d(dtype=Any),
    sh_degree: int,
    transforms: wp.array(dtype=Any),
    has_transform: int,
    light: wp.array(dtype=Any),
    has_light: int,
    rot: Any,
    trans: Any,
    campos: Any,
    fx: Any,
    fy: Any,
    cx: Any,
    cy: Any,
    lim_x_neg: Any,
    lim_x_pos: Any,
    lim_y_neg: Any,
    lim_y_pos: Any,
    near: Any,
    eps2d: Any,
    tiles_x: int,
    tiles_y: int,
    mean2d_out: wp.array(dtype=Any),
    conic_out: wp.array(dtype=Any),
    depth_out: wp.array(dtype=Any),
    opacity_out: wp.array(dtype=Any),
    colour_out: wp.array(dtype=Any),
    rect_out: wp.array(dtype=wp.vec4i),
    tile_count_out: wp.array(dtype=wp.int32),
):
    g = wp.tid()
    mu = means[g]
    p = rot * mu + trans
    zero = type(fx)(0.0)
    one = type(fx)(1.0)
    # Culled Gaussians still get finite outputs (z clamped to near) so the adjoint stays finite; they touch no
    # tile, so the compositor never reads them.
    z = wp.max(p[2], near)
    tx = wp.clamp(p[0] / z, -lim_x_neg, lim_x_pos) * z
    ty = wp.clamp(p[1] / z, -lim_y_neg, lim_y_pos) * z
    iz = one / z
    # Jacobian of (fx x/z + cx, fy y/z + cy) at the (clamped) camera point
    J = wp.matrix(fx * iz, zero, -fx * tx * iz * iz, zero, fy * iz, -fy * ty * iz * iz, shape=(2, 3))
    Rq = quat_to_matrix(quats[g])
    s = log_scales[g]
    S = wp.matrix(wp.exp(s[0]), zero, zero, zero, wp.exp(s[1]), zero, zero, zero, wp.exp(s[2]), shape=(3, 3))
    M = rot * Rq * S
    if has_transform != 0:
        # an embedded Gaussian deformed by the local linear map A: Σ = A R S Sᵀ Rᵀ Aᵀ
        M = rot * transforms[g] * Rq * S
    T = J * M
    cov = T * wp.transpose(T)
    a = cov[0, 0] + eps2d
    b = cov[0, 1]
    c = cov[1, 1] + eps2d
    det = a * c - b * b
    inv_det = one / wp.max(det, type(fx)(1.0e-30))
    conic_out[g] = type(mu)(c * inv_det, -b * inv_det, a * inv_det)
    m2 = wp.vector(fx * p[0] * iz + cx, fy * p[1] * iz + cy)
    mean2d_out[g] = m2
    depth_out[g] = p[2]
    opacity_out[g] = one / (one + wp.exp(-opacity_logits[g]))
    view = wp.normalize(mu - campos)
    rgb = sh_colour(sh, g, sh_degree, view)
    if has_light != 0:
        # Lambertian shading on the splat's normal: its thinnest axis (a flat splat's normal; for a
        # "triangles" binding A R e_z is the deformed triangle's unit normal), turned to face the camera
        # (both sides of a cloth are lit, as two-sided lighting does). light[0] = (ambient, L) with L the
        # directional light's direction × intensity; light[1][0] = a headlight's intensity (a light at the
        # camera, as MuJoCo's default one): shade = ambient + max(0, n·L) + headlight · |n·v|.
        Mw = Rq
        if has_transform != 0:
            Mw = transforms[g] * Rq
        e = type(mu)(zero, zero, one)
        if s[0] <= s[1] and s[0] <= s[2]:
            e = type(mu)(one, zero, zero)
        elif s[1] <= s[2]:
            e = type(mu)(zero, one, zero)
        nrm = wp.normalize(Mw * e)
        facing = wp.dot(nrm, view)
        if facing > zero:
            nrm = -nrm
        lt = light[0]
        hl = light[1]
        direct = lt[1] * nrm[0] + lt[2] * nrm[1] + lt[3] * nrm[2]
        shade = lt[0] + wp.max(direct, zero) + hl[0] * wp.abs(facing)
        rgb = rgb * shade
    colour_out[g] = rgb
    # screen extent: 3σ of the larger eigenvalue of the dilated covariance, in whole tiles
    mid = type(fx)(0.5) * (a + c)
    lam = mid + wp.sqrt(wp.max(type(fx)(0.1), mid * mid - det))
    r = wp.ceil(type(fx)(3.0) * wp.sqrt(lam))
    ftile = type(fx)(16.0)
    x0 = wp.clamp(int(wp.floor((m2[0] - r) / ftile)), 0, tiles_x)
    x1 = wp.clamp(int(wp.floor((m2[0] + r) / ftile)) + 1, 0, tiles_x)
    y0 = wp.clamp(int(wp.floor((m2[1] - r) / ftile)), 0, tiles_y)
    y1 = wp.clamp(int(wp.floor((m2[1] + r) / ftile)) + 1, 0, tiles_y)
    n = (x1 - x0) * (y1 - y0)
    if p[2] <= near or det <= zero:
        n = 0
    rect_out[g] = wp.vec4i(x0, y0, x1, y1)
    tile_count_out[g] = n
