"""Geometry from calibrated pictures (issue 37): projection identical to pliant's rasteriser, space carving of
a known box from exact and pliant-rendered masks, free-space carving from depth, the automatic search box,
depth back-projection, radius outlier removal, the RANSAC floor and per-frame clouds in the observation
file's layout."""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl
from pliant.gaussians import Camera, Gaussians, render
from pliant.geometry import (
    backproject,
    carve,
    fit_plane,
    frame_clouds,
    hull_bounds,
    project,
    remove_outliers,
    view_agreement,
)
from pliant.io import Observations

#: The soft_box scene's box at rest [m] (0.3 m cube centred at y = 0.5).
BLO, BHI = np.array([-0.15, 0.35, -0.15]), np.array([0.15, 0.65, 0.15])
CENTRE = 0.5 * (BLO + BHI)
W, H = 200, 150


def _ring(distance: float, elevations: list[float], fov: float, azimuth0: float = 0.0) -> list[Camera]:
    """Cameras at ``distance`` [m] from the box's centre, 90° apart in azimuth, looking at it."""
    cams = []
    for k, el in enumerate(elevations):
        a, e = np.radians(azimuth0 + 90.0 * k), np.radians(el)
        eye = CENTRE + distance * np.array([np.cos(e) * np.cos(a), np.sin(e), np.cos(e) * np.sin(a)])
        cams.append(Camera.look_at(eye, CENTRE, fov_y=fov, width=W, height=H))
    return cams


#: Far cameras facing the box's four side faces: their visual hull of the box is within a²/D ≈ 7.5 mm of it
#: (a the half size, D the distance), under one 1 cm voxel.
FAR = _ring(3.0, [0.0, 0.0, 0.0, 0.0], 10.0)
#: Cameras above and below in turn (a tetrahedron): every face is seen, but the visual hull of four views
#: bulges by centimetres; depth closes it.
TETRA = _ring(1.2, [35.0, -35.0, 35.0, -35.0], 30.0, 30.0)


def _stack(cams: list[Camera]) -> tuple[np.ndarray, np.ndarray]:
    return np.stack([c.K for c in cams]), np.stack([c.world_to_camera for c in cams])


def _box_pictures(cams: list[Camera], lo=BLO, hi=BHI) -> tuple[np.ndarray, np.ndarray]:
    """Exact masks and depth (camera z of the first hit) [C, H, W] of the box [lo, hi]: each pixel centre's
    ray against the box's slabs."""
    masks, depth = [], []
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    for cam in cams:
        q = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], axis=-1)
        d = q @ cam.rotation  # world direction with camera z = 1: the ray parameter is the depth
        with np.errstate(divide="ignore", invalid="ignore"):
            t0, t1 = (lo - cam.position) / d, (hi - cam.position) / d
        near = np.nanmax(np.minimum(t0, t1), axis=-1)
        far = np.nanmin(np.maximum(t0, t1), axis=-1)
        hit = (near <= far) & (far > 0.0)
        masks.append(hit)
        depth.append(np.where(hit, near, 0.0))
    return np.array(masks), np.array(depth)


def _box_distance(p: np.ndarray, lo=BLO, hi=BHI) -> np.ndarray:
    """Signed distance [m] of points to the box's surface (negative inside)."""
    q = np.abs(p - 0.5 * (lo + hi)) - 0.5 * (hi - lo)
    return np.where(np.all(q < 0, axis=1), q.max(axis=1), np.linalg.norm(np.maximum(q, 0.0), axis=1))


def _iou(vox) -> float:
    """Intersection over union of the kept voxels and the voxels whose centres lie inside the true box."""
    c = vox.origin + (np.argwhere(np.ones(vox.shape, dtype=bool)) + 0.5) * vox.spacing
    inside = np.all(np.abs(c - CENTRE) < 0.15, axis=1)
    occ = vox.occupied.reshape(-1)
    return float((occ & inside).sum() / (occ | inside).sum())


def _face_errors(vox) -> np.ndarray:
    """[2, 3] errors of the kept voxels' box faces against the true box, in voxels."""
    lo, hi = vox.bounds()
    return np.stack([lo - BLO, hi - BHI]) / vox.spacing


