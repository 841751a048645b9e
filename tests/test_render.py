"""Tests for pliant.render: rasterizer, camera framing, video writing, export and plots."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import imageio.v3 as iio
import imageio_ffmpeg
import numpy as np
import pytest
import trimesh

from pliant.render import (
    Camera,
    Renderer,
    VideoWriter,
    export_obj,
    export_obj_sequence,
    export_ply,
    export_ply_sequence,
    export_usd,
    fit_order,
    plot_error_vs_dt,
    plot_phase_portrait,
    plot_series,
    realtime_indices,
    render_video,
    video,
    write_video,
)

BG = (0.2, 0.3, 0.4)
BG_U8 = np.array([51, 77, 102], np.uint8)  # round(255 * BG)


def _front_camera(w: int = 80, h: int = 60) -> Camera:
    return Camera(eye=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), fov_y=40.0, width=w, height=h)


def _flat_renderer(cam: Camera, **kw) -> Renderer:
    return Renderer(cam, ground=False, background=BG, ambient=1.0, **kw)


def _saturated(frames: np.ndarray, thresh: int = 40) -> np.ndarray:
    """Mask of object pixels: the default orange is saturated; ground/background are grey."""
    f = frames[..., :3].astype(np.int16)
    return (f.max(axis=-1) - f.min(axis=-1)) > thresh


def _sphere_drop(n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Icosphere (r = 0.2 m) falling from y = 1.2 m towards the ground, [T, N, 3] and faces."""
    ico = trimesh.creation.icosphere(subdivisions=2, radius=0.2)
    t = np.linspace(0.0, 0.4, n_frames)
    y = 1.2 - 0.5 * 9.81 * t**2  # stays above the ground (>= 0.41 m) over 0.4 s
    x = ico.vertices[None] + np.stack([np.zeros_like(t), y, np.zeros_like(t)], 1)[:, None]
    return x, np.asarray(ico.faces)


def _pixel(cam: Camera, p) -> tuple[int, int]:
    """(row, col) of the pixel containing the projection of world point p."""
    pix, _ = cam.project(np.asarray(p, float).reshape(1, 3))
    return int(pix[0, 1]), int(pix[0, 0])


def _read_mp4(path: Path, h: int, w: int) -> np.ndarray:
    """Decodes an MP4 with the bundled ffmpeg to uint8 [T, h, w, 3]; asserts H.264 + yuv420p."""
    cmd = [
        imageio_ffmpeg.get_ffmpeg_exe(),
        "-hide_banner",
        "-i",
        str(path),
        "-f",
        "rawvideo",
        "-pix_fmt",
        "rgb24",
        "-",
    ]
    res = subprocess.run(cmd, capture_output=True, check=True)
    info = res.stderr.decode(errors="replace")
    assert "Video: h264" in info and "yuv420p" in info and f"{w}x{h}" in info
    assert len(res.stdout) % (h * w * 3) == 0
    return np.frombuffer(res.stdout, np.uint8).reshape(-1, h, w, 3)


# ---------------------------------------------------------------------------------------------
# Rasterizer
# ---------------------------------------------------------------------------------------------


def test_triangle_covers_its_projection_and_nothing_else():
    """A triangle fills its projected area (within 3 %) with its colour and leaves background elsewhere."""
    cam = _front_camera()
    tri = np.array([[-0.8, -0.6, 0.0], [0.9, -0.5, 0.0], [0.1, 0.7, 0.0]])
    img = _flat_renderer(cam).render(tri, np.array([[0, 1, 2]]), colors=(1.0, 0.0, 0.0))
    assert img.shape == (60, 80, 3) and img.dtype == np.uint8
    pix, _ = cam.project(tri)
    covered = np.any(img != BG_U8, axis=-1)
    rows, cols = np.nonzero(covered)
    assert cols.min() >= np.floor(pix[:, 0].min()) and cols.max() <= np.ceil(pix[:, 0].max())
    assert rows.min() >= np.floor(pix[:, 1].min()) and rows.max() <= np.ceil(pix[:, 1].max())
    d1, d2 = pix[1] - pix[0], pix[2] - pix[0]
    area = 0.5 * abs(d1[0] * d2[1] - d1[1] * d2[0])
    assert abs(covered.sum() - area) < 0.03 * area
    centroid = pix.mean(axis=0).astype(int)
    assert tuple(img[centroid[1], centroid[0]]) == (255, 0, 0)  # ambient=1: unshaded colour
    assert np.all(img[~covered] == BG_U8)


