"""Warp rasterization kernels for the preview renderer.

All kernels are launched on the ``"cpu"`` device only. Warp CPU kernels are compiled C++ that
runs the launch grid *serially*, so the per-triangle / per-particle kernels below can do a
read-compare-write depth test on shared pixels without atomics or locks. (They would race
on a GPU; the renderer never launches them there.)

Conventions: screen-space vertices are ``vec3(column_px, row_px, view_depth_m)``; the depth
buffer stores ``1 / view_depth`` (0 = empty, larger = nearer) because 1/z interpolates
linearly in screen space, which also gives perspective-correct attribute interpolation.
"""

from __future__ import annotations

import warp as wp

# Inclusive coverage test tolerance (barycentric units) so pixel centres that lie exactly on
# a shared edge are not dropped by both neighbours through round-off.
_COVER_EPS = wp.constant(-1.0e-6)


@wp.func
def _edge(ax: float, ay: float, bx: float, by: float, px: float, py: float) -> float:
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


@wp.func
def _pixel_lo(v: float, n: int) -> int:
    # First pixel whose centre (j + 0.5) is >= v, clamped to the image before the float->int
    # conversion so huge coordinates cannot overflow.
    return wp.max(int(wp.ceil(wp.clamp(v - 0.5, -1.0, float(n)))), 0)


@wp.func
def _pixel_hi(v: float, n: int) -> int:
    # Last pixel whose centre is <= v.
    return wp.min(int(wp.floor(wp.clamp(v - 0.5, -1.0, float(n)))), n - 1)


@wp.func
def _lambert(n: wp.vec3, light: wp.vec3, ambient: float) -> float:
    return ambient + (1.0 - ambient) * wp.max(wp.dot(n, light), 0.0)


@wp.kernel
def vertex_normals_kernel(
    x: wp.array(dtype=wp.vec3),
    faces: wp.array(dtype=wp.vec3i),
    normals_out: wp.array(dtype=wp.vec3),
):
    """Accumulates area-weighted face normals_out onto vertices (normals_out must be zeroed)."""
    f = wp.tid()
    t = faces[f]
    p0 = x[t[0]]
    n = wp.cross(x[t[1]] - p0, x[t[2]] - p0)
    wp.atomic_add(normals_out, t[0], n)
    wp.atomic_add(normals_out, t[1], n)
    wp.atomic_add(normals_out, t[2], n)


@wp.kernel
def raster_triangles_kernel(
    screen: wp.array(dtype=wp.vec3),
    world: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    colors: wp.array(dtype=wp.vec3),
    faces: wp.array(dtype=wp.vec3i),
    smooth: int,
    per_vertex_color: int,
    edge_px: float,
    eye: wp.vec3,
    light: wp.vec3,
    ambient: float,
    near: float,
    depth_io: wp.array2d(dtype=float),
    image_out: wp.array2d(dtype=wp.vec3),
):
    """One thread per triangle: z-buffered, two-sided Lambert shading of its covered pixels."""
    f = wp.tid()
    t = faces[f]
    a = screen[t[0]]
    b = screen[t[1]]
    c = screen[t[2]]
    # Triangles crossing the near plane are skipped (no clipping): previews keep the object in
    # front of the camera.
    if a[2] < near or b[2] < near or c[2] < near:
        return
    area = _edge(a[0], a[1], b[0], b[1], c[0], c[1])
    if wp.abs(area) < 1.0e-12:
        return
    height = depth_io.shape[0]
    width = depth_io.shape[1]
    x0 = _pixel_lo(wp.min(wp.min(a[0], b[0]), c[0]), width)
    x1 = _pixel_hi(wp.max(wp.max(a[0], b[0]), c[0]), width)
    y0 = _pixel_lo(wp.min(wp.min(a[1], b[1]), c[1]), height)
    y1 = _pixel_hi(wp.max(wp.max(a[1], b[1]), c[1]), height)
    if x0 > x1 or y0 > y1:
        return

    p0 = world[t[0]]
    nf = wp.cross(world[t[1]] - p0, world[t[2]] - p0)
    # Two-sided lighting: orient every normal of this triangle towards the viewer.
    sgn = 1.0
    if wp.dot(nf, eye - p0) < 0.0:
        sgn = -1.0
    nfl = wp.length(nf)
    flat_shade = ambient
    if nfl > 0.0:
        flat_shade = _lambert(nf * (sgn / nfl), light, ambient)

    c0 = colors[0]
    c1 = c0
    c2 = c0
    if per_vertex_color != 0:
        c0 = colors[t[0]]
        c1 = colors[t[1]]
        c2 = colors[t[2]]
    n0 = normals[t[0]] * sgn
    n1 = normals[t[1]] * sgn
    n2 = normals[t[2]] * sgn

    inv_area = 1.0 / area
    iz0 = 1.0 / a[2]
    iz1 = 1.0 / b[2]
    iz2 = 1.0 / c[2]
    # Pixel distance to edge i is w_i * |area| / |edge i| (for the optional wireframe).
    abs_area = wp.abs(area)
    e0 = abs_area / wp.max(wp.length(wp.vec2(c[0] - b[0], c[1] - b[1])), 1.0e-12)
    e1 = abs_area / wp.max(wp.length(wp.vec2(a[0] - c[0], a[1] - c[1])), 1.0e-12)
    e2 = abs_area / wp.max(wp.length(wp.vec2(b[0] - a[0], b[1] - a[1])), 1.0e-12)

    for py in range(y0, y1 + 1):
        fy = float(py) + 0.5
        for px in range(x0, x1 + 1):
            fx = float(px) + 0.5
            w0 = _edge(b[0], b[1], c[0], c[1], fx, fy) * inv_area
            w1 = _edge(c[0], c[1], a[0], a[1], fx, fy) * inv_area
            w2 = _edge(a[0], a[1], b[0], b[1], fx, fy) * inv_area
            if w0 >= _COVER_EPS and w1 >= _COVER_EPS and w2 >= _COVER_EPS:
                iz = w0 * iz0 + w1 * iz1 + w2 * iz2
                if iz > depth_io[py, px]:
                    depth_io[py, px] = iz
                    # Perspective-correct barycentrics.
                    q0 = w0 * iz0 / iz
                    q1 = w1 * iz1 / iz
                    q2 = w2 * iz2 / iz
                    shade = flat_shade
                    if smooth != 0:
                        n = q0 * n0 + q1 * n1 + q2 * n2
                        nl = wp.length(n)
                        if nl > 1.0e-30:
                            shade = _lambert(n / nl, light, ambient)
                    if edge_px > 0.0:
                        if wp.min(wp.min(w0 * e0, w1 * e1), w2 * e2) < edge_px:
                            shade = shade * 0.45
                    image_out[py, px] = (q0 * c0 + q1 * c1 + q2 * c2) * shade