# ------------------------------------------------------------------------------------------------ project
def test_project_agrees_with_the_rasteriser_to_1e9_px(monkeypatch):
    """project() gives the pixel coordinates pliant's rasteriser computes for Gaussian means (float64)."""
    import pliant.gaussians._render as R

    cam = Camera.look_at([0.4, 0.9, 1.3], [0.0, 0.45, 0.0], width=W, height=H)
    rng = np.random.default_rng(3)
    means = rng.uniform(-0.3, 0.3, size=(500, 3)) + [0.0, 0.5, 0.0]
    seen = {}
    launch = R.wp.launch

    def spy(kernel, *args, **kw):
        launch(kernel, *args, **kw)
        if kernel is R.project_kernel:
            seen["mean2d"], seen["depth"] = kw["outputs"][0], kw["outputs"][2]

    monkeypatch.setattr(R.wp, "launch", spy)
    render(Gaussians.from_values(means, dtype="float64", device="cpu"), cam)
    uv, z = project(means, cam.K, cam.world_to_camera)
    np.testing.assert_allclose(uv, seen["mean2d"].numpy(), rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(z, seen["depth"].numpy(), rtol=0.0, atol=1e-12)
    # the homogeneous form K [R | t] p, and NaN behind the camera
    h = (cam.K @ cam.world_to_camera[:3] @ np.c_[means, np.ones(len(means))].T).T
    np.testing.assert_allclose(uv, h[:, :2] / h[:, 2:], rtol=0.0, atol=1e-9)
    uv_b, z_b = project(2.0 * cam.position - means[:1], cam.K, cam.world_to_camera)
    assert z_b[0] < 0 and np.isnan(uv_b).all()


# -------------------------------------------------------------------------------------------------- carve
def test_carving_exact_masks_recovers_the_box_within_one_voxel():
    masks, _ = _box_pictures(FAR)
    K, T = _stack(FAR)
    vox = carve(K, T, masks, BLO - 0.1, BHI + 0.1, 0.01)
    assert vox.shape == (50, 50, 50) and vox.occupied.sum() == len(vox.centres)
    assert np.abs(_face_errors(vox)).max() <= 1.0 + 1e-9
    # every voxel whose centre is inside the box is kept (the visual hull contains the object)
    i = np.argwhere(np.ones(vox.shape, dtype=bool))
    inside = np.all(np.abs(vox.origin + (i + 0.5) * vox.spacing - CENTRE) < 0.15, axis=1)
    assert vox.occupied.reshape(-1)[inside].all()
    # the footprint test keeps a superset
    wide = carve(K, T, masks, BLO - 0.1, BHI + 0.1, 0.01, footprint=True)
    assert np.all(wide.occupied >= vox.occupied) and wide.occupied.sum() > vox.occupied.sum()


def test_carving_pliant_rendered_masks_recovers_the_box_within_one_voxel():
    """The soft_box scene's Gaussians rendered by pliant (alpha > 0.5 as the mask), four cameras 200×150."""
    from pliant.gaussians._scene import scene_gaussians

    scene = pl.scene.build_scene(pl.scene.load_scene("soft_box"))
    x0 = scene.model.particle_q_np
    np.testing.assert_allclose([x0.min(axis=0), x0.max(axis=0)], [BLO, BHI], atol=1e-6)
    splats = scene_gaussians(scene)
    alpha = np.array([splats.render(x0, cam).alpha.numpy() for cam in FAR])
    K, T = _stack(FAR)
    vox = carve(K, T, alpha, BLO - 0.1, BHI + 0.1, 0.01)  # float alpha: > 0.5 is the object
    err = _face_errors(vox)
    assert np.abs(err).max() <= 1.0 + 1e-9, err
    assert _iou(vox) > 0.85  # the splats' soft edges widen the silhouettes by about a centimetre


def test_carving_observe_images_masks_contains_the_box():
    """``observe_images(masks=True)``'s four ring cameras (35° above, azimuths 30° + 90° k) see no face
    head-on and none from below, so their hull bulges (tens of voxels under the box); it still holds
    every voxel of the box away from its corners, which surface splats cover with alpha < 0.5."""
    from pliant.fit import observe_images

    scene = pl.scene.build_scene(pl.scene.load_scene("soft_box"))
    obs = observe_images(scene, frames=2, cameras=4, image_size=(W, H), masks=True)
    lo, hi = hull_bounds(obs.K, obs.world_to_camera, obs.masks[:, 0])
    assert np.all(lo < BLO) and np.all(hi > BHI)
    vox = carve(obs.K, obs.world_to_camera, obs.masks[:, 0], lo, hi, 0.01)
    c = vox.origin + (np.argwhere(np.ones(vox.shape, dtype=bool)) + 0.5) * vox.spacing
    inner = np.all(np.abs(c - CENTRE) < 0.15 - 0.01, axis=1)
    assert vox.occupied.reshape(-1)[inner].all()


def test_depth_closes_the_visual_hull_and_unseen_voxels_stay():
    masks, depth = _box_pictures(TETRA)
    K, T = _stack(TETRA)
    s = 0.005
    hull = carve(K, T, masks, BLO - 0.1, BHI + 0.1, s)
    assert np.abs(_face_errors(hull)).max() > 5.0  # four silhouettes alone bulge by centimetres
    vox = carve(K, T, masks, BLO - 0.1, BHI + 0.1, s, depth=depth)
    assert np.abs(_face_errors(vox)).max() <= 1.0 + 1e-9
    assert _iou(vox) > 0.99 and _iou(hull) < 0.8
    assert np.all(vox.occupied <= hull.occupied)
    # a fifth camera looking away from the box sees only background: what lies outside its image stays
    away = Camera.look_at(CENTRE + [0.0, 0.0, 2.0], CENTRE + [0.0, 0.0, 4.0], width=W, height=H)
    K5, T5 = _stack([*TETRA, away])
    m5 = np.concatenate([masks, np.zeros((1, H, W), dtype=bool)])
    d5 = np.concatenate([depth, np.zeros((1, H, W))])
    same = carve(K5, T5, m5, BLO - 0.1, BHI + 0.1, s, depth=d5)
    np.testing.assert_array_equal(same.occupied, vox.occupied)
    assert same.seen_by.max() == 4 and same.sole[4] == 0


def test_a_camera_that_disagrees_stands_out_in_sole():
    masks, _ = _box_pictures(TETRA)
    K, T = _stack(TETRA)
    good = carve(K, T, masks, BLO - 0.1, BHI + 0.1, 0.01).sole
    assert good.max() < 1.2 * good.min()  # symmetric views remove alike
    masks[2] = np.roll(masks[2], 25, axis=1)  # camera 2's masks shifted by 25 px (a wrong pose)
    vox = carve(K, T, masks, BLO - 0.1, BHI + 0.1, 0.01)
    assert int(np.argmax(vox.sole)) == 2 and vox.sole[2] > 2.0 * np.delete(vox.sole, 2).max()


def test_view_agreement_is_one_for_consistent_views_and_drops_for_a_shifted_one():
    masks, _ = _box_pictures(TETRA)
    K, T = _stack(TETRA)
    assert view_agreement(K, T, masks, BLO - 0.1, BHI + 0.1, 0.01).min() > 0.99
    masks[2] = np.roll(masks[2], 25, axis=1)
    a = view_agreement(K, T, masks, BLO - 0.1, BHI + 0.1, 0.01)
    assert int(np.argmin(a)) == 2 and a[2] < 0.85


@pytest.mark.parametrize("cams", [FAR, TETRA], ids=["far", "tetra"])
def test_hull_bounds_contains_the_box(cams):
    masks, _ = _box_pictures(cams)
    lo, hi = hull_bounds(*_stack(cams), masks)
    assert np.all(lo < BLO) and np.all(hi > BHI)
    assert np.all(hi - lo < 3.0 * (BHI - BLO))  # a search box: the hull and a margin


# -------------------------------------------------------------------------------------------- backproject
def test_backprojected_exact_depth_lies_on_the_box():
    masks, depth = _box_pictures(TETRA)
    K, T = _stack(TETRA)
    for c in range(len(TETRA)):
        p = backproject(depth[c], K[c], T[c], masks[c])
        assert p.shape == (masks[c].sum(), 3)
        assert np.abs(_box_distance(p)).max() < 1e-9


def test_backprojected_rendered_depth_lies_on_the_object():
    """pliant's rasteriser's depth of a wall of splats facing a tilted camera (every splat at the same camera
    z, so the expected depth is exact) back-projects onto the wall; the soft_box's rendered depth, a blend of
    the front splats and (through their residual transmittance) the ones behind, lands within centimetres,
    inside the box."""
    from pliant.gaussians._scene import scene_gaussians

    cam = TETRA[1]
    g = np.mgrid[-10:11, -10:11].reshape(2, -1).T * 0.02
    wall_cam = np.c_[g, np.full(len(g), 1.1)]  # camera coordinates: a square wall at z = 1.1 m
    wall = (wall_cam - cam.translation) @ cam.rotation
    out = render(Gaussians.from_values(wall, scales=0.02, opacities=0.99, dtype="float64", device="cpu"), cam)
    alpha, depth = out.alpha.numpy(), out.depth.numpy()
    p = backproject(depth, cam.K, cam.world_to_camera, alpha > 0.5)
    assert len(p) > 1000
    n = cam.rotation[2]  # the wall's normal: the optical axis
    np.testing.assert_allclose(p @ n - wall[0] @ n, 0.0, atol=1e-9)
    scene = pl.scene.build_scene(pl.scene.load_scene("soft_box"))
    x0 = scene.model.particle_q_np
    out = scene_gaussians(scene).render(x0, cam)
    p = backproject(out.depth.numpy(), cam.K, cam.world_to_camera, out.alpha.numpy() > 0.5)
    d = _box_distance(p)
    assert -0.03 < np.median(d) < 0.0 and np.percentile(np.abs(d), 90) < 0.06


# ------------------------------------------------------------------------------------------- point clouds
def test_remove_outliers_keeps_dense_points_and_drops_isolated_ones():
    rng = np.random.default_rng(0)
    dense = np.mgrid[0:8, 0:8, 0:8].reshape(3, -1).T * 0.002  # 2 mm lattice
    lonely = rng.uniform(0.1, 0.2, size=(20, 3)) * rng.choice([-1.0, 1.0], size=(20, 3))
    pts = np.concatenate([dense, lonely])
    keep = remove_outliers(pts, radius=0.0045, min_neighbors=6)
    # the closed form: neighbours counted by brute force
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    np.testing.assert_array_equal(keep, (d <= 0.0045).sum(axis=1) - 1 >= 6)
    assert keep[: len(dense)].all() and not keep[len(dense) :].any()


def test_fit_plane_finds_the_floor_and_nothing_on_a_sphere():
    rng = np.random.default_rng(1)
    tilt = np.radians(3.0)
    n_true = np.array([np.sin(tilt), np.cos(tilt), 0.0])
    xz = rng.uniform(-0.5, 0.5, size=(2000, 2))
    floor = np.c_[xz[:, 0], np.zeros(2000), xz[:, 1]]
    floor[:, 1] = (0.02 - n_true[0] * floor[:, 0]) / n_true[1] + rng.normal(0.0, 0.001, 2000)
    obj = rng.uniform([-0.1, 0.1, -0.1], [0.1, 0.3, 0.1], size=(1000, 3))
    plane = fit_plane(np.concatenate([floor, obj]), tol=0.004, seed=2)
    assert plane is not None
    assert np.degrees(np.arccos(plane.normal @ n_true)) < 0.3
    assert abs(plane.height - 0.02 / n_true[1]) < 0.001
    assert abs(plane.inlier_fraction - 2000 / 3000) < 0.01 and plane.inliers[:2000].mean() > 0.99
    sphere = rng.normal(size=(3000, 3))
    sphere = 0.1 * sphere / np.linalg.norm(sphere, axis=1, keepdims=True) + [0.0, 0.5, 0.0]
    assert fit_plane(sphere, tol=0.004) is None
    wall = np.c_[xz[:, 0], xz[:, 0] + 0.5, xz[:, 1]]  # a 45° ramp is not a floor
    assert fit_plane(wall, tol=0.004) is None


# ----------------------------------------------------------------------------------------- frame clouds
def test_frame_clouds_have_the_observation_layout_and_lie_on_each_frames_box():
    shift = np.array([0.05, -0.02, 0.0])
    pics = [_box_pictures(TETRA, BLO + s, BHI + s) for s in (np.zeros(3), shift)]
    masks = np.stack([p[0] for p in pics], axis=1)  # [C, T, H, W]
    depth_mm = np.round(np.stack([p[1] for p in pics], axis=1) * 1000.0).astype(np.uint16)
    K, T = _stack(TETRA)
    cloud, count = frame_clouds(K, T, masks, depth=depth_mm, max_points=500)
    assert cloud.shape == (2, 500, 3) and count.tolist() == [500, 500] and count.dtype == np.int64
    for t, s in enumerate((np.zeros(3), shift)):
        assert np.abs(_box_distance(cloud[t, : count[t]], BLO + s, BHI + s)).max() < 0.002  # mm rounding
    again, _ = frame_clouds(K, T, masks, depth=depth_mm, max_points=500)
    np.testing.assert_array_equal(again, cloud)  # deterministic
    # masks only: the carved hull's surface voxels (far cameras: the hull is within a voxel of the box)
    fmasks = np.stack([_box_pictures(FAR, BLO + s, BHI + s)[0] for s in (np.zeros(3), shift)], axis=1)
    cloud2, count2 = frame_clouds(*_stack(FAR), fmasks, lo=BLO - 0.1, hi=BHI + 0.15, spacing=0.01)
    for t, s in enumerate((np.zeros(3), shift)):
        assert np.abs(_box_distance(cloud2[t, : count2[t]], BLO + s, BHI + s)).max() < 0.01 * np.sqrt(3)
    # the arrays feed an observation file as they are
    obs = Observations.from_arrays(
        t=np.array([0.0, 0.1]), points=np.zeros((2, 1, 3)), cloud=cloud, cloud_count=count
    )
    assert obs.cloud.shape == (2, 500, 3)


# ------------------------------------------------------------------------------------------------- errors
@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda K, T, m: carve(K, T, m[0], BLO, BHI, 0.01), r"carve: masks: expected \[C, H, W\]"),
        (lambda K, T, m: carve(K[:3], T[:3], m, BLO, BHI, 0.01), r"cameras: 3 cameras \(K\) but masks for 4"),
        (lambda K, T, m: carve(K, T, m, BLO, BHI, 0.0), r"carve: spacing: expected a voxel edge > 0 m"),
        (lambda K, T, m: carve(K, T, m, BHI, BLO, 0.01), r"carve: expected lo < hi"),
        (lambda K, T, m: carve(K, T, m, BLO, BHI, 1e-5), r"carve: .* voxels; use a larger spacing"),
        (
            lambda K, T, m: carve(K, T, m, BLO, BHI, 0.01, depth=np.zeros((4, 2, 2))),
            r"carve: depth: expected \[C=4, H=150, W=200\] like masks",
        ),
        (
            lambda K, T, m: hull_bounds(K, T, np.concatenate([m[:3], np.zeros_like(m[:1])])),
            r"hull_bounds: masks: camera 3 has no object pixel; drop that camera",
        ),
        (lambda K, T, m: hull_bounds(K[:1], T[:1], m[:1]), r"hull_bounds: .* at least two cameras"),
        (lambda K, T, m: backproject(np.zeros(5), K[0], T[0]), r"backproject: depth: expected \[H, W\]"),
        (
            lambda K, T, m: backproject(np.ones((H, W)), K[0], T[0], m[0, :5]),
            r"backproject: mask: expected \(150, 200\) like depth",
        ),
        (lambda K, T, m: frame_clouds(K, T, m), r"frame_clouds: masks: expected \[C, T, H, W\]"),
        (lambda K, T, m: remove_outliers(np.zeros((3, 3)), 0.0, 1), r"remove_outliers: radius: expected > 0"),
    ],
)
def test_bad_input_fails_in_one_line_naming_the_argument(call, match):
    masks, _ = _box_pictures(FAR)
    with pytest.raises(ValueError, match=match) as e:
        call(*_stack(FAR), masks)
    assert "\n" not in str(e.value)


def test_a_huge_focal_length_projects_outside_without_warnings():
    """Found by tests/test_fuzz_observations.py: fy = 1e308 px overflowed in the projection (a
    RuntimeWarning on every carve); its pixels lie far outside the image: that view carves nothing."""
    import warnings

    K, T = _stack(FAR)
    masks, _ = _box_pictures(FAR)
    K[0, 1, 1] = 1e308
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        uv, _ = project([CENTRE + 0.1], K[0], T[0])
        vox = carve(K, T, masks, BLO - 0.05, BHI + 0.05, 0.02)
    assert abs(uv[0, 1]) > 1e300 and 0 <= uv[0, 0] < W
    others = carve(K[1:], T[1:], masks[1:], BLO - 0.05, BHI + 0.05, 0.02)
    np.testing.assert_array_equal(vox.occupied, others.occupied)
