"""Scenes with a [gaussians] section: validation (file:line: field), splats generated from the surface or read
from a PLY, `pliant run` drawing them, and visual correction toward a "real" twin."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl
from pliant.cli import main
from pliant.scene import SceneError, build_scene, load_scene, parse_scene

HEAD = '[scene]\nname = "t"\nframes = 3\nsubsteps = 8\n'
CLOTH = (
    '[[objects]]\nkind = "cloth"\nname = "sheet"\nnx = 4\nny = 4\nsize = 0.5\nplane = "xz"\n'
    "origin = [-0.25, 0.5, -0.25]\npin = [0, 4]\nmaterial = {stiffness = 100.0}\n"
)
CAMERA = "[camera]\neye = [1.0, 1.0, 1.2]\ntarget = [0.0, 0.3, 0.0]\nwidth = 64\nheight = 48\n"


def _error(text: str, base=".") -> str:
    with pytest.raises(SceneError) as info:
        parse_scene(text, "s.toml", base)
    return str(info.value)


def test_bad_gaussians_sections_name_file_line_and_field(tmp_path):
    msg = _error(HEAD + CLOTH + '[gaussians]\nobject = "cape"\n')
    assert "s.toml:16: gaussians.object: no object named 'cape'; objects: sheet" in msg
    msg = _error(HEAD + CLOTH + "[gaussians]\nobject = 3\n")
    assert "gaussians.object: index 3 out of range" in msg
    msg = _error(HEAD + CLOTH + '[gaussians]\nply = "missing.ply"\n', tmp_path)
    assert "gaussians.ply: no such file" in msg and "missing.ply" in msg
    (tmp_path / "a.ply").write_text("ply\n")
    msg = _error(HEAD + CLOTH + '[gaussians]\nply = "a.ply"\ngenerate = "mesh"\n', tmp_path)
    assert "gaussians.generate: give ply (splats from a file) or generate, not both" in msg
    msg = _error(HEAD + CLOTH + '[gaussians]\nbind = "barycentric"\n')
    assert "gaussians.bind: 'barycentric' embeds splats in tets, but objects[0] (cloth) has none" in msg
    msg = _error(HEAD + CLOTH + '[gaussians]\nbind = "skin"\n')
    assert "gaussians.bind" in msg and "lbs" in msg
    msg = _error(HEAD + CLOTH + "[gaussians]\nsparkle = 1\n")
    assert "gaussians.sparkle" in msg
    msg = _error(HEAD + CLOTH + '[gaussians.correction]\nset = ["stiffness"]\n')
    assert "gaussians.correction.set[0]: expected PATH=VALUE, got 'stiffness'" in msg
    two = CLOTH + CLOTH.replace('"sheet"', '"other"')
    msg = _error(HEAD + two + '[gaussians.correction]\nset = ["scene.frames=3"]\n')
    assert "gaussians.correction: visual correction needs a scene with exactly one object" in msg


def test_register_section_refuses_builtin_names():
    with pytest.raises(ValueError, match=r"\[camera\] is a built-in scene section"):
        pl.scene.register_section("camera", pl.scene.SceneConfig)


def test_generated_splats_follow_the_cloth():
    from pliant.gaussians._scene import scene_splats

    cfg = parse_scene(HEAD + CLOTH + '[gaussians]\ngenerate = "mesh"\nchecker = 0.1\n')
    scene = build_scene(cfg, device="cpu")
    s = scene_splats(cfg, scene)
    m = scene.model
    assert s.binding.method == "triangles" and s.binding.gaussians.count == m.tri_count == 32
    # at rest each splat sits at its triangle's centroid; checker colours use both colours
    tris = m.tri_indices.numpy()
    np.testing.assert_allclose(
        s.place(m.particle_q_np).means.numpy(), m.particle_q_np[tris].mean(1), atol=1e-6
    )
    cols = s.binding.gaussians.numpy()["sh"][:, 0] * pl.gaussians.SH_C0 + 0.5
    assert len(np.unique(cols.round(3), axis=0)) == 2
    # a rigid translation of the cloth moves every splat with it (rendering reads these means)
    shifted = m.particle_q_np + np.array([0.1, -0.2, 0.05])
    np.testing.assert_allclose(
        s.place(wp.array(shifted, dtype=wp.vec3)).means.numpy(),
        m.particle_q_np[tris].mean(1) + np.array([0.1, -0.2, 0.05]),
        atol=1e-5,
    )


def test_ply_splats_bind_to_the_object_and_bad_ply_is_named(tmp_path, capsys):
    g = pl.gaussians.Gaussians.from_values(
        np.random.default_rng(0).uniform(-0.25, 0.25, (20, 3)) + [0.0, 0.5, 0.0], scales=0.03, device="cpu"
    )
    pl.gaussians.save_ply(g, tmp_path / "splats.ply")
    scene_file = tmp_path / "s.toml"
    scene_file.write_text(HEAD + CLOTH + CAMERA + '[gaussians]\nply = "splats.ply"\n')
    from pliant.gaussians._scene import scene_splats

    cfg = load_scene(scene_file)
    s = scene_splats(cfg, build_scene(cfg, device="cpu"))
    assert s.binding.method == "lbs" and s.binding.gaussians.count == 20
    # `pliant fit` writes fitted.toml into another folder: the PLY path becomes absolute and still loads
    from pliant.fit._toml import scene_toml

    (tmp_path / "fit").mkdir()
    moved = load_scene(scene_toml(cfg, tmp_path / "fit" / "fitted.toml"))
    assert moved.gaussians.ply == str(tmp_path.resolve() / "splats.ply")
    assert scene_splats(moved, build_scene(moved, device="cpu")).binding.gaussians.count == 20
    # a PLY without the Gaussian properties: the CLI names the scene file, the field and what is missing,
    # and writes nothing
    (tmp_path / "splats.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
        "end_header\n0 0 0\n"
    )
    out = tmp_path / "out"
    assert main(["run", str(scene_file), "--out", str(out), "-q"]) != 0
    err = capsys.readouterr().err
    assert "s.toml: gaussians.ply:" in err and "missing required Gaussian properties" in err
    assert not out.exists() or not any(out.iterdir())


def test_run_draws_splats_and_refuses_splats_without_section(tmp_path, capsys):
    scene_file = tmp_path / "s.toml"
    scene_file.write_text(HEAD + CLOTH + CAMERA + '[gaussians]\ngenerate = "mesh"\n')
    out = tmp_path / "out"
    assert main(["run", str(scene_file), "--out", str(out), "-q"]) == 0
    import imageio.v3 as iio

    frames = iio.imread(out / "t.mp4", index=None)
    assert frames.shape == (4, 48, 64, 3)
    # the splats are drawn: orange-ish cloth pixels on the white background
    assert (np.abs(frames[0].astype(int) - 255).sum(axis=2) > 100).sum() > 20
    plain = tmp_path / "p.toml"
    plain.write_text(HEAD + CLOTH)
    assert main(["run", str(plain), "--out", str(out), "-q", "--renderer", "splats"]) != 0
    assert "--renderer splats: " in capsys.readouterr().err


def test_demo_scene_corrects_toward_its_twin():
    from pliant.gaussians import SplatSession

    cfg = load_scene("splat_cloth", ["scene.frames=12", "gaussians.correction.iterations=4"])
    scene = build_scene(cfg, device="cpu")
    run = SplatSession(cfg, scene)
    traj = scene.simulator().run(12, progress=False, on_frame=run.on_frame)
    plain = scene.simulator().run(12, progress=False)
    corrected = np.linalg.norm(traj.x - run.twin_x, axis=2).mean()
    uncorrected = np.linalg.norm(plain.x - run.twin_x, axis=2).mean()
    assert corrected < 0.6 * uncorrected, (corrected, uncorrected)
    line = run.drift_summary(traj.x)
    assert "visual correction: mean drift from the real twin" in line and "% less" in line