@wp.kernel
def raster_points_kernel(
    screen: wp.array(dtype=wp.vec3),
    radius_px: wp.array(dtype=float),
    radius_m: wp.array(dtype=float),
    colors: wp.array(dtype=wp.vec3),
    per_vertex_color: int,
    light_view: wp.vec3,
    ambient: float,
    near: float,
    depth_io: wp.array2d(dtype=float),
    image_out: wp.array2d(dtype=wp.vec3),
):
    """One thread per particle: a z-buffered, Lambert-shaded sphere impostor."""
    i = wp.tid()
    s = screen[i]
    if s[2] < near:
        return
    rp = radius_px[i]
    rm = radius_m[i]
    height = depth_io.shape[0]
    width = depth_io.shape[1]
    x0 = _pixel_lo(s[0] - rp, width)
    x1 = _pixel_hi(s[0] + rp, width)
    y0 = _pixel_lo(s[1] - rp, height)
    y1 = _pixel_hi(s[1] + rp, height)
    col = colors[0]
    if per_vertex_color != 0:
        col = colors[i]
    inv_rp = 1.0 / rp
    for py in range(y0, y1 + 1):
        dy = (float(py) + 0.5 - s[1]) * inv_rp
        for px in range(x0, x1 + 1):
            dx = (float(px) + 0.5 - s[0]) * inv_rp
            d2 = dx * dx + dy * dy
            if d2 <= 1.0:
                nz = wp.sqrt(1.0 - d2)
                z = s[2] - rm * nz
                if z > near:
                    iz = 1.0 / z
                    if iz > depth_io[py, px]:
                        depth_io[py, px] = iz
                        # Camera frame: x right, y up, z forward; the visible cap faces -z.
                        n = wp.vec3(dx, -dy, -nz)
                        image_out[py, px] = col * _lambert(n, light_view, ambient)


