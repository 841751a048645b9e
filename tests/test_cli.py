"""The ``pliant`` command: run, demo, Ctrl-C and divergence handling, scene errors, info, export, bench."""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl
from pliant.cli import main
from pliant.io import load_checkpoint


def _object_mask(frame: np.ndarray) -> np.ndarray:
    """Pixels of the (orange) object: saturated colour, unlike the grey ground and pale sky."""
    f = frame.astype(np.int16)
    return (f.max(axis=2) - f.min(axis=2)) > 60


def test_run_rope_writes_a_moving_video(tmp_path):
    """`pliant run rope --frames 30` writes an NPZ and an MP4 whose object is in view and moves."""
    import imageio.v3 as iio

    assert main(["run", "rope", "--frames", "30", "--out", str(tmp_path), "--quiet", "--device", "cpu"]) == 0
    traj = pl.Trajectory.load(tmp_path / "rope.npz")
    assert traj.x.shape == (31, 31, 3)
    frames = iio.imread(tmp_path / "rope.mp4", index=None)
    assert frames.shape[0] == 31 and frames.shape[1:] == (480, 640, 3)
    first, mid, last = (_object_mask(frames[k]) for k in (0, 12, -1))
    assert min(first.sum(), mid.sum(), last.sum()) > 200, "the rope is not visible"
    # The rope swings down (0.4 s in, it hangs below the pin) and on: the object's pixels change.
    rows = np.nonzero(first)[0].mean(), np.nonzero(mid)[0].mean()
    assert rows[1] - rows[0] > 20, f"rope pixels did not move down (mean rows {rows})"
    iou = (first & last).sum() / (first | last).sum()
    assert iou < 0.5, f"first and last frames show the rope in the same place (IoU {iou:.2f})"
    # And it is inside the picture, not squeezed against the border.
    h, w = first.shape
    inner = np.zeros_like(first)
    inner[h // 20 : -h // 20, w // 20 : -w // 20] = True
    for mask in (first, mid, last):
        assert (mask & inner).sum() > 0.9 * mask.sum(), "object pixels lie mostly on the image border"


def test_demo_quick(tmp_path, capsys):
    """`pliant demo --frames 3` writes demo.npz and demo.mp4 and says where the video is."""
    assert main(["demo", "--out", str(tmp_path), "--frames", "3", "--quiet", "--device", "cpu"]) == 0
    out = capsys.readouterr().out
    assert (tmp_path / "demo.npz").exists() and (tmp_path / "demo.mp4").exists()
    assert "625 particles" in out and f"video: {(tmp_path / 'demo.mp4').resolve()}" in out
    assert pl.Trajectory.load(tmp_path / "demo.npz").frame_count == 4


def test_ctrl_c_keeps_outputs_and_resume_finishes(tmp_path, capsys, monkeypatch):
    """Ctrl-C at frame 5 exits 130 keeping NPZ, video and checkpoint; --resume completes the run."""
    real_step = pl.Simulator.step_frame

    def step(self):
        if self.frame == 5:
            raise KeyboardInterrupt
        real_step(self)

    monkeypatch.setattr(pl.Simulator, "step_frame", step)
    args = ["run", "rope", "--frames", "12", "--out", str(tmp_path), "--quiet", "--device", "cpu"]
    assert main(args) == 130
    err = capsys.readouterr().err
    assert "interrupted at frame 5" in err and "--resume" in err
    assert pl.Trajectory.load(tmp_path / "rope.npz").frame_count == 6
    assert (tmp_path / "rope.mp4").exists()
    assert load_checkpoint(tmp_path / "rope.ckpt.npz")["frame"] == 5
    monkeypatch.setattr(pl.Simulator, "step_frame", real_step)
    assert main([*args, "--resume", "--no-video"]) == 0
    assert pl.Trajectory.load(tmp_path / "rope.npz").frame_count == 13


def test_divergence_exits_2_with_one_line(tmp_path, capsys):
    """A diverging scene prints one error line naming the frame, exits 2 and keeps partial outputs."""
    scene = tmp_path / "stiff.toml"
    scene.write_text(
        '[scene]\nname = "stiff"\nframes = 20\nsubsteps = 1\n'
        '[[objects]]\nkind = "rope"\nn_segments = 10\nmaterial = { stiffness = 1e7 }\n'
    )
    assert main(["run", str(scene), "--out", str(tmp_path), "--quiet", "--no-video", "--device", "cpu"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("pliant: error: diverged at frame"), err
    assert "Traceback" not in "".join(err)
    assert (tmp_path / "stiff.npz").exists()


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        (
            '[[objects]]\nkind = "clth"\n',
            "bad.toml:2: objects[0].kind: unknown kind 'clth'; allowed: cloth, rope",
        ),
        (
            '[scene]\nframes = "ten"\n[[objects]]\nkind = "rope"\n',
            "bad.toml:2: scene.frames: input should be",
        ),
        ("[scene]\nframes = 3\n", "bad.toml: objects: missing required field"),
        ('[[objects]\nkind = "rope"\n', "bad.toml:1: TOML syntax error"),
        (
            '[[objects]]\nkind = "soft_box"\n[objects.material]\nstiffness = -1.0\n',
            "bad.toml:4: objects[0].material.stiffness: input should be greater than or equal to 0",
        ),
    ],
    ids=["unknown-kind", "bad-type", "missing-field", "toml-syntax", "out-of-range"],
)
def test_scene_errors_name_file_and_field(tmp_path, capsys, monkeypatch, body, expected):
    """Scene mistakes exit 1 with one stderr line: file, line, dotted field and the fix; no traceback."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "bad.toml").write_text(body)
    assert main(["run", "bad.toml", "--out", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"pliant: error: {expected}"), err
    assert "Traceback" not in err


def test_unknown_scene_lists_builtins(capsys):
    """An unknown scene name lists the built-in scenes."""
    assert main(["run", "no_such_scene"]) == 1
    err = capsys.readouterr().err
    assert "built-in scenes: " in err and "cloth, " in err and "rope" in err and "soft_box" in err


def test_info_exits_0(capsys):
    """`pliant info` prints versions, devices and the kernel cache and exits 0."""
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    for key in ("pliant", "warp", "numpy", "python", "devices", "kernel cache"):
        assert key in out


def test_export_obj_sequence_and_single_ply(tmp_path):
    """`pliant export` writes an OBJ per frame, or one PLY frame with --frame."""
    x = np.random.default_rng(0).normal(size=(3, 4, 3))
    pl.Trajectory(x=x, t=np.arange(3.0), faces=np.array([[0, 1, 2], [1, 2, 3]])).save(tmp_path / "t.npz")
    assert main(["export", str(tmp_path / "t.npz"), "--format", "obj", "--out", str(tmp_path / "objs")]) == 0
    assert len(list((tmp_path / "objs").glob("*.obj"))) == 3
    assert (
        main(["export", str(tmp_path / "t.npz"), "--out", str(tmp_path / "last.ply"), "--frame", "-1"]) == 0
    )
    assert (tmp_path / "last.ply").read_bytes().startswith(b"ply")


def test_bench_list_and_unknown(capsys):
    """`pliant bench --list` names the discovered benchmarks; an unknown name is a one-line error."""
    assert main(["bench", "--list"]) == 0
    assert "render_cloth" in capsys.readouterr().out
    assert main(["bench", "nope"]) == 1
    assert "unknown benchmark(s) nope" in capsys.readouterr().err
