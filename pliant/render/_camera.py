"""Pinhole camera with a y-up convention and automatic framing."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Camera", "as_points"]

#: Allowed vertical field of view [degrees] and image side [pixels].
FOV_RANGE = (0.01, 179.0)
MAX_IMAGE_SIDE = 16384

# Direction from the target towards the eye for the default 3/4 view: in front (+z), to the
# right (+x) and about 25 degrees above the horizon, so the ground plane is visible under
# the object and both the front and a side face are seen.
DEFAULT_VIEW_DIR = (0.75, 0.62, 1.0)


def as_points(points: object, name: str = "points") -> np.ndarray:
    """Converts NumPy/Warp/array-like input to a float64 [N, 3] host array.

    Args:
        points: Anything ``np.asarray`` accepts, or a ``warp.array`` (copied to the host).
        name: Argument name used in error messages.

    Returns:
        Array of shape [N, 3], dtype float64.
    """
    if hasattr(points, "numpy") and not isinstance(points, np.ndarray):
        points = points.numpy()  # warp.array / torch tensor on CPU
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim == 1 and arr.size == 3:
        arr = arr.reshape(1, 3)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape [N, 3], got {arr.shape}")
    return arr


def _vec3(v: object, name: str) -> np.ndarray:
    arr = np.asarray(v, dtype=np.float64).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be a finite 3-vector, got {v!r}")
    return arr


@dataclass
class Camera:
    """Perspective pinhole camera.

    Pixel coordinates are (column, row) with the origin at the top-left corner of the image;
    pixel ``(i, j)`` has its centre at ``(j + 0.5, i + 0.5)``.

    Attributes:
        eye: Camera position [3] in metres.
        target: Point looked at [3] in metres.
        up: Approximate up direction [3] (pliant is y-up).
        fov_y: Vertical field of view in degrees.
        width: Image width in pixels.
        height: Image height in pixels.
        near: Near-plane distance in metres; geometry closer than this is not drawn.
            ``None`` means 1e-3 times the eye-target distance.
    """

    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]))
    fov_y: float = 40.0
    width: int = 640
    height: int = 480
    near: float | None = None

    def __post_init__(self) -> None:
        self.eye = _vec3(self.eye, "eye")
        self.target = _vec3(self.target, "target")
        self.up = _vec3(self.up, "up")
        self.fov_y = float(self.fov_y)
        self.width = int(self.width)
        self.height = int(self.height)
        if not FOV_RANGE[0] <= self.fov_y <= FOV_RANGE[1]:
            # Below ~0.01° the focal length overflows the pixel maths; at 180° it is zero.
            raise ValueError(
                f"fov_y must be in [{FOV_RANGE[0]}, {FOV_RANGE[1]}] degrees, got {self.fov_y}; "
                "zoom by moving the eye instead"
            )
        if not (1 <= self.width <= MAX_IMAGE_SIDE and 1 <= self.height <= MAX_IMAGE_SIDE):
            raise ValueError(
                f"image size must be 1..{MAX_IMAGE_SIDE} pixels a side, got {self.width}x{self.height}"
            )
        with np.errstate(over="ignore", invalid="ignore"):
            fwd = self.target - self.eye
            dist = float(np.linalg.norm(fwd))
        scale = max(1.0, float(np.max(np.abs(self.eye))), float(np.max(np.abs(self.target))))
        if not np.isfinite(dist) or dist <= 1e-9 * scale:
            raise ValueError(
                f"eye {self.eye.tolist()} and target {self.target.tolist()} coincide (or are too far apart "
                "to subtract); put the eye at a finite distance from the point it looks at"
            )
        if np.linalg.norm(np.cross(fwd, self.up)) <= 1e-9 * np.linalg.norm(fwd) * np.linalg.norm(self.up):
            raise ValueError("up is parallel to the viewing direction")
        if self.near is not None and not (self.near > 0.0 and np.isfinite(self.near)):
            raise ValueError(f"near must be positive, got {self.near}")

    @property
    def distance(self) -> float:
        """Eye-target distance in metres."""
        return float(np.linalg.norm(self.target - self.eye))

    @property
    def near_plane(self) -> float:
        """Effective near-plane distance in metres."""
        return float(self.near) if self.near is not None else 1e-3 * self.distance

    @property
    def focal_px(self) -> float:
        """Focal length in pixels (square pixels)."""
        return 0.5 * self.height / math.tan(math.radians(self.fov_y) * 0.5)

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Orthonormal camera frame.

        Returns:
            ``(right, up, forward)`` unit vectors [3]; ``forward`` points from eye to target.
        """
        fwd = self.target - self.eye
        fwd = fwd / np.linalg.norm(fwd)
        right = np.cross(fwd, self.up)
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        return right, up, fwd

    def project(self, points: object) -> tuple[np.ndarray, np.ndarray]:
        """Perspective projection of world points.

        Args:
            points: World positions [N, 3] in metres.

        Returns:
            ``(pixels, depth)``: pixel coordinates [N, 2] as (column, row) floats, and view-space
            depth [N] in metres along the viewing direction (positive in front of the camera;
            points with ``depth <= near_plane`` are not visible).
        """
        pts = as_points(points)
        right, up, fwd = self.basis()
        rel = pts - self.eye
        xc, yc, zc = rel @ right, rel @ up, rel @ fwd
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = self.focal_px / zc
        pix = np.stack([0.5 * self.width + xc * inv, 0.5 * self.height - yc * inv], axis=1)
        return pix, zc

    @classmethod
    def fit(
        cls,
        points: object,
        *,
        direction: tuple[float, float, float] | np.ndarray = DEFAULT_VIEW_DIR,
        up: tuple[float, float, float] | np.ndarray = (0.0, 1.0, 0.0),
        fov_y: float = 40.0,
        width: int = 640,
        height: int = 480,
        padding: float = 0.08,
    ) -> Camera:
        """Camera looking at the bounding-box centre of ``points`` with every point in view.

        The eye sits on the ray ``center + s * direction`` at the smallest distance ``s`` for
        which every point (beyond a million points: every bounding-box corner) projects inside
        the image with a ``padding`` fraction of the half-image kept free on every side.

        Args:
            points: Positions [..., 3] in metres (e.g. [N, 3] or a whole trajectory [T, N, 3]);
                non-finite rows (and rows beyond float32's range, which are not drawn) are ignored.
            direction: Direction from the target towards the eye (default: 3/4 view from the
                front-right, about 25 degrees above the horizon).
            up: Up vector.
            fov_y: Vertical field of view in degrees.
            width: Image width in pixels.
            height: Image height in pixels.
            padding: Fraction (0..1) of each half-image left empty around the box.

        Returns:
            A new camera.
        """
        if hasattr(points, "numpy") and not isinstance(points, np.ndarray):
            points = points.numpy()
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        # As the renderer: rows float32 cannot hold (|x| > 3.4e38, e.g. a far collider) are not framed.
        pts = pts[np.all(np.abs(pts) <= np.finfo(np.float32).max, axis=1)]
        if len(pts) == 0:
            raise ValueError("Camera.fit needs at least one finite point")
        if not 0.0 <= padding < 1.0:
            raise ValueError(f"padding must be in [0, 1), got {padding}")
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        center = 0.5 * (lo + hi)
        d = _vec3(direction, "direction")
        d /= np.linalg.norm(d)
        # A provisional camera for the basis (which depends only on d); its distance must be resolvable
        # next to the coordinates' size.
        reach = max(1.0, float(np.max(np.abs(center))), float(np.max(hi - lo)))
        cam = cls(
            eye=center + reach * d,
            target=center,
            up=np.asarray(up, float),
            fov_y=fov_y,
            width=width,
            height=height,
        )
        right, upv, _ = cam.basis()
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
        if np.max(hi - lo) <= 1e-9 * max(1.0, float(np.max(np.abs(center)))):
            rel = corners * 0.05  # a single point: frame a 10 cm box around it
        elif len(pts) > 1_000_000:
            rel = corners * (0.5 * (hi - lo))  # the box corners bound every point, cheaply
        else:
            rel = pts - center  # exact: tighter than the box for round or diagonal shapes
        s = rel @ d  # offset towards the camera
        tan_y = math.tan(math.radians(fov_y) * 0.5) * (1.0 - padding)
        tan_x = tan_y * width / height
        dist = np.max(np.maximum(s + np.abs(rel @ right) / tan_x, s + np.abs(rel @ upv) / tan_y))
        dist = max(float(dist), 1.05 * float(np.max(s)), 1e-9)  # every point in front of the eye
        return cls(
            eye=center + dist * d,
            target=center,
            up=np.asarray(up, float),
            fov_y=fov_y,
            width=width,
            height=height,
        )