@wp.kernel
def shadow_triangles_kernel(
    ls: wp.array(dtype=wp.vec3),
    faces: wp.array(dtype=wp.vec3i),
    smap_io: wp.array2d(dtype=float),
):
    """Orthographic light-space rasterization keeping the largest height towards the light."""
    f = wp.tid()
    t = faces[f]
    a = ls[t[0]]
    b = ls[t[1]]
    c = ls[t[2]]
    # Non-finite vertices are flagged with a hugely negative height.
    if wp.min(wp.min(a[2], b[2]), c[2]) < -1.0e29:
        return
    area = _edge(a[0], a[1], b[0], b[1], c[0], c[1])
    if wp.abs(area) < 1.0e-12:
        return
    n = smap_io.shape[0]
    x0 = _pixel_lo(wp.min(wp.min(a[0], b[0]), c[0]), n)
    x1 = _pixel_hi(wp.max(wp.max(a[0], b[0]), c[0]), n)
    y0 = _pixel_lo(wp.min(wp.min(a[1], b[1]), c[1]), n)
    y1 = _pixel_hi(wp.max(wp.max(a[1], b[1]), c[1]), n)
    inv_area = 1.0 / area
    for py in range(y0, y1 + 1):
        fy = float(py) + 0.5
        for px in range(x0, x1 + 1):
            fx = float(px) + 0.5
            w0 = _edge(b[0], b[1], c[0], c[1], fx, fy) * inv_area
            w1 = _edge(c[0], c[1], a[0], a[1], fx, fy) * inv_area
            w2 = 1.0 - w0 - w1
            if w0 >= _COVER_EPS and w1 >= _COVER_EPS and w2 >= _COVER_EPS:
                h = w0 * a[2] + w1 * b[2] + w2 * c[2]
                if h > smap_io[py, px]:
                    smap_io[py, px] = h


@wp.kernel
def shadow_points_kernel(
    ls: wp.array(dtype=wp.vec3),
    radius_px: wp.array(dtype=float),
    radius_m: wp.array(dtype=float),
    smap_io: wp.array2d(dtype=float),
):
    """Light-space discs for particle shadows."""
    i = wp.tid()
    s = ls[i]
    if s[2] < -1.0e29:
        return
    rp = wp.max(radius_px[i], 0.5)
    n = smap_io.shape[0]
    x0 = _pixel_lo(s[0] - rp, n)
    x1 = _pixel_hi(s[0] + rp, n)
    y0 = _pixel_lo(s[1] - rp, n)
    y1 = _pixel_hi(s[1] + rp, n)
    for py in range(y0, y1 + 1):
        dy = (float(py) + 0.5 - s[1]) / rp
        for px in range(x0, x1 + 1):
            dx = (float(px) + 0.5 - s[0]) / rp
            d2 = dx * dx + dy * dy
            if d2 <= 1.0:
                h = s[2] + radius_m[i] * wp.sqrt(1.0 - d2)
                if h > smap_io[py, px]:
                    smap_io[py, px] = h


@wp.func
def _ray_dir(
    right: wp.vec3, up: wp.vec3, fwd: wp.vec3, focal: float, cx: float, cy: float, px: float, py: float
) -> wp.vec3:
    # Unnormalised: its component along fwd is exactly `focal`, so t * focal is view depth.
    return fwd * focal + right * (px - cx) - up * (py - cy)


@wp.func
def _frac(v: float) -> float:
    return v - wp.floor(v)


@wp.func
def _box_filtered_stripe(p: float, w: float) -> float:
    # Integral of the +-1 square wave of period 2 over [p - w/2, p + w/2], divided by w
    # (analytic box filter, so the checkerboard does not alias towards the horizon).
    return 2.0 * (wp.abs(_frac((p - 0.5 * w) * 0.5) - 0.5) - wp.abs(_frac((p + 0.5 * w) * 0.5) - 0.5)) / w


@wp.func
def _ground_base(
    eye: wp.vec3,
    right: wp.vec3,
    up: wp.vec3,
    fwd: wp.vec3,
    focal: float,
    cx: float,
    cy: float,
    fx: float,
    fy: float,
    hit: wp.vec3,
    ground_y: float,
    tile: float,
    color_a: wp.vec3,
    color_b: wp.vec3,
) -> wp.vec3:
    # Pixel footprint on the plane, from the neighbouring pixels' rays, sets the filter width.
    dx = _ray_dir(right, up, fwd, focal, cx, cy, fx + 1.0, fy)
    dy = _ray_dir(right, up, fwd, focal, cx, cy, fx, fy + 1.0)
    wx = 4.0 * tile
    wz = 4.0 * tile
    if dx[1] < 0.0 and dy[1] < 0.0:
        hx = eye + dx * ((ground_y - eye[1]) / dx[1])
        hy = eye + dy * ((ground_y - eye[1]) / dy[1])
        wx = wp.abs(hx[0] - hit[0]) + wp.abs(hy[0] - hit[0]) + 1.0e-6 * tile
        wz = wp.abs(hx[2] - hit[2]) + wp.abs(hy[2] - hit[2]) + 1.0e-6 * tile
    wx = wp.min(wx / tile, 4.0)
    wz = wp.min(wz / tile, 4.0)
    checker = 0.5 - 0.5 * _box_filtered_stripe(hit[0] / tile, wx) * _box_filtered_stripe(hit[2] / tile, wz)
    return color_a + (color_b - color_a) * checker


