"""The Gaussian set: means, rotations, log-scales, opacity logits and spherical-harmonic colours."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import warp as wp

from .._warp import DTYPES, mat33_type, np_dtype, resolve_device, scalar_type, vec3_type

#: Zeroth spherical-harmonic basis constant, Y_00 = 1 / (2 √π): colour = SH_C0 · f_dc + 0.5.
SH_C0 = 0.28209479177387814


def vec4_type(dtype: str) -> type:
    """Warp 4-vector type for ``dtype`` (quaternions)."""
    return wp.vec4 if scalar_type(dtype) is wp.float32 else wp.vec4d


def vec2_type(dtype: str) -> type:
    """Warp 2-vector type for ``dtype`` (image points)."""
    return wp.vec2 if scalar_type(dtype) is wp.float32 else wp.vec2d


def sh_degree_of(coeffs: int) -> int:
    """Spherical-harmonic degree of ``coeffs`` coefficients per channel (1, 4, 9 or 16)."""
    for d in range(4):
        if (d + 1) ** 2 == coeffs:
            return d
    raise ValueError(f"SH coefficients per channel must be 1, 4, 9 or 16 (degree 0-3), got {coeffs}")


class Gaussians:
    """A set of 3D Gaussians in the parametrisation of 3D Gaussian splatting (Kerbl et al. 2023).

    The stored quantities are the ones optimised: ``means`` [m] (vec3), ``quats`` (vec4, w x y z; normalised
    when used), ``log_scales`` (vec3, natural log of the standard deviations [m] along the Gaussian's axes),
    ``opacity_logits`` (scalar, opacity = sigmoid(logit)) and ``sh`` (array2d [N, (d+1)²] of vec3: the
    spherical-harmonic coefficients of RGB; colour = Σ_k Y_k(view dir) sh_k + 0.5, clamped at 0).

    Args:
        means: Centres [m], shape [N, 3] (NumPy) or a Warp vec3 array.
        quats: Rotations as w, x, y, z quaternions, shape [N, 4] or a Warp vec4 array.
        log_scales: Log standard deviations [log m], shape [N, 3] or a Warp vec3 array.
        opacity_logits: Opacity logits, shape [N] or a Warp scalar array.
        sh: SH coefficients, shape [N, K, 3] with K in (1, 4, 9, 16), or a Warp array2d of vec3.
        dtype: ``"float32"`` or ``"float64"``.
        device: Warp device (default: CUDA when present).
        requires_grad: Allocate gradients for every parameter (ignored for Warp arrays passed in, which
            are kept as they are so that gradients flow into whatever produced them).
        transforms: Optional local linear maps A [N, 3, 3] (or a Warp mat33 array) applied to each Gaussian's
            shape, Σ = A R S Sᵀ Rᵀ Aᵀ (what a binding produces: the deformation gradient of the embedding,
            or the blended rotation of skinning). ``None`` is the identity.
    """

    def __init__(
        self,
        means: wp.array | npt.ArrayLike,
        quats: wp.array | npt.ArrayLike,
        log_scales: wp.array | npt.ArrayLike,
        opacity_logits: wp.array | npt.ArrayLike,
        sh: wp.array | npt.ArrayLike,
        *,
        dtype: str = "float32",
        device: str | None = None,
        requires_grad: bool = False,
        transforms: wp.array | npt.ArrayLike | None = None,
    ) -> None:
        if dtype not in DTYPES:
            raise ValueError(f"dtype must be one of {DTYPES}, got {dtype!r}")
        if device is None:
            for a in (means, quats, log_scales, opacity_logits, sh):
                if isinstance(a, wp.array):
                    device = str(a.device)
                    break
        self.dtype = dtype
        self.device = resolve_device(device)
        s, v3, v4 = scalar_type(dtype), vec3_type(dtype), vec4_type(dtype)
        self.means = self._array(means, v3, 3, "means", requires_grad)
        n = self.means.shape[0]
        self.quats = self._array(quats, v4, 4, "quats", requires_grad, n)
        self.log_scales = self._array(log_scales, v3, 3, "log_scales", requires_grad, n)
        self.opacity_logits = self._array(opacity_logits, s, 0, "opacity_logits", requires_grad, n)
        if isinstance(sh, wp.array):
            if sh.ndim != 2 or sh.dtype != v3 or sh.shape[0] != n:
                raise ValueError(f"sh must be a Warp array2d of {v3.__name__} with {n} rows, got {sh}")
            self.sh = sh
        else:
            a = np.asarray(sh, dtype=np_dtype(dtype))
            if a.ndim == 2 and a.shape[1] == 3:
                a = a[:, None, :]
            if a.ndim != 3 or a.shape[0] != n or a.shape[2] != 3:
                raise ValueError(f"sh must have shape [N={n}, K, 3], got {a.shape}")
            _finite(a, "sh")
            self.sh = wp.array(a, dtype=v3, device=self.device, requires_grad=requires_grad)
        self.sh_degree = sh_degree_of(self.sh.shape[1])
        self.transforms = None
        if transforms is not None:
            m33 = mat33_type(dtype)
            if isinstance(transforms, wp.array):
                if transforms.dtype != m33 or transforms.shape != (n,):
                    raise ValueError(
                        f"transforms must be a Warp array of {n} {m33.__name__}, got {transforms}"
                    )
                self.transforms = transforms
            else:
                a = np.asarray(transforms, dtype=np_dtype(dtype))
                if a.shape != (n, 3, 3):
                    raise ValueError(f"transforms must have shape [N={n}, 3, 3], got {a.shape}")
                _finite(a, "transforms")
                self.transforms = wp.array(a, dtype=m33, device=self.device, requires_grad=requires_grad)

    def _array(
        self,
        a: wp.array | npt.ArrayLike,
        wtype: type,
        width: int,
        name: str,
        requires_grad: bool,
        n: int | None = None,
    ) -> wp.array:
        if isinstance(a, wp.array):
            if a.dtype != wtype or a.ndim != 1:
                raise ValueError(
                    f"{name} must be a 1-d Warp array of {wtype.__name__}, got {a.dtype} {a.shape}"
                )
            if str(a.device) != self.device:
                raise ValueError(f"{name} is on {a.device} but the Gaussians are on {self.device}")
            out = a
        else:
            arr: np.ndarray = np.asarray(a, dtype=np_dtype(self.dtype))
            shape = (arr.shape[0],) if arr.ndim >= 1 else ()
            want = shape + ((width,) if width else ())
            if arr.ndim != (2 if width else 1) or arr.shape != want:
                raise ValueError(
                    f"{name} must have shape [N{', ' + str(width) if width else ''}], got {arr.shape}"
                )
            _finite(arr, name)
            out = wp.array(arr, dtype=wtype, device=self.device, requires_grad=requires_grad)
        if n is not None and out.shape[0] != n:
            raise ValueError(f"{name} has {out.shape[0]} entries but means has {n}")
        return out

    # ------------------------------------------------------------------ construction from plain quantities
    @classmethod
    def from_values(
        cls,
        means: np.ndarray,
        *,
        scales: np.ndarray | float = 0.01,
        rotations: np.ndarray | None = None,
        opacities: np.ndarray | float = 0.9,
        colors: np.ndarray | None = None,
        sh_degree: int = 0,
        dtype: str = "float32",
        device: str | None = None,
        requires_grad: bool = False,
    ) -> Gaussians:
        """Gaussians from means [m], scales [m], rotations (wxyz), opacities in (0, 1) and RGB in [0, 1].

        Args:
            means: Centres [m], shape [N, 3].
            scales: Standard deviations [m], shape [N, 3], [N] or a scalar (isotropic).
            rotations: Quaternions w, x, y, z, shape [N, 4] (default identity).
            opacities: Opacities in (0, 1), shape [N] or a scalar.
            colors: View-independent RGB in [0, 1], shape [N, 3] (default grey 0.5).
            sh_degree: SH degree 0-3; coefficients above degree 0 start at zero.
            dtype: ``"float32"`` or ``"float64"``.
            device: Warp device.
            requires_grad: Allocate gradients.
        """
        means = np.asarray(means, dtype=np.float64).reshape(-1, 3)
        n = len(means)
        sc = np.broadcast_to(
            np.asarray(scales, dtype=np.float64).reshape(-1, 1)
            if np.ndim(scales) == 1
            else np.asarray(scales, dtype=np.float64),
            (n, 3),
        )
        if np.any(sc <= 0.0):
            raise ValueError("scales must be positive")
        op = np.broadcast_to(np.asarray(opacities, dtype=np.float64), (n,))
        if np.any(op <= 0.0) or np.any(op >= 1.0):
            raise ValueError("opacities must lie in (0, 1)")
        q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)) if rotations is None else np.asarray(rotations, np.float64)
        rgb = np.full((n, 3), 0.5) if colors is None else np.asarray(colors, np.float64).reshape(n, 3)
        sh = np.zeros((n, (sh_degree_of((sh_degree + 1) ** 2) + 1) ** 2, 3))
        sh[:, 0] = (rgb - 0.5) / SH_C0
        return cls(
            means,
            q,
            np.log(sc),
            np.log(op / (1.0 - op)),
            sh,
            dtype=dtype,
            device=device,
            requires_grad=requires_grad,
        )

    # ------------------------------------------------------------------------------------------ accessors
    @property
    def count(self) -> int:
        """Number of Gaussians."""
        return self.means.shape[0]

    def __len__(self) -> int:
        return self.count

    @property
    def requires_grad(self) -> bool:
        """Whether any parameter array carries a gradient."""
        extra = [] if self.transforms is None else [self.transforms]
        return any(a.requires_grad for a in self.parameters() + extra)

    def parameters(self) -> list[wp.array]:
        """The parameter arrays: means, quats, log_scales, opacity_logits, sh."""
        return [self.means, self.quats, self.log_scales, self.opacity_logits, self.sh]

    def numpy(self) -> dict[str, np.ndarray]:
        """Parameters as NumPy arrays (float64 copies): means, quats, log_scales, opacity_logits, sh, and
        transforms when the set has them."""
        out = {
            "means": self.means.numpy().astype(np.float64),
            "quats": self.quats.numpy().astype(np.float64),
            "log_scales": self.log_scales.numpy().astype(np.float64),
            "opacity_logits": self.opacity_logits.numpy().astype(np.float64),
            "sh": self.sh.numpy().astype(np.float64),
        }
        if self.transforms is not None:
            out["transforms"] = self.transforms.numpy().astype(np.float64)
        return out

    @property
    def scales(self) -> np.ndarray:
        """Standard deviations [m], shape [N, 3] (NumPy)."""
        return np.exp(self.log_scales.numpy().astype(np.float64))

    @property
    def opacities(self) -> np.ndarray:
        """Opacities in (0, 1), shape [N] (NumPy)."""
        return 1.0 / (1.0 + np.exp(-self.opacity_logits.numpy().astype(np.float64)))

    def copy(
        self, *, dtype: str | None = None, device: str | None = None, requires_grad: bool = False
    ) -> Gaussians:
        """A deep copy, optionally in another dtype or on another device."""
        return _from_numpy(
            self.numpy(), dtype=dtype or self.dtype, device=device or self.device, requires_grad=requires_grad
        )

    def with_means(
        self, means: wp.array, quats: wp.array | None = None, transforms: wp.array | None = None
    ) -> Gaussians:
        """The same Gaussians with other means (and rotations, transforms): arrays are shared, not copied."""
        return Gaussians(
            means,
            self.quats if quats is None else quats,
            self.log_scales,
            self.opacity_logits,
            self.sh,
            dtype=self.dtype,
            device=self.device,
            transforms=transforms,
        )

    def baked(self) -> Gaussians:
        """An equivalent set without ``transforms``: each A R S Sᵀ Rᵀ Aᵀ re-expressed as a rotation and scales
        (its eigen-decomposition), as PLY files and other renderers expect. A copy, not on any tape."""
        p = self.numpy()
        A = p.pop("transforms", None)
        if A is None:
            return self.copy()
        q = p["quats"] / np.linalg.norm(p["quats"], axis=1, keepdims=True)
        M = A @ quat_matrices(q) * np.exp(p["log_scales"])[:, None, :]
        evals, evecs = np.linalg.eigh(M @ M.transpose(0, 2, 1))
        evecs[np.linalg.det(evecs) < 0, :, 0] *= -1.0  # a proper rotation
        p["quats"] = _matrix_quats(evecs)
        p["log_scales"] = 0.5 * np.log(np.maximum(evals, 1e-300))
        return _from_numpy(p, dtype=self.dtype, device=self.device)

    def __repr__(self) -> str:
        return (
            f"Gaussians(count={self.count}, sh_degree={self.sh_degree}, dtype={self.dtype}, "
            f"device={self.device})"
        )


def _finite(a: np.ndarray, name: str) -> None:
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} holds non-finite values (NaN or inf)")


def quat_matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices [N, 3, 3] of unit quaternions w, x, y, z [N, 4]."""
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )


