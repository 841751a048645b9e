"""Appearance fitting and visual correction with pl.gaussians (synthetic, calibrated images)."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from pliant.gaussians import (
    Adam,
    Camera,
    Gaussians,
    VisualCorrector,
    bind,
    fit_appearance,
    photometric_loss,
    psnr,
    render,
)


def _truth(n=80, seed=0, dtype="float32"):
    rng = np.random.default_rng(seed)
    means = rng.uniform(-0.4, 0.4, (n, 3))
    return Gaussians.from_values(
        means,
        scales=rng.uniform(0.04, 0.1, (n, 3)),
        rotations=rng.normal(size=(n, 4)),
        opacities=rng.uniform(0.5, 0.9, n),
        colors=rng.uniform(0, 1, (n, 3)),
        dtype=dtype,
        device="cpu",
    )


def _ring(k, offset=0.0):
    angles = np.linspace(0, 2 * np.pi, k, endpoint=False) + offset
    return [
        Camera.look_at([2.5 * np.sin(a), 0.8, 2.5 * np.cos(a)], [0, 0, 0], width=64, height=48)
        for a in angles
    ]


def _fit(iterations):
    gt = _truth()
    train, test = _ring(6), _ring(2, 0.5)
    images = [render(gt, c).colour.numpy() for c in train]
    held = [render(gt, c).colour.numpy() for c in test]
    rng = np.random.default_rng(1)
    init = Gaussians.from_values(
        gt.numpy()["means"] + rng.normal(scale=0.02, size=(gt.count, 3)),
        scales=0.06,
        opacities=0.5,
        device="cpu",
    )
    g, history = fit_appearance(init, train, images, iterations=iterations)
    p_train = np.mean([psnr(render(g, c).colour, im) for c, im in zip(train, images, strict=True)])
    p_test = np.mean([psnr(render(g, c).colour, im) for c, im in zip(test, held, strict=True)])
    return history, p_train, p_test


def test_fit_appearance_reduces_loss_quickly():
    history, p_train, p_test = _fit(30)
    assert history[-1] < 0.5 * history[0]
    assert p_train > 26.0 and p_test > 26.0


@pytest.mark.slow
def test_fit_appearance_psnr():
    # 6 training views, 2 held-out views between them, 200 Adam steps from grey, jittered Gaussians.
    history, p_train, p_test = _fit(200)
    assert p_train >= 30.0 and p_test >= 25.0, (p_train, p_test)


def test_fit_rejects_bad_images():
    gt = _truth(n=5)
    cams = _ring(2)
    good = np.zeros((48, 64, 3))
    bad = good.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="image 1 holds 1 non-finite"):
        fit_appearance(gt, cams, [good, bad], iterations=1)
    with pytest.raises(ValueError, match="image 0 has size 32 x 48"):
        fit_appearance(gt, cams, [good[:, :32], good], iterations=1)
    with pytest.raises(ValueError, match="2 cameras but 1 images"):
        fit_appearance(gt, cams, [good], iterations=1)


def test_photometric_loss_and_adam():
    rng = np.random.default_rng(0)
    c = wp.array(rng.uniform(size=(4, 5, 3)), dtype=wp.vec3d)
    t = wp.array(rng.uniform(size=(4, 5, 3)), dtype=wp.vec3d)
    a = wp.array(rng.uniform(size=(4, 5)), dtype=wp.float64)
    m = wp.array(rng.uniform(size=(4, 5)), dtype=wp.float64)
    loss, gc, ga = photometric_loss(c, a, t, m, mask_weight=0.5)
    d, e = c.numpy() - t.numpy(), a.numpy() - m.numpy()
    assert loss == pytest.approx(np.mean(d**2) + 0.5 * np.mean(e**2), rel=1e-12)
    np.testing.assert_allclose(gc.numpy(), 2 * d / d.size, rtol=1e-12)
    np.testing.assert_allclose(ga.numpy(), 2 * 0.5 * e / e.size, rtol=1e-12)
    # Adam's first step moves every coordinate by lr against the sign of its gradient
    p = wp.array(np.zeros((3, 3)), dtype=wp.vec3d, requires_grad=True)
    p.grad.assign(rng.normal(size=(3, 3)))
    Adam([p], [0.1]).step()
    np.testing.assert_allclose(p.numpy(), -0.1 * np.sign(p.grad.numpy()), rtol=1e-9)


def _particles():
    g = np.linspace(-0.3, 0.3, 4)
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)


def test_visual_correction_pushes_particles_toward_the_images():
    X = _particles()
    rng = np.random.default_rng(2)
    g = Gaussians.from_values(
        X + rng.normal(scale=0.02, size=X.shape),
        scales=0.07,
        opacities=0.8,
        colors=rng.uniform(0, 1, X.shape),
        device="cpu",
    )
    b = bind(g, X, method="lbs", k=4, neighbours=8)
    cams = _ring(3)
    shift = np.array([0.03, -0.02, 0.01])
    observed = [render(b.deform(wp.array(X + shift, dtype=wp.vec3)), c).colour.numpy() for c in cams]
    vc = VisualCorrector(b, cams, iterations=3)
    f = vc.forces(wp.array(X, dtype=wp.vec3), observed).numpy().astype(np.float64)
    total = f.sum(axis=0)
    assert np.dot(total, shift) / (np.linalg.norm(total) * np.linalg.norm(shift)) > 0.8
    # images of the simulated state itself: no force at all
    same = [render(b.deform(wp.array(X, dtype=wp.vec3)), c).colour.numpy() for c in cams]
    assert np.abs(vc.forces(wp.array(X, dtype=wp.vec3), same).numpy()).max() == 0.0
