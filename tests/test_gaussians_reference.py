"""A slow, dense NumPy oracle for pliant.gaussians.render: every Gaussian against every pixel, float64.

Independent of the Warp code except for the conventions it must share (OpenCV pixel centres at integer
coordinates, 3σ tile footprint, α clamp 0.99, α ≥ 1/255, stop before T < 1e-4, SH constants of 3DGS).
"""

from __future__ import annotations

import numpy as np

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = [1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396]
C3 = [
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
]


def quat_matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def sh_rgb(sh: np.ndarray, d: np.ndarray) -> np.ndarray:
    x, y, z = d
    basis = [C0]
    if len(sh) > 1:
        basis += [-C1 * y, C1 * z, -C1 * x]
    if len(sh) > 4:
        xx, yy, zz = x * x, y * y, z * z
        basis += [C2[0] * x * y, C2[1] * y * z, C2[2] * (2 * zz - xx - yy), C2[3] * x * z, C2[4] * (xx - yy)]
    if len(sh) > 9:
        xx, yy, zz = x * x, y * y, z * z
        basis += [
            C3[0] * y * (3 * xx - yy),
            C3[1] * x * y * z,
            C3[2] * y * (4 * zz - xx - yy),
            C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
            C3[4] * x * (4 * zz - xx - yy),
            C3[5] * z * (xx - yy),
            C3[6] * x * (xx - 3 * yy),
        ]
    return np.maximum(np.asarray(basis) @ sh + 0.5, 0.0)


def reference_render(p: dict, cam, background=(0.0, 0.0, 0.0), near: float = 0.01, eps2d: float = 0.3):
    """Dense render of ``p`` (``Gaussians.numpy()``) → (colour [H,W,3], alpha [H,W], depth [H,W])."""
    H, W = cam.height, cam.width
    R, t = cam.rotation, cam.translation
    fx, fy, cx, cy = cam.fx, cam.fy, cam.cx, cam.cy
    lims = ((cx + 0.3 * W) / fx, (W - cx + 0.3 * W) / fx, (cy + 0.3 * H) / fy, (H - cy + 0.3 * H) / fy)
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    tiles_x, tiles_y = (W + 15) // 16, (H + 15) // 16
    items = []
    for g in range(len(p["means"])):
        pc = R @ p["means"][g] + t
        if pc[2] <= near:
            continue
        z = pc[2]
        tx = np.clip(pc[0] / z, -lims[0], lims[1]) * z
        ty = np.clip(pc[1] / z, -lims[2], lims[3]) * z
        J = np.array([[fx / z, 0, -fx * tx / z**2], [0, fy / z, -fy * ty / z**2]])
        A = p["transforms"][g] if "transforms" in p else np.eye(3)
        M = R @ A @ quat_matrix(p["quats"][g]) @ np.diag(np.exp(p["log_scales"][g]))
        cov = J @ M @ M.T @ J.T + eps2d * np.eye(2)
        det = np.linalg.det(cov)
        if det <= 0:
            continue
        conic = np.linalg.inv(cov)
        m = np.array([fx * pc[0] / z + cx, fy * pc[1] / z + cy])
        mid = 0.5 * (cov[0, 0] + cov[1, 1])
        r = np.ceil(3 * np.sqrt(mid + np.sqrt(max(0.1, mid * mid - det))))
        x0, x1 = (np.clip(np.floor((m[0] + s * r) / 16) + o, 0, tiles_x) for s, o in ((-1, 0), (1, 1)))
        y0, y1 = (np.clip(np.floor((m[1] + s * r) / 16) + o, 0, tiles_y) for s, o in ((-1, 0), (1, 1)))
        if x1 <= x0 or y1 <= y0:
            continue
        inrect = (xs >= 16 * x0) & (xs < 16 * x1) & (ys >= 16 * y0) & (ys < 16 * y1)
        dx, dy = xs - m[0], ys - m[1]
        power = -0.5 * (conic[0, 0] * dx * dx + conic[1, 1] * dy * dy) - conic[0, 1] * dx * dy
        o = 1.0 / (1.0 + np.exp(-p["opacity_logits"][g]))
        alpha = np.minimum(0.99, o * np.exp(power))
        alpha = np.where(inrect & (power <= 0) & (alpha >= 1 / 255), alpha, 0.0)
        d = p["means"][g] - cam.position
        colour = sh_rgb(p["sh"][g], d / np.linalg.norm(d))
        items.append((z, g, alpha, colour))
    items.sort(key=lambda it: (it[0], it[1]))
    T = np.ones((H, W))
    C = np.zeros((H, W, 3))
    D = np.zeros((H, W))
    done = np.zeros((H, W), bool)
    for z, _g, alpha, colour in items:
        t_next = T * (1 - alpha)
        done |= (alpha > 0) & (t_next < 1e-4)
        a = np.where(done, 0.0, alpha)
        C += (a * T)[..., None] * colour
        D += a * T * z
        T = T * (1 - a)
    A = 1 - T
    depth = np.where(A > 0, D / np.where(A > 0, A, 1), 0.0)
    return C + T[..., None] * np.asarray(background), A, depth


def test_reference_sh_basis_is_orthonormal():
    # The oracle's SH constants are checked on their own: ∫ Y_i Y_j dΩ = δ_ij (Fibonacci-sphere quadrature).
    # (sh_rgb clamps at 0, so this evaluates each basis function in a range where 0.5 + Y_k stays ≥ 0 by
    # scaling the coefficient down and back up.)
    m = 4000
    i = np.arange(m) + 0.5
    z = 1 - 2 * i / m
    phi = np.pi * (1 + 5**0.5) * i
    d = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], axis=1)
    B = np.zeros((m, 16))
    for k in range(1, 16):
        sh = np.zeros((16, 3))
        sh[k] = 0.1  # |0.1 Y_k| < 0.5: no clamping
        B[:, k] = [(sh_rgb(sh, di)[0] - 0.5) / 0.1 for di in d]
    B[:, 0] = C0
    gram = 4 * np.pi * B.T @ B / m
    np.testing.assert_allclose(gram, np.eye(16), atol=2e-3)
