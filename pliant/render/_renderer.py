"""Headless z-buffer preview renderer built on Warp CPU kernels."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np
import warp as wp

from . import _kernels as K
from ._camera import Camera, as_points

__all__ = ["Renderer", "default_point_radius", "resolve_colors", "DEFAULT_COLOR"]

DEVICE = "cpu"
DEFAULT_COLOR = (0.91, 0.42, 0.16)
DEFAULT_BACKGROUND = (0.95, 0.96, 0.97)
DEFAULT_LIGHT = (-0.35, 1.0, 0.55)
_GROUND_A = np.array([0.86, 0.87, 0.89])
_GROUND_B = np.array([0.72, 0.73, 0.76])
_SHADOW_RES = 512

ColorLike = Sequence[float] | np.ndarray


def _rgb(c: object, name: str) -> np.ndarray:
    arr = np.asarray(c, dtype=np.float64).reshape(-1)
    if arr.shape != (3,):
        raise ValueError(f"{name} must be an RGB triple, got {c!r}")
    if np.issubdtype(np.asarray(c).dtype, np.integer) or arr.max() > 1.0:
        arr = arr / 255.0
    return np.clip(arr, 0.0, 1.0)


def resolve_colors(colors: object, n: int, default: np.ndarray) -> tuple[np.ndarray, bool]:
    """Normalises a colour argument.

    Args:
        colors: ``None``, one RGB triple, or per-vertex colours [n, 3]; floats in [0, 1] or
            integers in [0, 255].
        n: Number of vertices/particles.
        default: Colour [3] used when ``colors`` is None.

    Returns:
        ``(table, per_vertex)``: float32 [n, 3] (or [1, 3]) colours in [0, 1] and whether they
        are per vertex.
    """
    if colors is None:
        return np.asarray(default, np.float32).reshape(1, 3), False
    raw = np.asarray(colors)
    arr = raw.astype(np.float64)
    if arr.size == 3 and arr.ndim <= 1:
        return _rgb(arr, "colors").astype(np.float32).reshape(1, 3), False
    if arr.shape != (n, 3):
        raise ValueError(f"colors must be an RGB triple or have shape [{n}, 3], got {arr.shape}")
    if np.issubdtype(raw.dtype, np.integer):
        arr = arr / 255.0
    return np.clip(arr, 0.0, 1.0).astype(np.float32), True


def default_point_radius(points: np.ndarray) -> float:
    """Default particle radius: 45% of the median nearest-neighbour spacing, in metres.

    Args:
        points: Positions [N, 3] in metres.

    Returns:
        Radius in metres (0.0 when it cannot be estimated, e.g. a single particle).
    """
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) < 2:
        return 0.0
    from scipy.spatial import cKDTree

    # A subsample of query points is enough for a median and keeps this O(N log N).
    rng = np.random.default_rng(0)
    query = pts if len(pts) <= 4096 else pts[rng.choice(len(pts), 4096, replace=False)]
    dist, _ = cKDTree(pts).query(query, k=2)
    nn = dist[:, 1]
    nn = nn[nn > 0.0]
    return 0.45 * float(np.median(nn)) if len(nn) else 0.0


def _nice_tile(length: float) -> float:
    """Largest 1/2/5 x 10^k value not above ``length``."""
    k = math.floor(math.log10(length))
    for m in (5.0, 2.0, 1.0):
        if m * 10.0**k <= length:
            return m * 10.0**k
    return 10.0**k


def _wrap(arr: np.ndarray, dtype: object) -> wp.array:
    # Zero-copy view of a contiguous host array (the kernels read/write NumPy memory directly).
    return wp.array(np.ascontiguousarray(arr), dtype=dtype, device=DEVICE, copy=False)


class Renderer:
    """Headless software rasterizer for quick previews of meshes and particle sets.

    It always runs on Warp's CPU device (inputs are copied to the host), whatever device the
    simulation uses: Warp CPU kernels run serially, so the per-triangle depth test needs no
    atomics. Typical cost: a few ms to ~20 ms per 640x480 frame for 20k triangles on one core.

    Args:
        camera: Camera (image size and projection).
        ground: ``True`` draws a checkerboard ground plane at y = 0, a float at that height,
            ``False``/``None`` draws none. The plane is seen only from above.
        background: RGB background colour (floats in [0, 1] or ints in [0, 255]).
        light_dir: Direction *towards* the (directional) light, world frame.
        color: Default object colour when ``render`` gets no ``colors``.
        ambient: Ambient fraction in [0, 1]; the rest is Lambertian diffuse.
        shading: ``"smooth"`` (interpolated area-weighted vertex normals) or ``"flat"``.
        shadows: Cast the object's shadow on the ground (orthographic shadow map).
        ground_tile: Checker size in metres; ``None`` picks a round value from the camera
            distance.
        edges: Darken triangle edges (wireframe overlay), about 1 output pixel wide.
        supersample: Render at ``supersample`` times the resolution and box-filter down
            (anti-aliasing; cost grows with its square).
    """

    def __init__(
        self,
        camera: Camera,
        *,
        ground: bool | float | None = True,
        background: ColorLike = DEFAULT_BACKGROUND,
        light_dir: Sequence[float] | np.ndarray = DEFAULT_LIGHT,
        color: ColorLike = DEFAULT_COLOR,
        ambient: float = 0.35,
        shading: Literal["smooth", "flat"] = "smooth",
        shadows: bool = True,
        ground_tile: float | None = None,
        edges: bool = False,
        supersample: int = 1,
    ) -> None:
        if shading not in ("smooth", "flat"):
            raise ValueError(f"shading must be 'smooth' or 'flat', got {shading!r}")
        if not 0.0 <= ambient <= 1.0:
            raise ValueError(f"ambient must be in [0, 1], got {ambient}")
        if int(supersample) < 1:
            raise ValueError(f"supersample must be >= 1, got {supersample}")
        light = np.asarray(light_dir, np.float64).reshape(3)
        if not np.linalg.norm(light) > 0.0:
            raise ValueError("light_dir must be non-zero")
        self.camera = camera
        if ground is None or ground is False:
            self.ground_height: float | None = None
        elif ground is True:
            self.ground_height = 0.0
        else:
            self.ground_height = float(ground)
        self.background = _rgb(background, "background")
        self.light_dir = light / np.linalg.norm(light)
        self.color = _rgb(color, "color")
        self.ambient = float(ambient)
        self.shading = shading
        self.shadows = bool(shadows)
        self.ground_tile = float(ground_tile) if ground_tile is not None else None
        self.edges = bool(edges)
        self.supersample = int(supersample)
        self._ground_cache: tuple[tuple, np.ndarray, np.ndarray] | None = None
        self._light_frame = (np.zeros(3), np.zeros(3), self.light_dir)  # set by _shadow_pass
        self._buffers: dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    # ------------------------------------------------------------------------------------------
    def _get_buffers(self, h: int, w: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        s = self.supersample
        key = (h, w, s)
        if key not in self._buffers:
            self._buffers = {
                key: (
                    np.zeros((h * s, w * s), np.float32),
                    np.zeros((h * s, w * s, 3), np.float32),
                    np.zeros((_SHADOW_RES, _SHADOW_RES), np.float32),
                )
            }
        return self._buffers[key]

    def render(
        self,
        points: object,
        faces: object | None = None,
        *,
        colors: object | None = None,
        point_radius: float | np.ndarray | None = None,
        point_radius_px: float | None = None,
    ) -> np.ndarray:
        """Renders one frame.

        Args:
            points: Vertex or particle positions [N, 3] in metres (NumPy, Warp or array-like);
                non-finite rows are not drawn.
            faces: Triangle vertex indices [F, 3]; ``None`` draws particles as shaded spheres.
            colors: One RGB triple or per-vertex colours [N, 3] (floats in [0, 1] or uint8).
            point_radius: Particle radius in metres (scalar or per particle [N]).
            point_radius_px: Particle radius in output pixels (used when ``point_radius`` is
                None). With neither given, 45% of the median nearest-neighbour spacing.

        Returns:
            RGB image, uint8 [height, width, 3].
        """
        cam = self.camera
        pts = as_points(points)
        n = len(pts)
        ss = self.supersample
        H, W = cam.height, cam.width
        Hs, Ws = H * ss, W * ss
        depth, image, smap = self._get_buffers(H, W)

        right, up, fwd = cam.basis()
        focal = cam.focal_px * ss
        near = cam.near_plane
        # Rows the float32 kernels cannot hold (|x| > 3.4e38 overflows to inf) are not drawn, like NaNs.
        with np.errstate(over="ignore"):
            valid = np.all(np.isfinite(pts.astype(np.float32)), axis=1)
        world = np.where(valid[:, None], pts, 0.0)
        rel = world - cam.eye
        zc = rel @ fwd
        zc = np.where(valid, zc, -1.0)  # invalid rows are rejected by the near-plane test
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.where(zc > near, focal / zc, 0.0)
        screen = np.stack([0.5 * Ws + (rel @ right) * inv, 0.5 * Hs - (rel @ up) * inv, zc], axis=1)
        with np.errstate(over="ignore"):  # far off-screen points: ±inf pixels, clipped by the kernels
            screen = screen.astype(np.float32)
        table, per_vertex = resolve_colors(colors, n, self.color)

        tri = None
        radius_m = radius_px = None
        if faces is not None:
            tri = np.asarray(faces.numpy() if hasattr(faces, "numpy") else faces)
            if tri.ndim != 2 or tri.shape[1] != 3:
                raise ValueError(f"faces must have shape [F, 3], got {tri.shape}")
            tri = tri.astype(np.int32, copy=False)
            if len(tri) and (tri.min() < 0 or tri.max() >= n):
                raise ValueError("faces index out of range of points")
        elif n:
            radius_m, radius_px = self._particle_radii(world, zc, valid, focal, point_radius, point_radius_px)

        has_geometry = n > 0 and (tri is None or len(tri) > 0) and bool(valid.any())
        world32 = world.astype(np.float32)
        wp_world = _wrap(world32, wp.vec3) if n else None
        wp_tri = _wrap(tri, wp.vec3i) if tri is not None and len(tri) else None

        # 1) shadow map, 2) ground/background (which reads it), 3) object.
        g = self.ground_height
        has_ground = g is not None and cam.eye[1] > g
        shadow_args = self._shadow_pass(world32, valid, wp_tri, radius_m, smap, has_ground and has_geometry)
        wp_depth = _wrap(depth, float)
        wp_image = _wrap(image, wp.vec3)
        ground_args = self._ground_inputs(has_ground, focal, Hs, Ws)
        self._draw_ground(
            image, depth, wp_image, wp_depth, ground_args, shadow_args, has_ground, focal, Hs, Ws
        )

        if has_geometry:
            wp_screen = _wrap(screen, wp.vec3)
            wp_colors = _wrap(table, wp.vec3)
            if wp_tri is not None:
                self._draw_triangles(
                    n, wp_screen, wp_world, wp_colors, wp_tri, per_vertex, wp_depth, wp_image
                )
            elif tri is None:
                assert radius_px is not None and radius_m is not None  # set above for points without faces
                light_view = np.array([self.light_dir @ right, self.light_dir @ up, self.light_dir @ fwd])
                wp.launch(
                    K.raster_points_kernel,
                    dim=n,
                    inputs=[
                        wp_screen,
                        _wrap(radius_px, float),
                        _wrap(radius_m, float),
                        wp_colors,
                        int(per_vertex),
                        wp.vec3(*light_view),
                        self.ambient,
                        float(near),
                        wp_depth,
                        wp_image,
                    ],
                    device=DEVICE,
                )

        out = np.empty((H, W, 3), np.uint8)
        wp.launch(K.resolve_kernel, dim=(H, W), inputs=[wp_image, ss, _wrap(out, wp.uint8)], device=DEVICE)
        return out

    def _draw_ground(
        self,
        image: np.ndarray,
        depth: np.ndarray,
        wp_image: wp.array,
        wp_depth: wp.array,
        ground_args: list,
        shadow_args: list | None,
        has_ground: bool,
        focal: float,
        Hs: int,
        Ws: int,
    ) -> None:
        """Fill ``image`` / ``depth`` [Hs, Ws] with the ground and background (cached per camera and setting),
        then darken the screen rectangle the objects' shadow can fall in (``shadow_args``, if any)."""
        # The unshadowed ground only depends on the camera and settings: compute it once and
        # copy it per frame; then re-shade just the screen rectangle the shadow can fall in.
        key = (
            tuple(self.camera.eye),
            tuple(self.camera.target),
            tuple(self.camera.up),
            self.camera.fov_y,
            Hs,
            Ws,
            has_ground,
            self.ground_height,
            self.ground_tile,
            tuple(self.background),
            tuple(self.light_dir),
            self.ambient,
        )
        if self._ground_cache is None or self._ground_cache[0] != key:
            wp.launch(K.ground_kernel, dim=(Hs, Ws), inputs=[*ground_args, wp_depth, wp_image], device=DEVICE)
            self._ground_cache = (key, image.copy(), depth.copy())
        else:
            np.copyto(image, self._ground_cache[1])
            np.copyto(depth, self._ground_cache[2])
        if shadow_args is not None:
            rect = self._shadow_rect(shadow_args, focal, Hs, Ws)
            if rect is not None:
                i0, i1, j0, j1 = rect
                wp.launch(
                    K.ground_shadow_kernel,
                    dim=(i1 - i0, j1 - j0),
                    inputs=[i0, j0, *ground_args[1:], self._shadow_level(), *shadow_args, wp_image],
                    device=DEVICE,
                )

    def _draw_triangles(
        self,
        n: int,
        wp_screen: wp.array,
        wp_world: wp.array | None,
        wp_colors: wp.array,
        wp_tri: wp.array,
        per_vertex: bool,
        wp_depth: wp.array,
        wp_image: wp.array,
    ) -> None:
        """Rasterise the triangles ``wp_tri`` over ``n`` vertices (screen and world positions, colours) into
        ``wp_depth`` / ``wp_image``, with smooth (per-vertex) normals when ``shading`` is "smooth"."""
        normals = np.zeros((n, 3), np.float32)
        wp_normals = _wrap(normals, wp.vec3)
        smooth = self.shading == "smooth"
        if smooth:
            wp.launch(
                K.vertex_normals_kernel,
                dim=wp_tri.shape[0],
                inputs=[wp_world, wp_tri, wp_normals],
                device=DEVICE,
            )
        wp.launch(
            K.raster_triangles_kernel,
            dim=wp_tri.shape[0],
            inputs=[
                wp_screen,
                wp_world,
                wp_normals,
                wp_colors,
                wp_tri,
                int(smooth),
                int(per_vertex),
                0.5 * self.supersample if self.edges else 0.0,
                wp.vec3(*self.camera.eye),
                wp.vec3(*self.light_dir),
                self.ambient,
                float(self.camera.near_plane),
                wp_depth,
                wp_image,
            ],
            device=DEVICE,
        )

    # ------------------------------------------------------------------------------------------
    def _particle_radii(
        self,
        world: np.ndarray,
        zc: np.ndarray,
        valid: np.ndarray,
        focal: float,
        point_radius: float | np.ndarray | None,
        point_radius_px: float | None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per-particle radii in metres and in (supersampled) pixels, both float32 [N]."""
        n = len(world)
        zpos = np.where(zc > 0.0, zc, 1.0)
        if point_radius is None and point_radius_px is None:
            r = default_point_radius(world[valid])
            point_radius = r if r > 0.0 else 0.01 * self.camera.distance
        if point_radius is not None:
            rm = np.broadcast_to(np.asarray(point_radius, np.float64), (n,))
            rp = rm * focal / zpos
        else:
            assert point_radius_px is not None  # one of the two radii is set above
            rp = np.full(n, float(point_radius_px) * self.supersample)
            rm = rp * zpos / focal
        # At least ~1 output pixel so tiny or distant particles stay visible.
        rp = np.maximum(rp, 0.75 * self.supersample)
        return rm.astype(np.float32), rp.astype(np.float32)

    def _ground_inputs(self, has_ground: bool, focal: float, Hs: int, Ws: int) -> list:
        """Ground-kernel arguments between the launch offset and the shadow arguments."""
        cam = self.camera
        right, up, fwd = cam.basis()
        g = self.ground_height if self.ground_height is not None else 0.0
        tile = self.ground_tile or _nice_tile(cam.distance / 5.0)
        center = np.array([cam.target[0], g, cam.target[2]])
        lit = self.ambient + (1.0 - self.ambient) * max(self.light_dir[1], 0.0)
        return [
            int(has_ground),
            wp.vec3(*cam.eye),
            wp.vec3(*right),
            wp.vec3(*up),
            wp.vec3(*fwd),
            float(focal),
            0.5 * Ws,
            0.5 * Hs,
            float(g),
            float(tile),
            wp.vec3(*center),
            1.5 * cam.distance,  # checkerboard starts fading into the background here ...
            5.0 * cam.distance,  # ... and is gone here (metres from the target, on the plane)
            wp.vec3(*_GROUND_A),
            wp.vec3(*_GROUND_B),
            wp.vec3(*self.background),
            float(lit),
        ]

    def _shadow_level(self) -> float:
        """Ground brightness in full shadow: ambient plus a little sky light."""
        lit = self.ambient + (1.0 - self.ambient) * max(self.light_dir[1], 0.0)
        return float(self.ambient + 0.3 * (lit - self.ambient))

    def _shadow_rect(self, shadow_args: list, focal: float, Hs: int, Ws: int) -> tuple | None:
        """Screen rectangle (i0, i1, j0, j1) containing the shadow map's footprint on the ground."""
        cam = self.camera
        la, lb, lw = self._light_frame
        u0, v0, scale = shadow_args[4], shadow_args[5], shadow_args[6]
        span = _SHADOW_RES / scale
        g = float(self.ground_height)  # type: ignore[arg-type]
        corners = []
        for du in (0.0, span):
            for dv in (0.0, span):
                u, v = u0 + du, v0 + dv
                # Point with light-space coords (u, v) on the plane y = g.
                w = (g - u * la[1] - v * lb[1]) / lw[1]
                corners.append(u * la + v * lb + w * lw)
        right, up, fwd = cam.basis()
        rel = np.asarray(corners) - cam.eye
        z = rel @ fwd
        if np.any(z <= cam.near_plane):
            return 0, Hs, 0, Ws  # footprint reaches behind the camera: re-shade everything
        cols = 0.5 * Ws + (rel @ right) * focal / z
        rows = 0.5 * Hs - (rel @ up) * focal / z
        j0, j1 = max(int(np.floor(cols.min())) - 1, 0), min(int(np.ceil(cols.max())) + 1, Ws)
        i0, i1 = max(int(np.floor(rows.min())) - 1, 0), min(int(np.ceil(rows.max())) + 1, Hs)
        if i0 >= i1 or j0 >= j1:
            return None
        return i0, i1, j0, j1

    def _shadow_pass(
        self,
        world32: np.ndarray,
        valid: np.ndarray,
        wp_tri: wp.array | None,
        radius_m: np.ndarray | None,
        smap: np.ndarray,
        enabled: bool,
    ) -> list | None:
        """Fills the light-space height map.

        Returns:
            The shadow arguments of ``ground_shadow_kernel`` (map, light frame, map origin and
            scale, depth bias), or None when no shadow is drawn.
        """
        lw = self.light_dir
        if not (enabled and self.shadows and lw[1] > 0.05):
            return None
        wp_smap = _wrap(smap, float)
        # Light frame: lw towards the light, (la, lb) span the shadow-map plane.
        la = np.cross(lw, [0.0, 0.0, 1.0] if abs(lw[2]) < 0.9 else [1.0, 0.0, 0.0])
        la /= np.linalg.norm(la)
        lb = np.cross(lw, la)
        self._light_frame = (la, lb, lw)
        pts = world32.astype(np.float64)
        u, v, h = pts @ la, pts @ lb, pts @ lw
        pad = 0.0 if radius_m is None else float(np.max(radius_m, initial=0.0))
        uv = np.stack([u[valid], v[valid]], axis=1)
        lo = uv.min(axis=0) - pad
        span = float(np.max(uv.max(axis=0) + pad - lo))
        span = max(span, 1e-9)
        res = smap.shape[0]
        # One texel of border so PCF at the footprint edge reads "lit".
        scale = (res - 2) / span
        if not (np.isfinite(span) and np.all(np.isfinite(lo)) and scale > 0.0 and 1.0 / scale < 1e30):
            # A footprint too large for float32 light-space maths (e.g. a collider at 1e308 m): no shadow
            # rather than a division by zero; such a scene is not meant to be looked at anyway.
            return None
        u0, v0 = lo[0] - 1.0 / scale, lo[1] - 1.0 / scale
        ls = np.stack([(u - u0) * scale, (v - v0) * scale, np.where(valid, h, -1e30)], axis=1)
        ls = ls.astype(np.float32)
        smap.fill(-np.inf)
        if wp_tri is not None:
            wp.launch(
                K.shadow_triangles_kernel,
                dim=wp_tri.shape[0],
                inputs=[_wrap(ls, wp.vec3), wp_tri, wp_smap],
                device=DEVICE,
            )
        elif radius_m is not None:
            rpx = (radius_m * scale).astype(np.float32)
            wp.launch(
                K.shadow_points_kernel,
                dim=len(ls),
                inputs=[_wrap(ls, wp.vec3), _wrap(rpx, float), _wrap(radius_m, float), wp_smap],
                device=DEVICE,
            )
        # Depth bias of two texels so a surface resting on the ground does not shadow itself.
        bias = 2.0 / scale
        return [
            wp_smap,
            wp.vec3(*la),
            wp.vec3(*lb),
            wp.vec3(*lw),
            float(u0),
            float(v0),
            float(scale),
            bias,
        ]