@wp.kernel
def ground_kernel(
    has_ground: int,
    eye: wp.vec3,
    right: wp.vec3,
    up: wp.vec3,
    fwd: wp.vec3,
    focal: float,
    cx: float,
    cy: float,
    ground_y: float,
    tile: float,
    center: wp.vec3,
    fade0: float,
    fade1: float,
    color_a: wp.vec3,
    color_b: wp.vec3,
    background: wp.vec3,
    lit: float,
    depth_out: wp.array2d(dtype=float),
    image_out: wp.array2d(dtype=wp.vec3),
):
    """One thread per pixel: clears to the background or ray-casts the ground plane y = ground_y.

    The plane carries a box-filtered checkerboard that fades into the background with distance
    from ``center`` between ``fade0`` and ``fade1`` metres (no aliasing towards the horizon).
    """
    i, j = wp.tid()
    color = background
    inv_depth = 0.0
    if has_ground != 0:
        fx = float(j) + 0.5
        fy = float(i) + 0.5
        d = _ray_dir(right, up, fwd, focal, cx, cy, fx, fy)
        if d[1] < 0.0:
            t = (ground_y - eye[1]) / d[1]
            hit = eye + d * t
            r = wp.length(wp.vec2(hit[0] - center[0], hit[2] - center[2]))
            fade = wp.clamp((r - fade0) / (fade1 - fade0), 0.0, 1.0)
            if fade < 1.0:
                base = _ground_base(
                    eye, right, up, fwd, focal, cx, cy, fx, fy, hit, ground_y, tile, color_a, color_b
                )
                color = base * lit * (1.0 - fade) + background * fade
            inv_depth = 1.0 / (t * focal)
    depth_out[i, j] = inv_depth
    image_out[i, j] = color


@wp.kernel
def ground_shadow_kernel(
    i0: int,
    j0: int,
    eye: wp.vec3,
    right: wp.vec3,
    up: wp.vec3,
    fwd: wp.vec3,
    focal: float,
    cx: float,
    cy: float,
    ground_y: float,
    tile: float,
    center: wp.vec3,
    fade0: float,
    fade1: float,
    color_a: wp.vec3,
    color_b: wp.vec3,
    background: wp.vec3,
    lit: float,
    shadowed: float,
    smap: wp.array2d(dtype=float),
    la: wp.vec3,
    lb: wp.vec3,
    lw: wp.vec3,
    s_u0: float,
    s_v0: float,
    s_scale: float,
    s_bias: float,
    image_out: wp.array2d(dtype=wp.vec3),
):
    """Re-shades shadowed ground pixels of the sub-rectangle starting at pixel (i0, j0).

    Expects ``image_out`` to hold the unshadowed ground from ``ground_kernel``; a 3x3 PCF lookup in
    the light-space height map gives soft shadow edges. Unshadowed pixels are left untouched.
    """
    ti, tj = wp.tid()
    i = ti + i0
    j = tj + j0
    fx = float(j) + 0.5
    fy = float(i) + 0.5
    d = _ray_dir(right, up, fwd, focal, cx, cy, fx, fy)
    if d[1] >= 0.0:
        return
    hit = eye + d * ((ground_y - eye[1]) / d[1])
    su = (wp.dot(hit, la) - s_u0) * s_scale
    sv = (wp.dot(hit, lb) - s_v0) * s_scale
    n = smap.shape[0]
    if su < -2.0 or sv < -2.0 or su > float(n) + 2.0 or sv > float(n) + 2.0:
        return
    h = wp.dot(hit, lw) + s_bias
    iu = int(wp.floor(su))
    iv = int(wp.floor(sv))
    occluded = 0.0
    for di in range(-1, 2):
        for dj in range(-1, 2):
            ri = iv + di
            rj = iu + dj
            if ri >= 0 and ri < n and rj >= 0 and rj < n:
                if smap[ri, rj] > h:
                    occluded += 1.0
    if occluded == 0.0:
        return
    r = wp.length(wp.vec2(hit[0] - center[0], hit[2] - center[2]))
    fade = wp.clamp((r - fade0) / (fade1 - fade0), 0.0, 1.0)
    base = _ground_base(eye, right, up, fwd, focal, cx, cy, fx, fy, hit, ground_y, tile, color_a, color_b)
    shade = lit + (shadowed - lit) * occluded / 9.0
    image_out[i, j] = base * shade * (1.0 - fade) + background * fade


@wp.kernel
def resolve_kernel(image: wp.array2d(dtype=wp.vec3), ss: int, out: wp.array3d(dtype=wp.uint8)):
    """Box-downsamples the ss x ss supersampled float image to uint8 RGB."""
    i, j = wp.tid()
    acc = wp.vec3(0.0)
    for a in range(ss):
        for b in range(ss):
            acc += image[i * ss + a, j * ss + b]
    acc = acc / float(ss * ss)
    for k in range(3):
        out[i, j, k] = wp.uint8(int(wp.clamp(acc[k], 0.0, 1.0) * 255.0 + 0.5))