def test_nearer_quad_wins_depth_test_regardless_of_order():
    """Where two quads overlap the one nearer the camera is visible, whatever the face order."""
    cam = _front_camera()
    quad = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    near = quad * [0.5, 0.5, 1] + [0.3, 0.3, 0.8]  # smaller, 0.8 m closer, offset up-right
    pts = np.vstack([quad, near])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    colors = np.array([[0, 0, 1]] * 4 + [[1, 0, 0]] * 4, float)  # far blue, near red
    r = _flat_renderer(cam)
    for f in (faces, faces[::-1]):
        img = r.render(pts, f, colors=colors)
        assert tuple(img[_pixel(cam, [0.3, 0.3, 0.8])]) == (255, 0, 0)
        assert tuple(img[_pixel(cam, [-0.7, -0.7, 0.0])]) == (0, 0, 255)


def test_particles_are_discs_of_the_requested_pixel_radius():
    """A particle drawn with point_radius_px=6 covers pi*6^2 pixels within 10 %, centred on its projection."""
    cam = _front_camera(120, 90)
    img = _flat_renderer(cam).render(np.array([[0.2, -0.1, 0.0]]), point_radius_px=6.0)
    covered = np.any(img != BG_U8, axis=-1)
    assert abs(covered.sum() - np.pi * 36) < 0.1 * np.pi * 36
    (px, py), _ = cam.project(np.array([[0.2, -0.1, 0.0]]))[0][0], None
    rows, cols = np.nonzero(covered)
    assert abs(cols.mean() + 0.5 - px) < 0.5 and abs(rows.mean() + 0.5 - py) < 0.5


