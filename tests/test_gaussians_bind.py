"""Bindings of Gaussians to particles: exact for rigid/affine motions, and differentiable end to end
(render loss → Gaussians → binding → particle positions) against finite differences in float64."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl
from pliant.gaussians import Camera, Gaussians, bind, render
from tests.test_gaussians_reference import reference_render


def _rotation(seed=0):
    q = np.random.default_rng(seed).normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _block(n=3):
    """A cube [-0.5, 0.5]³ of (n+1)³ particles, each cell split into 6 tets around its diagonal."""
    g = np.linspace(-0.5, 0.5, n + 1)
    X = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    idx = np.arange(len(X)).reshape(n + 1, n + 1, n + 1)
    tets = []
    for i in range(n):
        for j in range(n):
            for k in range(n):
                c = [idx[i + a, j + b, k + d] for a in (0, 1) for b in (0, 1) for d in (0, 1)]
                # six tets around the main diagonal c0-c7 of the cell
                for p, q in ((1, 3), (3, 2), (2, 6), (6, 4), (4, 5), (5, 1)):
                    tets.append([c[0], c[p], c[q], c[7]])
    tets = np.array(tets)
    Xm = X[tets]
    vol = np.einsum("ij,ij->i", Xm[:, 1] - Xm[:, 0], np.cross(Xm[:, 2] - Xm[:, 0], Xm[:, 3] - Xm[:, 0]))
    tets[vol < 0] = tets[vol < 0][:, [0, 2, 1, 3]]
    return X, tets


def _gaussians(n=30, seed=2, device="cpu", dtype="float64"):
    rng = np.random.default_rng(seed)
    return Gaussians.from_values(
        rng.uniform(-0.4, 0.4, (n, 3)),
        scales=rng.uniform(0.04, 0.1, (n, 3)),
        rotations=rng.normal(size=(n, 4)),
        opacities=rng.uniform(0.3, 0.8, n),
        colors=rng.uniform(0, 1, (n, 3)),
        dtype=dtype,
        device=device,
    )


def _binding(method, g, X, tets):
    clusters = [np.flatnonzero(X[:, 0] < 0), np.flatnonzero(X[:, 0] >= 0)]
    tris = np.concatenate([tets[:, [0, 1, 2]], tets[:, [0, 1, 3]]])  # a surface mesh stand-in
    return bind(g, X, method=method, tets=tets, triangles=tris, clusters=clusters, k=8, neighbours=8)


@pytest.mark.parametrize("method", ["lbs", "barycentric", "triangles", "rigid"])
def test_rest_and_rigid_motion_are_exact(method, device):
    X, tets = _block()
    g = _gaussians(device=device)
    b = _binding(method, g, X, tets)
    mu = g.numpy()["means"]
    rest = b.deform(wp.array(X, dtype=wp.vec3d, device=device))
    np.testing.assert_allclose(rest.numpy()["means"], mu, atol=1e-12)
    np.testing.assert_allclose(
        rest.numpy()["transforms"], np.broadcast_to(np.eye(3), (g.count, 3, 3)), atol=1e-12
    )
    R, t = _rotation(), np.array([0.3, -0.2, 0.5])
    moved = b.deform(wp.array(X @ R.T + t, dtype=wp.vec3d, device=device))
    np.testing.assert_allclose(moved.numpy()["means"], mu @ R.T + t, atol=1e-10)
    np.testing.assert_allclose(moved.numpy()["transforms"], np.broadcast_to(R, (g.count, 3, 3)), atol=1e-10)


def test_barycentric_follows_affine_maps_exactly():
    X, tets = _block()
    g = _gaussians()
    b = _binding("barycentric", g, X, tets)
    F = np.array([[1.2, 0.1, 0.0], [0.0, 0.8, 0.3], [0.1, 0.0, 1.1]])
    moved = b.deform(wp.array(X @ F.T, dtype=wp.vec3d))
    np.testing.assert_allclose(moved.numpy()["means"], g.numpy()["means"] @ F.T, atol=1e-12)
    np.testing.assert_allclose(moved.numpy()["transforms"], np.broadcast_to(F, (g.count, 3, 3)), atol=1e-12)


def test_transforms_render_like_the_reference_and_like_baked_gaussians():
    X, tets = _block()
    g = _gaussians()
    b = _binding("barycentric", g, X, tets)
    F = np.array([[1.2, 0.1, 0.0], [0.0, 0.8, 0.3], [0.1, 0.0, 1.1]])
    moved = b.deform(wp.array(X @ F.T, dtype=wp.vec3d))
    cam = Camera.look_at([0.4, 0.5, 2.5], [0, 0, 0], width=64, height=48)
    out = render(moved, cam)
    ref = reference_render(moved.numpy(), cam)
    baked = render(moved.baked(), cam)
    for a, r, c in zip(out, ref, baked):
        np.testing.assert_allclose(a.numpy(), r, atol=1e-10)
        np.testing.assert_allclose(c.numpy(), r, atol=1e-9)


@pytest.mark.parametrize("method", ["lbs", "barycentric", "triangles", "rigid"])
def test_render_gradient_wrt_particles_matches_finite_differences(method):
    X, tets = _block()
    rng = np.random.default_rng(4)
    Xd = X + rng.normal(scale=0.03, size=X.shape)  # a generic deformed configuration
    g = _gaussians()
    b = _binding(method, g, X, tets)
    cam = Camera.look_at([0.4, 0.5, 2.5], [0, 0, 0], width=64, height=48)
    wc, wa = rng.normal(size=(48, 64, 3)), rng.normal(size=(48, 64))

    def loss(x):
        c, a, _ = render(b.deform(wp.array(x, dtype=wp.vec3d)), cam)
        return (c.numpy() * wc).sum() + (a.numpy() * wa).sum()

    q = wp.array(Xd, dtype=wp.vec3d, requires_grad=True)
    tape = wp.Tape()
    with tape:
        c, a, _ = render(b.deform(q), cam)
    tape.backward(grads={c: wp.array(wc, dtype=wp.vec3d), a: wp.array(wa, dtype=wp.float64)})
    grad = q.grad.numpy()
    assert np.abs(grad).max() > 0
    v = rng.normal(size=X.shape)
    h = 1e-6
    fd = (loss(Xd + h * v) - loss(Xd - h * v)) / (2 * h)
    ad = float((grad * v).sum())
    assert abs(ad - fd) <= 1e-6 * max(1.0, abs(fd)), (ad, fd)


def test_particle_weights_partition_unity():
    X, tets = _block()
    g = _gaussians()
    for method in ("lbs", "barycentric", "triangles", "rigid"):
        gi, pi, w = _binding(method, g, X, tets).particle_weights()
        np.testing.assert_allclose(np.bincount(gi, weights=w, minlength=g.count), 1.0, atol=1e-12)
        assert pi.min() >= 0 and pi.max() < len(X)


def test_bind_errors():
    X, tets = _block(1)
    g = _gaussians(n=3)
    with pytest.raises(ValueError, match="unknown binding method"):
        bind(g, X, method="magic")
    with pytest.raises(ValueError, match="needs tets"):
        bind(g, X, method="barycentric")
    with pytest.raises(ValueError, match="needs triangles"):
        bind(g, X, method="triangles")
    with pytest.raises(ValueError, match="needs clusters"):
        bind(g, X, method="rigid")
    b = bind(g, X)
    with pytest.raises(ValueError, match="particle_q must be"):
        b.deform(wp.zeros(3, dtype=wp.vec3d))
    assert pl.gaussians.Binding is type(b)
