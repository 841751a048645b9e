"""Pinhole cameras for the splat rasteriser: OpenCV intrinsics and a rigid world-to-camera transform."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


class Camera:
    """A pinhole camera in the OpenCV convention (x right, y down, z forward; pixel centres at integers).

    Args:
        K: Intrinsic matrix, shape [3, 3], ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` with focal lengths and
            principal point in pixels. Skew must be zero.
        world_to_camera: Rigid transform [4, 4] taking world points [m] to camera coordinates [m]: a
            rotation (orthonormal, determinant +1) and a translation, last row ``[0, 0, 0, 1]``.
        width: Image width [px], positive.
        height: Image height [px], positive.

    Raises:
        ValueError: non-finite entries, non-positive focal lengths, non-zero skew, a non-rigid pose, or a
            non-positive image size; the message names what is wrong.
    """

    def __init__(self, K: np.ndarray, world_to_camera: np.ndarray, width: int, height: int) -> None:
        K = np.asarray(K, dtype=np.float64)
        T = np.asarray(world_to_camera, dtype=np.float64)
        if K.shape != (3, 3):
            raise ValueError(f"Camera: K must have shape [3, 3], got {K.shape}")
        if T.shape != (4, 4):
            raise ValueError(f"Camera: world_to_camera must have shape [4, 4], got {T.shape}")
        if not np.all(np.isfinite(K)):
            raise ValueError("Camera: K has non-finite entries")
        if not np.all(np.isfinite(T)):
            raise ValueError("Camera: world_to_camera has non-finite entries")
        if K[0, 0] <= 0.0 or K[1, 1] <= 0.0:
            raise ValueError(f"Camera: focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
        if K[0, 1] != 0.0 or K[1, 0] != 0.0:
            raise ValueError(f"Camera: K must have zero skew, got K[0, 1]={K[0, 1]}, K[1, 0]={K[1, 0]}")
        if not np.allclose(K[2], [0.0, 0.0, 1.0]):
            raise ValueError(f"Camera: the last row of K must be [0, 0, 1], got {K[2].tolist()}")
        if int(width) != width or int(height) != height or width <= 0 or height <= 0:
            raise ValueError(f"Camera: width and height must be positive integers, got {width} x {height}")
        R = T[:3, :3]
        if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0]):
            raise ValueError(f"Camera: world_to_camera's last row must be [0, 0, 0, 1], got {T[3].tolist()}")
        ortho = np.abs(R @ R.T - np.eye(3)).max()
        if ortho > 1e-5 or np.linalg.det(R) < 0.0:
            raise ValueError(
                "Camera: world_to_camera is not rigid: its 3x3 block must be a rotation "
                f"(|R Rᵀ − I|max = {ortho:.3g}, det R = {np.linalg.det(R):.6g}); "
                "scale, shear and reflections are not allowed"
            )
        self.K = K
        self.world_to_camera = T
        self.width = int(width)
        self.height = int(height)

    @property
    def fx(self) -> float:
        """Horizontal focal length [px]."""
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        """Vertical focal length [px]."""
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        """Principal point x [px]."""
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        """Principal point y [px]."""
        return float(self.K[1, 2])

    @property
    def rotation(self) -> np.ndarray:
        """World-to-camera rotation, shape [3, 3]."""
        return self.world_to_camera[:3, :3]

    @property
    def translation(self) -> np.ndarray:
        """World-to-camera translation [m], shape [3]."""
        return self.world_to_camera[:3, 3]

    @property
    def position(self) -> np.ndarray:
        """Camera centre in world coordinates [m], shape [3]."""
        return -self.rotation.T @ self.translation

    @classmethod
    def look_at(
        cls,
        eye: ArrayLike,
        target: ArrayLike,
        *,
        up: ArrayLike = (0.0, 1.0, 0.0),
        fov_y: float = 50.0,
        width: int = 64,
        height: int = 48,
    ) -> Camera:
        """A camera at ``eye`` [m] looking at ``target`` [m].

        Args:
            eye: Camera centre [m], shape [3].
            target: Point the optical axis passes through [m], shape [3].
            up: World direction that appears up in the image (pliant is y-up).
            fov_y: Vertical field of view [degrees].
            width: Image width [px].
            height: Image height [px].
        """
        eye = np.asarray(eye, dtype=np.float64)
        f = np.asarray(target, dtype=np.float64) - eye
        if np.linalg.norm(f) == 0.0:
            raise ValueError("Camera.look_at: eye and target coincide")
        f /= np.linalg.norm(f)
        x = np.cross(f, np.asarray(up, dtype=np.float64))
        if np.linalg.norm(x) < 1e-9:
            raise ValueError("Camera.look_at: the viewing direction is parallel to up")
        x /= np.linalg.norm(x)
        y = np.cross(f, x)  # image y points down
        T = np.eye(4)
        T[:3, :3] = np.stack([x, y, f])
        T[:3, 3] = -T[:3, :3] @ eye
        focal = 0.5 * height / np.tan(0.5 * np.radians(fov_y))
        K = np.array([[focal, 0.0, 0.5 * (width - 1)], [0.0, focal, 0.5 * (height - 1)], [0.0, 0.0, 1.0]])
        return cls(K, T, width, height)

    def check_image(self, image: np.ndarray, name: str = "image") -> np.ndarray:
        """Validate an observed image for this camera and return it as float64 [H, W, C].

        Args:
            image: Array [H, W, 3] (colour) or [H, W] (mask / alpha), values in [0, 1].
            name: What the image is, for error messages.

        Raises:
            ValueError: the size differs from the camera's, or the image holds NaN/inf.
        """
        a = np.asarray(image.numpy() if hasattr(image, "numpy") else image, dtype=np.float64)
        if a.ndim not in (2, 3):
            raise ValueError(f"{name} must have shape [H, W, 3] or [H, W], got {a.shape}")
        if a.shape[:2] != (self.height, self.width):
            raise ValueError(
                f"{name} has size {a.shape[1]} x {a.shape[0]} (W x H) but the camera is "
                f"{self.width} x {self.height}"
            )
        if a.ndim == 3 and a.shape[2] != 3:
            raise ValueError(f"{name} must have 3 channels, got shape {a.shape}")
        bad = ~np.isfinite(a)
        if bad.any():
            raise ValueError(f"{name} holds {int(bad.sum())} non-finite values (NaN or inf)")
        return a

    def __repr__(self) -> str:
        return f"Camera({self.width}x{self.height}, fx={self.fx:.4g}, fy={self.fy:.4g})"