def _matrix_quats(R: np.ndarray) -> np.ndarray:
    """Unit quaternions w, x, y, z [N, 4] of rotation matrices [N, 3, 3] (Shepperd: the largest of the four
    candidate components is computed from the diagonal, the others from off-diagonal sums; vectorised)."""
    m = R
    tr = np.trace(m, axis1=1, axis2=2)
    d = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    k = np.argmax(d, axis=1)
    s = 2.0 * np.sqrt(np.maximum(1.0 + 2.0 * d[np.arange(len(m)), k] - tr, 1e-300))
    a21, a12, a02, a20, a10, a01 = m[:, 2, 1], m[:, 1, 2], m[:, 0, 2], m[:, 2, 0], m[:, 1, 0], m[:, 0, 1]
    branches = np.stack(
        [
            np.stack([0.25 * s, (a21 - a12) / s, (a02 - a20) / s, (a10 - a01) / s], -1),
            np.stack([(a21 - a12) / s, 0.25 * s, (a01 + a10) / s, (a02 + a20) / s], -1),
            np.stack([(a02 - a20) / s, (a01 + a10) / s, 0.25 * s, (a12 + a21) / s], -1),
            np.stack([(a10 - a01) / s, (a02 + a20) / s, (a12 + a21) / s, 0.25 * s], -1),
        ],
        axis=1,
    )
    return branches[np.arange(len(m)), k]


def _from_numpy(
    p: dict[str, np.ndarray], *, dtype: str, device: str | None, requires_grad: bool = False
) -> Gaussians:
    """Gaussians from the float64 arrays of :meth:`Gaussians.numpy` (with ``transforms`` when present)."""
    return Gaussians(
        p["means"],
        p["quats"],
        p["log_scales"],
        p["opacity_logits"],
        p["sh"],
        transforms=p.get("transforms"),
        dtype=dtype,
        device=device,
        requires_grad=requires_grad,
    )