def test_lambert_shading_two_sided_and_ground_under_object():
    """Lambert: a face along the light is white, a grazing one ambient, both sides alike; ground fades out."""
    cam = Camera.fit(np.array([[-1, 0, -1], [1, 1, 1]], float), width=96, height=72)
    r = Renderer(cam, ground=-0.5, light_dir=(0, 1, 0), ambient=0.2, shadows=False)
    quad_up = np.array([[-0.5, 0.5, -0.5], [0.5, 0.5, -0.5], [0.5, 0.5, 0.5], [-0.5, 0.5, 0.5]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    lit = r.render(quad_up, faces, colors=(1.0, 1.0, 1.0))
    lit_back = r.render(quad_up, faces[:, ::-1], colors=(1.0, 1.0, 1.0))
    quad_vertical = quad_up[:, [0, 2, 1]] + [0.0, 0.5, 0.0]  # faces +-z: grazing to a light from +y
    dim = r.render(quad_vertical, faces, colors=(1.0, 1.0, 1.0))
    assert lit[_pixel(cam, [0.0, 0.5, 0.0])].min() >= 250  # n.l = 1
    assert np.array_equal(lit, lit_back)  # two-sided: winding does not matter
    assert dim[_pixel(cam, [0.0, 0.5, 0.0])].max() <= 0.2 * 255 + 2  # ambient only
    ground = r.render(np.zeros((0, 3)))
    diff = np.abs(ground.astype(int) - np.round(r.background * 255)).max(axis=2)
    assert np.all(diff[-5:] > 20)  # checkerboard near the camera
    assert diff[:2].mean() < 0.5 * diff[-5:].mean()  # fading into the background far away


def test_ground_shadow_darkens_ground_below_object():
    """With shadows on, the ground straight below an object lit from above is darker than without."""
    cam = Camera.fit(np.array([[-1, 0, -1], [1, 1, 1]], float), width=96, height=72)
    quad = np.array([[-0.5, 0.6, -0.5], [0.5, 0.6, -0.5], [0.5, 0.6, 0.5], [-0.5, 0.6, 0.5]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    imgs = [
        Renderer(cam, ground=0.0, light_dir=(0, 1, 0), shadows=s).render(quad, faces) for s in (True, False)
    ]
    below = _pixel(cam, [0.0, 0.0, 0.45])  # under the front edge, not hidden by the quad
    assert imgs[0][below].mean() < 0.8 * imgs[1][below].mean()


def test_non_finite_points_are_skipped():
    """NaN vertices drop their triangles without corrupting the image."""
    cam = _front_camera()
    pts = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0, 0.5, 0], [np.nan, 0, 0]], float)
    r = _flat_renderer(cam)
    a = r.render(pts, np.array([[0, 1, 2]]))
    b = r.render(pts, np.array([[0, 1, 2], [0, 1, 3]]))
    assert np.array_equal(a, b)


# ---------------------------------------------------------------------------------------------
# Camera
# ---------------------------------------------------------------------------------------------


def test_camera_fit_keeps_every_point_in_frame():
    """Camera.fit puts all points of anisotropic, offset clouds inside the image and fills >= 50 % of it."""
    rng = np.random.default_rng(1)
    for scale, offset in [
        ((2.0, 0.1, 0.5), (5, 3, -2)),
        ((0.01, 0.3, 0.01), (0, 0, 0)),
        ((1, 1, 1), (0, -4, 0)),
    ]:
        pts = rng.normal(size=(2000, 3)) * scale + offset
        cam = Camera.fit(pts, width=320, height=200)
        pix, depth = cam.project(pts)
        assert np.all(depth > cam.near_plane)
        assert np.all((pix[:, 0] >= 0) & (pix[:, 0] < 320) & (pix[:, 1] >= 0) & (pix[:, 1] < 200))
        span = np.ptp(pix, axis=0) / [320, 200]
        assert span.max() > 0.5
        assert cam.eye[1] > cam.target[1]  # looks down: ground visible


# ---------------------------------------------------------------------------------------------
# Video
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("ext", [".mp4", ".gif"])
def test_render_video_of_falling_sphere(tmp_path, ext):
    """render_video writes one readable frame per state; the sphere moves down and stays in frame."""
    x, faces = _sphere_drop(8)
    out = render_video(x, tmp_path / f"drop{ext}", faces=faces, fps=10, width=160, height=120, progress=False)
    frames = _read_mp4(out, 120, 160) if ext == ".mp4" else iio.imread(out, index=None)[..., :3]
    assert frames.shape == (8, 120, 160, 3)
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 1.0
    obj = _saturated(frames)
    rows = []
    for k in range(8):
        assert obj[k].sum() > 100
        border = np.concatenate([obj[k, 0], obj[k, -1], obj[k, :, 0], obj[k, :, -1]])
        assert not border.any()
        rows.append(np.nonzero(obj[k])[0].mean())
    assert rows[-1] > rows[0] + 10  # falls down the image


def test_write_video_pads_odd_sizes_and_accepts_floats(tmp_path):
    """write_video accepts float frames of odd size; the MP4 has even dimensions and all frames."""
    frames = [np.full((31, 45, 3), k / 5.0) for k in range(6)]
    out = write_video(frames, tmp_path / "odd.mp4", fps=12)
    back = _read_mp4(out, 32, 46)
    assert back.shape == (6, 32, 46, 3)
    assert abs(int(back[5, 10, 10, 0]) - 255) <= 3 and int(back[0, 10, 10, 0]) <= 3


@pytest.mark.parametrize("ext", [".mp4", ".gif"])
def test_video_writer_keeps_frames_written_before_an_exception(tmp_path, ext):
    """An exception inside `with VideoWriter` still leaves a readable file holding every frame written."""
    path = tmp_path / f"partial{ext}"
    with pytest.raises(RuntimeError, match="boom"):
        with VideoWriter(path, fps=10) as vw:
            for k in range(5):
                vw.append_frame(np.full((24, 32, 3), 40 * k, np.uint8))
            raise RuntimeError("boom")
    frames = _read_mp4(path, 24, 32) if ext == ".mp4" else iio.imread(path, index=None)
    assert len(frames) == 5


def test_video_duck_typed_trajectory_plays_in_real_time(tmp_path):
    """video(traj) reads .x/.faces/.t (1 s of 101 states -> 11 frames at 10 fps) and draws .tets' surface."""
    x, faces = _sphere_drop(101)
    traj = SimpleNamespace(x=x, faces=faces, t=np.linspace(0.0, 1.0, 101))
    out = video(traj, tmp_path / "traj.mp4", fps=10, width=96, height=72, progress=False)
    assert len(_read_mp4(out, 72, 96)) == 11
    assert np.array_equal(realtime_indices(traj.t, fps=10), np.arange(0, 101, 10))
    tet = SimpleNamespace(
        x=np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]] * 2, float), tets=[[0, 1, 2, 3]]
    )
    frames = _read_mp4(video(tet, tmp_path / "tet.mp4", width=96, height=72, progress=False), 72, 96)
    tri = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    ref = _read_mp4(
        render_video(tet.x, tmp_path / "ref.mp4", faces=tri, width=96, height=72, progress=False), 72, 96
    )
    assert frames.shape == ref.shape and np.abs(frames.astype(int) - ref).max() <= 2


# ---------------------------------------------------------------------------------------------
# Export
# ---------------------------------------------------------------------------------------------


