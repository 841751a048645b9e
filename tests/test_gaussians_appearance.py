"""The appearance stage (pliant/gaussians/_appearance.py) and the rasteriser gradients it added: the
background's and the shading's (ambient, directional light, headlight) against float64 central differences,
and the recovery of a known palette, background and light from pliant-rendered frames."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from pliant.gaussians import Camera, Gaussians, render
from pliant.gaussians._appearance import fit_splat_appearance, sample_colours
from pliant.gaussians._scene import SceneSplats
from pliant.gaussians._surface import surface_gaussians

LIGHT = (0.35, 0.3, 0.5, 0.2, 0.25)  # ambient, L, headlight


def _flat_scene(n=40, seed=1, requires_grad=True):
    """Flat splats (one scale 5 % of the others, so the normal axis is unambiguous) in random orientations."""
    rng = np.random.default_rng(seed)
    s = rng.uniform(0.05, 0.12, (n, 3))
    s[:, 2] = 0.05 * s[:, 0]
    g = Gaussians.from_values(
        rng.uniform(-0.5, 0.5, (n, 3)),
        scales=s,
        rotations=rng.normal(size=(n, 4)),
        opacities=rng.uniform(0.3, 0.8, n),
        colors=rng.uniform(0.2, 0.8, (n, 3)),
        sh_degree=1,
    )
    p = g.numpy()
    p["sh"][:, 1:] = rng.normal(scale=0.2, size=p["sh"][:, 1:].shape)
    p["transforms"] = np.eye(3) + 0.2 * rng.normal(size=(n, 3, 3))  # a binding's local maps
    return Gaussians(**p, dtype="float64", device="cpu", requires_grad=requires_grad)


def _camera():
    return Camera.look_at([0.3, 0.6, 2.5], [0.0, 0.0, 0.0], width=48, height=40)


def _light_array(values, requires_grad=False):
    a = np.array([values[:4], [values[4], 0.0, 0.0, 0.0]])
    return wp.array(a, dtype=wp.vec4d, device="cpu", requires_grad=requires_grad)


@pytest.mark.parametrize("name", ["background", "light", "means", "quats", "sh", "transforms"])
def test_background_and_shading_gradients_match_finite_differences_float64(name):
    # L = Σ W·colour + Σ w·alpha with a fixed random W; directional derivative along a random direction,
    # central differences with h = 1e-6 (float64). The shading's gradient reaches the light array and, through
    # the normals, the quaternions, transforms and (view direction) means.
    cam = _camera()
    rng = np.random.default_rng(7)
    W, w = rng.normal(size=(40, 48, 3)), rng.normal(size=(40, 48))
    bg0 = np.array([0.2, 0.5, 0.7])

    def loss(g, bg, light, grad=False):
        tape = wp.Tape()
        with tape:
            c, a, _ = render(g, cam, bg, light=light)
        value = float(np.sum(W * c.numpy()) + np.sum(w * a.numpy()))
        if grad:
            tape.backward(grads={c: wp.array(W, dtype=wp.vec3d), a: wp.array(w, dtype=wp.float64)})
        return value

    g = _flat_scene()
    bg = wp.array([bg0], dtype=wp.vec3d, device="cpu", requires_grad=True)
    light = _light_array(LIGHT, requires_grad=True)
    loss(g, bg, light, grad=True)
    p = g.numpy()
    grads = {"background": bg.grad.numpy()[0], "light": light.grad.numpy()}
    grads.update(
        {
            k: a.grad.numpy()
            for k, a in zip(["means", "quats", "log_scales", "opacity_logits", "sh"], g.parameters())
        }
    )
    grads["transforms"] = g.transforms.grad.numpy()
    base = {"background": bg0, "light": np.array([LIGHT[:4], [LIGHT[4], 0, 0, 0]]), **p}
    v = rng.normal(size=np.shape(base[name]))
    if name == "light":
        v[1, 1:] = 0.0  # unused entries
    assert np.abs(grads[name] * (v != 0)).max() > 0

    def at(eps):
        q = {k: np.array(x, copy=True) for k, x in base.items()}
        q[name] = base[name] + eps * v
        gq = Gaussians(**{k: q[k] for k in p}, dtype="float64", device="cpu")
        return loss(gq, tuple(q["background"]), (*q["light"][0], q["light"][1, 0]))

    h = 1e-6
    fd = (at(h) - at(-h)) / (2 * h)
    ad = float(np.sum(grads[name] * v))
    assert abs(ad - fd) <= 1e-6 * max(1.0, abs(fd)), (name, ad, fd)


def test_light_shades_by_lambert_and_unlit_is_unchanged():
    # One flat splat facing +z seen head-on from +z: shade = ambient + max(0, n·L) + headlight·|n·v|.
    g = Gaussians.from_values(
        np.zeros((1, 3)), scales=[[0.2, 0.2, 0.01]], opacities=0.9, colors=[[0.6, 0.4, 0.2]], dtype="float64"
    )
    cam = Camera.look_at([0.0, 0.0, 3.0], [0.0, 0.0, 0.0], width=17, height=17)
    plain = render(g, cam).colour.numpy()[8, 8]
    lit = render(g, cam, light=(0.2, 0.1, 0.3, 0.5, 0.25)).colour.numpy()[8, 8]
    np.testing.assert_allclose(lit, plain * (0.2 + 0.5 + 0.25), rtol=1e-12)
    away = render(g, cam, light=(0.2, 0.0, 0.0, -0.5, 0.0)).colour.numpy()[8, 8]  # light behind: ambient only
    np.testing.assert_allclose(away, plain * 0.2, rtol=1e-12)
    with pytest.raises(ValueError, match="light must be 5 finite numbers"):
        render(g, cam, light=(1.0, 2.0))


def _bent_cloth(n=8):
    """A cloth bent into a dome (normals in every direction, so a directional light is identifiable)."""
    u, v = np.meshgrid(np.linspace(-0.4, 0.4, n + 1), np.linspace(-0.4, 0.4, n + 1), indexing="ij")
    X = np.stack([u, 0.25 * np.cos(2.5 * u) * np.cos(2.5 * v), v], axis=-1).reshape(-1, 3)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return X, tris


def _cams():
    return [
        Camera.look_at([1.4 * np.sin(t), 1.2, 1.4 * np.cos(t)], [0.0, 0.1, 0.0], width=40, height=32)
        for t in (0.4, 2.5, 4.6)
    ]


def _poses(X):
    """The cloth in three poses (as is, turned 30° about z, turned 30° about x): with one pose per-splat
    colours absorb any directional light (each splat has one normal), so the light is identifiable only
    across poses."""
    a = np.radians(30.0)
    c, s = np.cos(a), np.sin(a)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    out = [X, X @ Rz.T, X @ Rx.T]
    return out


def test_appearance_recovers_palette_background_and_light():
    # Frames rendered by pliant with another palette (a two-colour checker), another background and a light;
    # the appearance stage starts from the generated texture and recovers them.
    X, tris = _bent_cloth()
    poses = _poses(X)
    cams = _cams()
    g_true, b_true = surface_gaussians(X, tris, dtype="float64", device="cpu")
    centres = g_true.means.numpy()
    odd = (np.floor(centres[:, 0] / 0.2) + np.floor(centres[:, 2] / 0.2)) % 2 == 1
    albedo = np.where(odd[:, None], [0.15, 0.25, 0.8], [0.9, 0.8, 0.2])
    p = g_true.numpy()
    p["sh"][:, 0] = (albedo - 0.5) / 0.28209479177387814
    b_true.gaussians = Gaussians(**p, dtype="float64", device="cpu")
    bg_true = (0.75, 0.78, 0.8)
    light_true = (0.3, -0.2, 0.6, 0.3, 0.2)
    truth = SceneSplats(b_true, 0, len(X), bg_true, light_true)
    images = [[truth.image(x, c) for c in cams] for x in poses]

    _, b = surface_gaussians(X, tris, dtype="float64", device="cpu")  # the generated texture, on black
    splats = SceneSplats(b, 0, len(X), (0.0, 0.0, 0.0))
    res = fit_splat_appearance(splats, cams, poses, images, iterations=300)
    assert res.psnr_before < 15.0 and res.psnr_after > 40.0, (res.psnr_before, res.psnr_after)
    np.testing.assert_allclose(res.background, bg_true, atol=0.01)
    assert res.sh_degree == 1
    # Albedo and light share one scale (albedo · shade), so the light's direction is the figure (its size
    # relative to the ambient converges slowly: 0.6 of the truth after 300 steps).
    L_fit, L_true = np.array(res.light[1:4]), np.array(light_true[1:4])
    cos = L_fit @ L_true / np.linalg.norm(L_fit) / np.linalg.norm(L_true)
    assert np.degrees(np.arccos(min(cos, 1.0))) < 10.0, (L_fit, L_true)
    # A held-out pose (turned 20° about y and 15° about x): the fitted appearance draws it too.
    a, b2 = np.radians(20.0), np.radians(15.0)
    Ry = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(b2), -np.sin(b2)], [0.0, np.sin(b2), np.cos(b2)]])
    x_new = X @ (Rx @ Ry).T
    mse = np.mean([np.mean((splats.image(x_new, c) - truth.image(x_new, c)) ** 2) for c in cams])
    assert -10.0 * np.log10(mse) > 30.0, -10.0 * np.log10(mse)


def test_sample_colours_reads_the_pixel_under_each_point():
    cam = Camera.look_at([0.0, 0.0, 2.0], [0.0, 0.0, 0.0], width=9, height=7)
    img = np.zeros((7, 9, 3))
    img[3, 4] = (0.1, 0.2, 0.3)
    out = sample_colours(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 5.0]]), [cam], [img])
    np.testing.assert_allclose(out, [[0.1, 0.2, 0.3], [0.5, 0.5, 0.5]])  # the second is behind the camera


def test_appearance_keeps_a_start_that_already_draws_the_images():
    """Images rendered from the splats themselves: the fitted appearance (a few steps from the sampled
    colours) draws them worse than the start, so the stage keeps the start, splats and background alike."""
    X, tris = _bent_cloth()
    cams = _cams()
    _, b = surface_gaussians(X, tris, dtype="float64", device="cpu")
    splats = SceneSplats(b, 0, len(X), (0.2, 0.3, 0.4))
    images = [[splats.image(X, c) for c in cams]]
    start = b.gaussians.numpy()
    res = fit_splat_appearance(splats, cams, [X], images, iterations=5)
    assert res.psnr_after == res.psnr_before > 60.0
    assert res.background == (0.2, 0.3, 0.4)
    for k, v in b.gaussians.numpy().items():
        np.testing.assert_array_equal(v, start[k])
