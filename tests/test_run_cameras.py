"""``pliant run --cameras`` (``pl.run_scene(..., cameras=)``, issue 37 item 5): the splats of a run rendered
from a camera file's cameras, scored by PSNR and mask IoU against the file's images. The camera files are
made by rendering the run itself, so the scores have closed forms: identical float frames give PSNR = inf
and IoU = 1; 8-bit frames differ by their rounding only, at most 0.5/255 a pixel, so PSNR ≥ 20·log10(510)
≈ 54.2 dB."""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl
from pliant.cli import main
from pliant.scene import build_scene, load_scene

FRAMES = 3
W, H = 64, 48


def _cfg(frames: int = FRAMES):
    """splat_cloth, short and without its correction twin (the cameras are the subject here)."""
    cfg = load_scene("splat_cloth", [f"scene.frames={frames}"])
    cfg.gaussians.correction = None
    return cfg


def _cameras() -> list[pl.gaussians.Camera]:
    eyes = [(1.4, 1.0, 1.8), (-1.2, 1.2, 1.5)]
    return [pl.gaussians.Camera.look_at(e, (0.0, 0.2, 0.0), fov_y=50.0, width=W, height=H) for e in eyes]


@pytest.fixture(scope="module")
def truth(tmp_path_factory):
    """The run's positions and, per camera, the rendered RGB [T, H, W, 3] and alpha [T, H, W]."""
    report = pl.run_scene(_cfg(), tmp_path_factory.mktemp("truth"), device="cpu", video=False)
    assert report.ok and report.frames == FRAMES, report
    cfg = _cfg()
    session = pl.gaussians.SplatSession(cfg, build_scene(cfg, device="cpu"))
    x = report.trajectory.x
    rgb, alpha = [], []
    for cam in _cameras():
        outs = [session.render(xf, cam) for xf in x]
        rgb.append(np.stack([o.colour.numpy() for o in outs]))
        alpha.append(np.stack([o.alpha.numpy() for o in outs]))
    return {"x": x, "t": report.trajectory.t, "rgb": np.stack(rgb), "alpha": np.stack(alpha)}


def _file(path, cams, **arrays):
    np.savez(
        path,
        K=np.stack([c.K for c in cams]),
        world_to_camera=np.stack([c.world_to_camera for c in cams]),
        **arrays,
    )
    return path


def test_identical_images_score_inf_and_iou_one(truth, tmp_path):
    f = _file(
        tmp_path / "cams.npz", _cameras(), images=truth["rgb"], masks=truth["alpha"] > 0.5, t=truth["t"]
    )
    report = pl.run_scene(_cfg(), tmp_path / "out", device="cpu", video=False, cameras=f)
    assert report.ok and report.warnings == []
    assert [s.camera for s in report.cameras] == [0, 1]
    for s in report.cameras:
        assert s.frames == FRAMES + 1 and s.psnr == float("inf") and s.iou == 1.0
        assert s.video == tmp_path / "out" / f"camera_{s.camera}.mp4" and s.video in report.written
        import imageio.v3 as iio

        assert iio.imread(s.video, index=None).shape == (FRAMES + 1, H, W, 3)
        assert "PSNR inf dB, mask IoU 1.000 over 4 frames" in s.summary()


def test_8bit_images_score_the_rounding_and_a_shifted_camera_scores_lower(truth, tmp_path):
    u8 = np.round(truth["rgb"] * 255).astype(np.uint8)
    report = pl.run_scene(
        _cfg(),
        tmp_path / "a",
        device="cpu",
        video=False,
        cameras=_file(tmp_path / "a.npz", _cameras(), images=u8),
    )
    for s in report.cameras:
        # rounding error is uniform in ±0.5/255: MSE ≤ (0.5/255)², so PSNR ≥ 20 log10(510) ≈ 54.2 dB
        assert 54.1 < s.psnr < 90 and s.iou is None, s
    # The file says the images were taken 10 cm to the side of where they were: both scores drop.
    shifted = []
    for c in _cameras():
        T = c.world_to_camera.copy()
        T[0, 3] += 0.1
        shifted.append(pl.gaussians.Camera(c.K, T, W, H))
    f = _file(tmp_path / "b.npz", shifted, images=truth["rgb"], masks=truth["alpha"] > 0.5)
    report = pl.run_scene(_cfg(), tmp_path / "b", device="cpu", video=False, cameras=f)
    for s in report.cameras:
        assert s.psnr < 30 and 0.2 < s.iou < 0.85, s


def test_a_frame_count_mismatch_uses_the_common_prefix_and_says_so(truth, tmp_path):
    f = _file(tmp_path / "c.npz", _cameras(), images=truth["rgb"][:, :2], masks=truth["alpha"][:, :2] > 0.5)
    report = pl.run_scene(_cfg(), tmp_path / "out", device="cpu", video=False, cameras=f)
    assert report.ok and len(report.warnings) == 1 and "compared the first 2" in report.warnings[0]
    assert all(s.frames == 2 and s.psnr == float("inf") for s in report.cameras)


