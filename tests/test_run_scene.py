"""``pl.run_scene``, the library function behind ``pliant run`` (issue 40 item 4): it returns a report, prints
nothing unless asked, and writes what ``pliant run`` writes; ``pl.scene.from_mesh`` gives the scene that
``pliant run mesh.obj`` suggests."""

from __future__ import annotations

import pytest

import pliant as pl
from pliant.scene import load_scene


def test_run_scene_returns_a_report_and_prints_nothing(tmp_path, capsys):
    report = pl.run_scene(load_scene("rope", ["scene.frames=2"]), tmp_path, device="cpu", video=False)
    assert capsys.readouterr() == ("", "")
    assert report.status == "ok" and report.frames == report.frames_requested == 2
    assert report.written == [tmp_path / "rope.npz"] and report.checkpoint == tmp_path / "rope.ckpt.npz"
    assert report.trajectory.x.shape[0] == 3 and report.wall_simulate > 0
    assert report.metrics["particle_substeps_per_s"] > 0 and report.cameras == []


def test_from_mesh_gives_a_scene_that_loads(tmp_path):
    import trimesh

    trimesh.creation.box(extents=(0.2, 0.2, 0.2)).export(tmp_path / "box.obj")
    ms = pl.scene.from_mesh(tmp_path / "box.obj")
    (tmp_path / "box.toml").write_text(ms.toml)
    cfg = load_scene(tmp_path / "box.toml")
    assert cfg.scene.substeps == ms.values["substeps"]
    assert cfg.objects[0].material.stiffness == ms.values["stiffness"]
    # the lumped tet masses add up to ρ·V of the 0.2 m box (TetGen fills it exactly), its extent is 0.2 m
    assert ms.values["mass"] == pytest.approx(1000 * 0.2**3, rel=1e-6)
    assert ms.values["height"] == pytest.approx(0.2) and ms.values["lift"] == pytest.approx(0.02 + 0.1)


def test_the_cli_prints_what_the_report_holds(tmp_path, capsys):
    """``pliant run`` prints run_scene's lines as the run goes, then each written file (same bytes as the
    library's run: the CLI only parses and prints)."""
    from pliant.cli import main

    assert main(["run", "rope", "--frames", "2", "--out", str(tmp_path / "cli"), "--no-video", "-q"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("rope: ") and out[1].startswith("simulated 2 frames in ")
    assert out[2:] == [f"wrote {tmp_path / 'cli' / 'rope.npz'}"]
    lib = pl.run_scene(load_scene("rope", ["scene.frames=2"]), tmp_path / "lib", video=False)
    assert (tmp_path / "cli" / "rope.npz").read_bytes() == lib.written[0].read_bytes()


def test_a_run_that_cannot_start_raises_before_writing(tmp_path):
    (tmp_path / "f").write_text("a file where the output folder should be")
    with pytest.raises(pl.runner.RunError):
        pl.run_scene(load_scene("rope", ["scene.frames=1"]), tmp_path / "f", video=False)
    with pytest.raises(pl.runner.RunError, match="--resume: no checkpoint"):
        pl.run_scene(load_scene("rope", ["scene.frames=1"]), tmp_path / "o", video=False, resume=True)
    assert not list((tmp_path / "o").glob("*.npz"))
