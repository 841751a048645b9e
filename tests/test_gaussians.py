"""pl.gaussians: the rasteriser against a dense NumPy oracle, its gradients against finite differences,
PLY round trips, and the clear errors for bad cameras, files and images."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl
from pliant.gaussians import Camera, Gaussians, render
from tests.test_gaussians_reference import reference_render

BG = (0.1, 0.2, 0.3)


def _scene(n=40, seed=1, deg=3, opacity=(0.2, 0.8), dtype="float64", device="cpu", requires_grad=False):
    rng = np.random.default_rng(seed)
    g = Gaussians.from_values(
        rng.uniform(-0.6, 0.6, (n, 3)),
        scales=rng.uniform(0.03, 0.12, (n, 3)),
        rotations=rng.normal(size=(n, 4)),
        opacities=rng.uniform(*opacity, n),
        colors=rng.uniform(0, 1, (n, 3)),
        sh_degree=deg,
    )
    p = g.numpy()
    p["sh"][:, 1:] = rng.normal(scale=0.2, size=p["sh"][:, 1:].shape)
    return Gaussians(**p, dtype=dtype, device=device, requires_grad=requires_grad)


def _camera(width=64, height=48):
    return Camera.look_at([0.3, 0.2, 3.0], [0.0, 0.0, 0.0], width=width, height=height)


@pytest.mark.parametrize("deg", [0, 1, 2, 3])
def test_forward_matches_dense_reference_float64(device, deg):
    # 70 x 45 is not a whole number of tiles; opacities up to 0.995 exercise the 0.99 clamp and, where
    # Gaussians pile up, the early stop at T < 1e-4; one Gaussian behind the camera is culled.
    g = _scene(n=60, seed=deg, deg=deg, opacity=(0.2, 0.995), device=device)
    p = g.numpy()
    p["means"][0] = [0.0, 0.0, 5.0]  # behind the camera at z = 3 looking at -z
    g = Gaussians(**p, dtype="float64", device=device)
    cam = _camera(70, 45)
    out = render(g, cam, background=BG)
    ref = reference_render(g.numpy(), cam, BG)
    assert out.colour.shape == (45, 70) and out.alpha.shape == (45, 70) and out.depth.shape == (45, 70)
    assert out.colour.numpy().shape == (45, 70, 3)
    assert ref[1].max() > 0.9  # the scene covers pixels
    for a, b in zip(out, ref):
        np.testing.assert_allclose(a.numpy(), b, atol=1e-5, rtol=0)


def test_forward_float32_close_to_reference(device):
    g = _scene(n=60, seed=5, deg=3, dtype="float32", device=device)
    cam = _camera()
    out = render(g, cam, background=BG)
    ref = reference_render(g.numpy(), cam, BG)
    np.testing.assert_allclose(out.colour.numpy(), ref[0], atol=1e-4)
    np.testing.assert_allclose(out.alpha.numpy(), ref[1], atol=1e-4)
    np.testing.assert_allclose(out.depth.numpy(), ref[2], atol=1e-3)  # depth ~3 m, float32 sums


def test_empty_and_all_culled_render_background():
    cam = _camera()
    g = Gaussians.from_values(np.array([[0.0, 0.0, 10.0]]), dtype="float64", device="cpu")  # behind
    c, a, d = render(g, cam, background=BG)
    np.testing.assert_array_equal(c.numpy(), np.broadcast_to(BG, (48, 64, 3)))
    assert a.numpy().max() == 0.0 and d.numpy().max() == 0.0


def _weights(shape, seed=7):
    rng = np.random.default_rng(seed)
    return rng.normal(size=shape + (3,)), rng.normal(size=shape), rng.normal(size=shape)


def _loss(g, cam, w):
    c, a, d = render(g, cam, BG)
    return (c.numpy() * w[0]).sum() + (a.numpy() * w[1]).sum() + (d.numpy() * w[2]).sum()


def _backward(g, cam, w):
    tape = wp.Tape()
    with tape:
        c, a, d = render(g, cam, BG)
    v3 = wp.vec3d if g.dtype == "float64" else wp.vec3
    s = wp.float64 if g.dtype == "float64" else wp.float32
    tape.backward(grads={c: wp.array(w[0], dtype=v3), a: wp.array(w[1], dtype=s), d: wp.array(w[2], dtype=s)})
    return tape


@pytest.mark.parametrize("name", ["means", "quats", "log_scales", "opacity_logits", "sh"])
def test_gradients_match_finite_differences_float64(name):
    # L = Σ w_c·colour + Σ w_a·alpha + Σ w_d·depth; directional derivative along a random direction, central
    # differences with h = 1e-6. The seeds are fixed: no (pixel, Gaussian) pair crosses the α ≥ 1/255 cut
    # or a tile boundary within ±h, so L is smooth there (a crossing would show as a gross mismatch).
    cam = _camera()
    w = _weights((48, 64))
    g = _scene(requires_grad=True)
    _backward(g, cam, w)
    names = ["means", "quats", "log_scales", "opacity_logits", "sh"]
    grad = g.parameters()[names.index(name)].grad.numpy()
    assert np.abs(grad).max() > 0
    rng = np.random.default_rng(3)
    p = g.numpy()
    v = rng.normal(size=p[name].shape)
    h = 1e-6

    def at(eps):
        q = {k: x.copy() for k, x in p.items()}
        q[name] = p[name] + eps * v
        return _loss(Gaussians(**q, dtype="float64", device="cpu"), cam, w)

    fd = (at(h) - at(-h)) / (2 * h)
    ad = float((grad * v).sum())
    assert abs(ad - fd) <= 1e-6 * max(1.0, abs(fd)), (name, ad, fd)


def test_gradients_float32_match_float64(device):
    cam = _camera()
    w = _weights((48, 64))
    g64 = _scene(requires_grad=True, device=device)
    g32 = _scene(requires_grad=True, dtype="float32", device=device)
    _backward(g64, cam, w)
    _backward(g32, cam, w)
    for a, b in zip(g32.parameters(), g64.parameters()):
        ga, gb = a.grad.numpy().astype(np.float64), b.grad.numpy()
        assert np.linalg.norm(ga - gb) <= 1e-3 * np.linalg.norm(gb)


def test_ply_round_trip(tmp_path):
    g = _scene(n=25, deg=3)
    path = tmp_path / "splat.ply"
    pl.gaussians.save_ply(g, path)
    h = pl.gaussians.load_ply(path, dtype="float64", device="cpu")
    for k, v in g.numpy().items():
        np.testing.assert_allclose(h.numpy()[k], v, rtol=1e-6, atol=1e-6)  # the file holds float32
    assert h.sh_degree == 3
    # the standard layout: x y z nx ny nz f_dc f_rest(45) opacity scale rot, f_rest channel-major
    header = path.read_bytes().split(b"end_header\n")[0].decode()
    props = [line.split()[-1] for line in header.splitlines() if line.startswith("property")]
    assert props[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert props[9:54] == [f"f_rest_{i}" for i in range(45)]
    assert props[54:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    raw = np.frombuffer(path.read_bytes()[len(header) + len("end_header\n") :], dtype="<f4").reshape(25, 62)
    np.testing.assert_allclose(raw[:, 9 + 15], g.numpy()["sh"][:, 1, 1], rtol=1e-6)  # f_rest_15: green, k=1


def test_ply_ascii_and_degree0(tmp_path):
    path = tmp_path / "a.ply"
    names = [
        "x",
        "y",
        "z",
        "f_dc_0",
        "f_dc_1",
        "f_dc_2",
        "opacity",
        "scale_0",
        "scale_1",
        "scale_2",
        "rot_0",
        "rot_1",
        "rot_2",
        "rot_3",
    ]
    row = [0.1, 0.2, 0.3, 1.0, 2.0, 3.0, 0.5, -3.0, -3.5, -4.0, 1.0, 0.0, 0.0, 0.0]
    text = "ply\nformat ascii 1.0\nelement vertex 2\n" + "".join(f"property double {n}\n" for n in names)
    text += "end_header\n" + " ".join(map(str, row)) + "\n" + " ".join(map(str, row)) + "\n"
    path.write_text(text)
    g = pl.gaussians.load_ply(path, dtype="float64", device="cpu")
    assert g.count == 2 and g.sh_degree == 0
    np.testing.assert_allclose(g.scales[0], np.exp([-3.0, -3.5, -4.0]))
    np.testing.assert_allclose(g.numpy()["sh"][1, 0], [1.0, 2.0, 3.0])


def test_ply_missing_properties_named(tmp_path):
    path = tmp_path / "bad.ply"
    text = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
    path.write_text(text + "end_header\n0 0 0\n")
    with pytest.raises(
        pl.gaussians.PlyError, match="missing required Gaussian properties: f_dc_0.*opacity.*rot_3"
    ):
        pl.gaussians.load_ply(path)
    path.write_text("not a ply\n")
    with pytest.raises(pl.gaussians.PlyError, match="not a PLY"):
        pl.gaussians.load_ply(path)


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian"])
def test_ply_header_counts_are_checked_against_the_file_before_allocating(tmp_path, fmt):
    """Issue 41: a header declaring 10¹⁰ vertices in a 200-byte file is a PlyError naming the element, the
    bytes it needs (2 per ASCII property, 4 per float32 one) and those the file has, at once (an ASCII
    file's rows were allocated from the header's count first)."""
    import time

    path = tmp_path / "huge.ply"
    head = f"ply\nformat {fmt} 1.0\nelement vertex 10000000000\n"
    head += "".join(f"property float {n}\n" for n in ("x", "y", "z")) + "end_header\n"
    path.write_bytes(head.encode() + b"0 0 0\n")
    t0 = time.perf_counter()
    with pytest.raises(pl.gaussians.PlyError) as info:
        pl.gaussians.load_ply(path)
    need = 10**10 * (2 * 3 if fmt == "ascii" else 3 * 4)
    assert (
        f"element 'vertex' declares 10000000000 rows, at least {need} bytes, but the file holds 6 bytes"
        in str(info.value)
    )
    assert time.perf_counter() - t0 < 1.0


def test_camera_validation():
    K = np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]])
    T = np.eye(4)
    Camera(K, T, 64, 48)
    with pytest.raises(ValueError, match="focal lengths must be positive"):
        Camera(np.diag([-50.0, 50.0, 1.0]), T, 64, 48)
    with pytest.raises(ValueError, match="focal lengths must be positive"):
        Camera(np.diag([50.0, 0.0, 1.0]), T, 64, 48)
    S = np.eye(4)
    S[0, 0] = 2.0
    with pytest.raises(ValueError, match="not rigid"):
        Camera(K, S, 64, 48)
    M = np.eye(4)
    M[0, 0] = -1.0  # a reflection: orthonormal but det −1
    with pytest.raises(ValueError, match="not rigid"):
        Camera(K, M, 64, 48)
    bad = K.copy()
    bad[0, 2] = np.nan
    with pytest.raises(ValueError, match="K has non-finite"):
        Camera(bad, T, 64, 48)
    with pytest.raises(ValueError, match="width and height"):
        Camera(K, T, 0, 48)
    with pytest.raises(ValueError, match="last row"):
        Camera(K, np.vstack([T[:3], [0, 0, 1, 1]]), 64, 48)


def test_look_at_conventions():
    # OpenCV: a point right of and above the target projects right of and above the principal point
    cam = Camera.look_at([0, 0, 2], [0, 0, 0], width=64, height=48)
    p = cam.rotation @ np.array([0.1, 0.1, 0.0]) + cam.translation
    u, v = cam.fx * p[0] / p[2] + cam.cx, cam.fy * p[1] / p[2] + cam.cy
    assert p[2] == pytest.approx(2.0) and u > cam.cx and v < cam.cy
    np.testing.assert_allclose(cam.position, [0, 0, 2], atol=1e-12)


def test_image_checks():
    cam = _camera()
    cam.check_image(np.zeros((48, 64, 3)))
    with pytest.raises(ValueError, match="size 32 x 48 .* camera is 64 x 48"):
        cam.check_image(np.zeros((48, 32, 3)))
    img = np.zeros((48, 64, 3))
    img[3, 4, 1] = np.nan
    with pytest.raises(ValueError, match="1 non-finite"):
        cam.check_image(img, "observed image")


def test_bad_gaussians_rejected():
    with pytest.raises(ValueError, match="non-finite"):
        Gaussians.from_values(np.array([[0.0, np.nan, 0.0]]))
    with pytest.raises(ValueError, match="SH coefficients per channel"):
        Gaussians(np.zeros((1, 3)), [[1, 0, 0, 0]], np.zeros((1, 3)), [0.0], np.zeros((1, 5, 3)))
    with pytest.raises(ValueError, match="opacities"):
        Gaussians.from_values(np.zeros((1, 3)), opacities=1.5)


def test_raster_benchmark_quick():
    from pliant import bench

    r = bench.run("gaussians_raster", quick=True, device="cpu")
    assert r["gaussian_pixels_per_s_forward"] > 0 and r["forward_backward_s"] >= 0
    assert 0.05 < r["sanity_covered_fraction"] < 1.0


def test_render_inside_a_tape_without_gradients_is_harmless():
    # Gaussians that need no gradient: the render is recorded but backward leaves everything finite
    g = _scene(n=10)
    cam = _camera()
    x = wp.array(np.ones(3), dtype=wp.float64, requires_grad=True)
    y = wp.zeros(3, dtype=wp.float64, requires_grad=True)
    tape = wp.Tape()
    with tape:
        c, _, _ = render(g, cam)
        wp.launch(_double, dim=3, inputs=[x, y])
    tape.backward(grads={y: wp.array(np.ones(3), dtype=wp.float64)})
    np.testing.assert_array_equal(x.grad.numpy(), 2.0)
    ref = reference_render(g.numpy(), cam)
    np.testing.assert_allclose(c.numpy(), ref[0], atol=1e-10)


@wp.kernel
def _double(x: wp.array(dtype=wp.float64), y: wp.array(dtype=wp.float64)):
    i = wp.tid()
    y[i] = wp.float64(2.0) * x[i]