def test_image_size_only_renders_videos_without_scores(tmp_path):
    f = _file(tmp_path / "s.npz", _cameras()[:1], image_size=np.array([W, H]))
    report = pl.run_scene(_cfg(2), tmp_path / "out", device="cpu", video=False, cameras=f)
    (s,) = report.cameras
    assert s.frames == 0 and s.psnr is None and s.iou is None and s.video.exists()


@pytest.mark.parametrize(
    ("arrays", "array", "words"),
    [
        ({"image_size": [W, H], "K": np.eye(3)}, "K", "[C, 3, 3]"),
        ({}, "image_size", "missing"),
        ({"image_size": [W, 0]}, "image_size", "whole numbers"),
        ({"image_size": [W, H], "masks": np.ones((2, 1, H, W), bool)}, "masks", "without images"),
        ({"image_size": [W, H], "colours": np.ones(3)}, "colours", "unknown array"),
        ({"images": np.zeros((2, 1, H, W, 3), np.uint8), "t": [0.0, 1.0]}, "images", "t has 2 times"),
        ({"images": np.zeros((2, 1, H, W, 3), np.float32) + 2}, "images", "[0, 1]"),
        (
            {"images": np.zeros((2, 1, H, W, 3), np.uint8), "masks": np.zeros((2, 1, H, W), bool)},
            "masks",
            "no object pixel",
        ),
    ],
)
def test_bad_camera_files_give_one_line_naming_file_and_array(tmp_path, capsys, arrays, array, words):
    cams = _cameras()
    data = {
        "K": np.stack([c.K for c in cams]),
        "world_to_camera": np.stack([c.world_to_camera for c in cams]),
    }
    data.update(arrays)
    f = tmp_path / "bad.npz"
    np.savez(f, **data)
    with pytest.raises(pl.runner.RunError) as err:
        pl.run_scene(_cfg(1), tmp_path / "out", device="cpu", video=False, cameras=f)
    msg = str(err.value)
    assert f"{f}: {array}: " in msg and words in msg and "\n" not in msg, msg
    assert not (tmp_path / "out").exists()  # nothing written before the check
    code = main(["run", "splat_cloth", "--frames", "1", "--out", str(tmp_path / "o"), "--cameras", str(f)])
    assert code == 1 and capsys.readouterr().err == f"pliant: error: {msg}\n"


def test_a_pose_that_is_not_rigid_is_named(tmp_path):
    cams = _cameras()
    T = np.stack([c.world_to_camera for c in cams])
    T[1, :3, :3] *= 2.0
    f = tmp_path / "scaled.npz"
    np.savez(f, K=np.stack([c.K for c in cams]), world_to_camera=T, image_size=[W, H])
    with pytest.raises(pl.runner.RunError, match=r"world_to_camera: camera 1: not a rigid transform"):
        pl.run_scene(_cfg(1), tmp_path / "out", device="cpu", video=False, cameras=f)


def test_cameras_need_a_gaussians_section(tmp_path):
    f = _file(tmp_path / "s.npz", _cameras(), image_size=np.array([W, H]))
    with pytest.raises(pl.runner.RunError, match=r"has no \[gaussians\] section"):
        pl.run_scene(load_scene("rope", ["scene.frames=1"]), tmp_path / "out", video=False, cameras=f)


def test_cli_prints_psnr_and_iou_per_camera(truth, tmp_path, capsys):
    f = _file(tmp_path / "cams.npz", _cameras(), images=truth["rgb"], masks=truth["alpha"] > 0.5)
    out = tmp_path / "out"
    args = ["run", "splat_cloth", "--frames", str(FRAMES), "--out", str(out), "--cameras", str(f), "-q"]
    # the built-in scene runs its correction twin (2 L-BFGS-B evaluations a frame): the run differs from
    # the uncorrected truth, so the scores are high but finite
    assert main([*args, "--no-video", "--set", "gaussians.correction.iterations=2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    scores = [ln for ln in lines if ln.startswith("camera ")]
    assert len(scores) == 2 and all("dB, mask IoU" in ln and "over 4 frames" in ln for ln in scores), lines
    assert f"wrote {out / 'camera_1.mp4'}" in lines
    for ln in scores:
        psnr = float(ln.split("PSNR ")[1].split(" dB")[0])
        iou = float(ln.split("IoU ")[1].split(" ")[0])
        assert psnr > 30 and iou > 0.9, ln


def test_iou_closed_forms():
    a = np.zeros((4, 4))
    b = np.zeros((4, 4))
    a[:, :2] = 1.0  # left half
    b[:2, :] = 1.0  # top half: they share a quarter, their union is three quarters
    assert pl.gaussians.iou(a, b) == pytest.approx(1.0 / 3.0)
    assert pl.gaussians.iou(a, a > 0.5) == 1.0 and pl.gaussians.iou(a, 1.0 - a) == 0.0
    assert pl.gaussians.iou(np.zeros(3), np.zeros(3)) == 1.0  # two empty silhouettes agree
    with pytest.raises(ValueError, match="same shape"):
        pl.gaussians.iou(a, b[:2])