def test_ply_and_obj_round_trip_with_trimesh(tmp_path):
    """PLY and OBJ files load back in trimesh with the same counts, faces and coordinates (1e-6)."""
    ico = trimesh.creation.icosphere(subdivisions=2, radius=0.7)
    v, f = np.asarray(ico.vertices) + [0.3, 1.1, -0.2], np.asarray(ico.faces)
    for path in (export_ply(tmp_path / "m.ply", v, f), export_obj(tmp_path / "m.obj", v, f)):
        m = trimesh.load(path, process=False)
        assert m.vertices.shape == v.shape and m.faces.shape == f.shape
        np.testing.assert_allclose(m.vertices, v, atol=1e-6)
        np.testing.assert_array_equal(m.faces, f)
    cloud = trimesh.load(export_ply(tmp_path / "p.ply", v), process=False)
    np.testing.assert_allclose(cloud.vertices, v, atol=1e-6)


def test_sequences_round_trip(tmp_path):
    """OBJ/PLY sequences write one numbered file per frame holding that frame's vertices."""
    x, faces = _sphere_drop(3)
    for export, ext in ((export_obj_sequence, ".obj"), (export_ply_sequence, ".ply")):
        paths = export(tmp_path / ext[1:], x, faces)
        assert [p.name for p in paths] == [f"frame_{k:04d}{ext}" for k in range(3)]
        for k, p in enumerate(paths):
            m = trimesh.load(p, process=False)
            np.testing.assert_allclose(m.vertices, x[k], atol=1e-6)
            np.testing.assert_array_equal(m.faces, faces)


def test_export_usd_time_samples(tmp_path):
    """export_usd writes a y-up stage whose Mesh/Points positions at time code k equal frame k."""
    pytest.importorskip("pxr")
    from pxr import Usd, UsdGeom

    x, faces = _sphere_drop(4)
    stage = Usd.Stage.Open(str(export_usd(tmp_path / "m.usda", x, faces, fps=24)))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y and stage.GetTimeCodesPerSecond() == 24
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/pliant/mesh"))
    np.testing.assert_array_equal(np.asarray(mesh.GetFaceVertexIndicesAttr().Get()), faces.ravel())
    for k in range(4):
        np.testing.assert_allclose(np.asarray(mesh.GetPointsAttr().Get(k)), x[k], atol=1e-6)
    stage = Usd.Stage.Open(str(export_usd(tmp_path / "p.usdc", x, None)))
    pts = UsdGeom.Points(stage.GetPrimAtPath("/pliant/points"))
    np.testing.assert_allclose(np.asarray(pts.GetPointsAttr().Get(3)), x[3], atol=1e-6)


def test_export_usd_without_pxr_names_the_extra(tmp_path, monkeypatch):
    """Without usd-core, export_usd raises ImportError telling to pip install "pliant[usd]"."""
    monkeypatch.setitem(sys.modules, "pxr", None)
    with pytest.raises(ImportError, match=r"pip install -e '\.\[usd\]'"):  # in a checkout
        export_usd(tmp_path / "m.usda", np.zeros((2, 3, 3)), np.array([[0, 1, 2]]))


# ---------------------------------------------------------------------------------------------
# Plots
# ---------------------------------------------------------------------------------------------


def test_plots_write_images_without_touching_pyplot(tmp_path):
    """The three plot helpers write non-empty PNGs and leave matplotlib's backend and pyplot untouched."""
    import matplotlib

    backend = matplotlib.get_backend()
    had_pyplot = "matplotlib.pyplot" in sys.modules
    t = np.linspace(0, 2, 50)
    dts = np.array([0.1, 0.05, 0.025, 0.0125])
    outs = [
        plot_series(
            tmp_path / "e.png", t, {"E": 1 + t, "drift": np.exp(t)}, "energy [J]", "energy", logy=True
        ),
        plot_phase_portrait(
            tmp_path / "p.png", {"rk4": (np.cos(t), -np.sin(t))}, exact=(np.cos(t), -np.sin(t))
        ),
        plot_error_vs_dt(tmp_path / "c.png", dts, {"rk2": 3 * dts**2}, orders={"rk2": 2}),
    ]
    for p in outs:
        img = iio.imread(p)
        assert img.ndim == 3 and img.shape[0] > 100 and img.std() > 5
    assert matplotlib.get_backend() == backend
    assert ("matplotlib.pyplot" in sys.modules) == had_pyplot


def test_fit_order_recovers_slope():
    """fit_order returns the exponent of a power law to 1e-9 and ignores non-positive errors."""
    dts = np.array([0.1, 0.05, 0.025, 0.0125])
    assert abs(fit_order(dts, 7 * dts**4) - 4.0) < 1e-9
    assert abs(fit_order(dts, np.where(dts < 0.02, 0.0, dts**2)) - 2.0) < 1e-9
