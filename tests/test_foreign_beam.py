"""The MuJoCo beam camera fixture of issue 37 (tests/data/foreign/mujoco_beam_*, made by
benchmarks/peers/observe_mujoco_beam.py): what its sidecar says, that the truth is a clamped beam swinging
under its own weight, and that pliant's camera model puts the truth on the masks and the depth on the truth.

The files hold ``depth``, which pliant.io.Observations does not know yet, so they are read with NumPy.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import twin_truth as tt

from pliant.gaussians._camera import Camera

DATA = Path(__file__).resolve().parent / "data" / "foreign"
VIDEO_KEYS = {"t", "images", "masks", "depth", "K", "world_to_camera"}


@pytest.fixture(scope="module")
def meta():
    return json.loads((DATA / "mujoco_beam_video.json").read_text())


@pytest.fixture(scope="module")
def truth():
    return tt.load_beam_truth()


def _load(name: str) -> dict[str, np.ndarray]:
    with np.load(DATA / f"{name}.npz", allow_pickle=False) as z:
        assert set(z.files) == VIDEO_KEYS
        return {k: z[k] for k in z.files}


@pytest.fixture(scope="module", params=["mujoco_beam_video", "mujoco_beam_heldout"])
def footage(request):
    return request.param, _load(request.param)


def test_sidecar_and_arrays_say_the_same(meta, truth, footage):
    name, v = footage
    assert meta["data"].startswith("SYNTHETIC") and meta["engine"].startswith("mujoco 4.0")
    assert meta["renderer"].startswith("MuJoCo") and "OpenGL" in meta["renderer"]
    C = meta["cameras"] if name.endswith("video") else meta["heldout_cameras"]
    W, H = meta["image_size"]
    T = meta["frames"]
    assert v["images"].shape == (C, T, H, W, 3) and v["images"].dtype == np.uint8
    assert v["masks"].shape == (C, T, H, W) and v["masks"].dtype == bool
    assert v["depth"].shape == (C, T, H, W) and v["depth"].dtype == np.uint16
    assert v["K"].shape == (C, 3, 3) and v["world_to_camera"].shape == (C, 4, 4)
    np.testing.assert_allclose(v["t"], np.arange(T) / meta["fps"], atol=1e-12)
    np.testing.assert_array_equal(truth["t"], v["t"])
    eyes = np.asarray(meta["camera_eyes_m"]["fit" if name.endswith("video") else "heldout"]).reshape(C, 3)
    for c in range(C):
        cam = Camera(v["K"][c], v["world_to_camera"][c], W, H)
        np.testing.assert_allclose(cam.position, eyes[c], atol=1e-9)


def test_truth_is_a_clamped_beam_under_its_own_weight(meta, truth):
    x, tets, pinned, mass = truth["x"], truth["tets"], truth["pinned"], truth["mass"]
    size = np.ptp(x[0], axis=0)
    np.testing.assert_allclose(size, [0.4, 0.06, 0.08], atol=1e-12)
    # The clamp is the x = 0 face: exactly the points that never move.
    np.testing.assert_array_equal(pinned, np.flatnonzero(np.abs(x[0, :, 0]) < 1e-12))
    still = np.abs(x - x[:1]).max(axis=(0, 2)) == 0.0
    np.testing.assert_array_equal(np.flatnonzero(still), pinned)
    # MuJoCo's own masses: rho x volume spread evenly over the points.
    volume = tt.tet_volumes(x[0], tets).sum()
    rho = meta["material_engine"]["density_kg_m3"]
    np.testing.assert_allclose(mass, rho * volume / len(mass), rtol=1e-12)
    # It sags a visible 5-15 cm on average, swings on to the end and never reaches the floor.
    tip = np.abs(x[0, :, 0] - 0.4) < 1e-12
    sag = x[0, tip, 1].mean() - x[:, tip, 1].mean(axis=1)
    late = tt.heldout_frames(len(x))
    assert 0.05 < sag[len(x) // 2 :].mean() < 0.15
    assert 0.5 * np.ptp(sag[late]) > 0.02
    assert x[..., 1].min() > 0.3
    assert meta["figures"]["tip_sag_max_m"] == pytest.approx(sag.max(), rel=1e-9)


def _grow(mask: np.ndarray) -> np.ndarray:
    grown = mask.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            grown |= np.roll(np.roll(mask, dy, axis=0), dx, axis=1)
    return grown


def test_cameras_see_the_truth_on_the_masks_and_depth_on_the_truth(footage, truth):
    _, v = footage
    C, T, H, W = v["masks"].shape
    x, tets = truth["x"], truth["tets"]
    u, w = np.meshgrid(np.arange(W), np.arange(H))
    flipped, err = [], []
    rng = np.random.default_rng(0)
    for c in range(C):
        cam = Camera(v["K"][c], v["world_to_camera"][c], W, H)
        R, tr = cam.rotation, cam.translation
        rays = np.stack([(u - cam.cx) / cam.fx, (w - cam.cy) / cam.fy, np.ones_like(u, float)], -1)
        for f in range(0, T, 15):
            mask = v["masks"][c, f]
            # The whole beam is in view, away from the image's edges, and every true vertex projects onto it.
            assert not (mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())
            q = x[f] @ R.T + tr
            px = np.round(q[:, :2] / q[:, 2:] * [cam.fx, cam.fy] + [cam.cx, cam.cy]).astype(int)
            assert _grow(mask)[px[:, 1], px[:, 0]].all(), (c, f)
            flipped.append(_grow(mask)[::-1][px[:, 1], px[:, 0]].mean())
            # Depth is the distance along the optical axis [mm]: back-projected, it lands on the true surface.
            z = v["depth"][c, f] / 1000.0
            sel = np.flatnonzero(mask & (z > 0))
            sel = rng.choice(sel, size=min(200, sel.size), replace=False)  # enough pixels, kept quick
            world = (rays.reshape(-1, 3)[sel] * z.reshape(-1)[sel, None] - tr) @ R
            err.append(tt.distance_to_surface(world, x[f], tets))
    err = np.concatenate(err)
    # Measured: median 0.45 mm, 95th percentile 0.85 mm (mm rounding); depth 1 % off gives a median > 2.5 mm.
    assert np.median(err) < 1e-3 and np.percentile(err, 95) < 1.5e-3
    assert np.mean(flipped) < 0.6
