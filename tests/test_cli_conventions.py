"""CLI conventions (issue 17): exit codes, --version, lazy imports, examples in help, `pliant scenes`,
`--set`, the mesh-instead-of-scene message, and `rotation` / `up` on mesh and points objects."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import pliant as pl
from pliant.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]


def test_usage_mistakes_exit_1_and_version(capsys):
    """argparse mistakes exit 1 (2 is "diverged"); --version prints pliant's version and exits 0."""
    import pliant

    for argv in (["run"], ["nope"], ["run", "rope", "--frames", "x"], ["export", "a.npz"]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 1, argv
        assert "pliant: error:" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.strip() == f"pliant {pliant.__version__}"


def test_help_imports_no_warp_and_every_command_has_examples():
    """`import pliant.cli` and every --help run without loading Warp (so no CUDA warning either), and each
    sub-command's help (all of them, found in the parser) ends with usage examples."""
    code = (
        "import sys, contextlib, io\n"
        "import pliant.cli\n"
        "assert 'warp' not in sys.modules, 'import pliant.cli loaded warp'\n"
        "import argparse\n"
        "actions = pliant.cli.build_parser()._actions\n"
        "sub = next(a for a in actions if isinstance(a, argparse._SubParsersAction))\n"
        "cmds = sorted(sub.choices)\n"
        "assert {'demo', 'run', 'scenes', 'info', 'bench', 'study', 'export'} <= set(cmds), cmds\n"
        "for argv in [['--help']] + [[c, '--help'] for c in cmds]:\n"
        "    buf = io.StringIO()\n"
        "    with contextlib.redirect_stdout(buf):\n"
        "        try:\n"
        "            pliant.cli.main(argv)\n"
        "        except SystemExit as e:\n"
        "            assert e.code == 0, (argv, e.code)\n"
        "    text = buf.getvalue()\n"
        "    assert 'examples:' in text and 'pliant ' in text.split('examples:')[1], argv\n"
        "assert 'warp' not in sys.modules, 'a --help loaded warp'\n"
        "print('OK')\n"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "OK" and "warning" not in r.stderr.lower(), r.stderr


def test_scenes_list_and_show(capsys):
    """`pliant scenes` lists every built-in scene with a description; `show` prints the file verbatim."""
    from pliant.scene import builtin_scenes, parse_scene

    assert main(["scenes"]) == 0
    lines = capsys.readouterr().out.splitlines()
    names = builtin_scenes()
    assert [ln.split()[0] for ln in lines] == names
    assert all(len(ln.split(None, 1)[1]) > 10 for ln in lines)
    assert main(["scenes", "show", "rope"]) == 0
    text = capsys.readouterr().out
    assert parse_scene(text).scene.name == "rope"
    assert main(["scenes", "show", "nope"]) == 1
    assert "built-in scenes: " in capsys.readouterr().err


def test_set_overrides_scene_fields(tmp_path, capsys):
    """--set changes any field (checked like the file's own values); bad paths and values name the path."""
    from pliant.scene import load_scene

    cfg = load_scene(
        "rope",
        ["objects[0].material.stiffness=200", "scene.frames=7", "solver.integrator=RK4", "scene.name=r2"],
    )
    assert cfg.objects[0].material.stiffness == 200.0 and cfg.scene.frames == 7
    assert cfg.solver.integrator == "RK4" and cfg.scene.name == "r2"
    args = ["run", "rope", "--out", str(tmp_path), "-q", "--no-video", "--device", "cpu"]
    assert main([*args, "--set", "scene.frames=2", "--set", "objects[0].n_segments=5"]) == 0
    import pliant as pl

    assert pl.Trajectory.load(tmp_path / "rope.npz").x.shape == (3, 6, 3)
    capsys.readouterr()
    for item, expected in (
        ("objects[3].mass=1", "objects: (--set) index 3 out of range"),
        ("objects[0].material.stiffness=-5", "objects[0].material.stiffness:"),
        ("objects[0].colour=1", "objects[0].colour: unknown field"),
        ("scene.frames", "--set: (--set) expected PATH=VALUE"),
    ):
        assert main([*args, "--set", item]) == 1, item
        assert expected in capsys.readouterr().err, item


def test_mesh_instead_of_scene_prints_a_scene_that_runs(tmp_path, capsys):
    """`pliant run box.obj` exits 1 with one error line on stderr and, on stdout, plain scene lines (no
    prefix) that load and build."""
    import trimesh

    from pliant.scene import build_scene, load_scene

    trimesh.creation.box(extents=(0.2, 0.2, 0.2)).export(tmp_path / "box.obj")
    assert main(["run", str(tmp_path / "box.obj"), "--out", str(tmp_path)]) == 1
    out, err = capsys.readouterr()
    assert "is a mesh, not a scene file" in err and len(err.strip().splitlines()) == 1
    assert "pliant" not in out.split("[scene]")[1] and 'path = "box.obj"' in out
    (tmp_path / "box.toml").write_text(out)
    scene = build_scene(load_scene(tmp_path / "box.toml"), device="cpu")
    assert scene.model.particle_count >= 8


def test_mesh_scene_suggestion_is_stable_on_a_small_torus(tmp_path, capsys):
    """The suggested scene for a 0.2 m torus (the issue's case diverged at frame 1 with k = 500 and the
    default 16 substeps) runs without diverging: its substeps put the Gershgorin bound of the stiffest
    particle's ω at ω·Δt = 1 < 2 (symplectic Euler's limit)."""
    import trimesh

    from pliant.scene import build_scene, load_scene, mesh_scene_values

    trimesh.creation.torus(major_radius=0.07, minor_radius=0.03, major_sections=24, minor_sections=12).export(
        tmp_path / "torus.obj"
    )
    assert main(["run", str(tmp_path / "torus.obj")]) == 1
    out = capsys.readouterr().out
    (tmp_path / "torus.toml").write_text(out)
    cfg = load_scene(tmp_path / "torus.toml")
    v = mesh_scene_values(tmp_path / "torus.obj")
    assert cfg.scene.substeps == v["substeps"] > 16 and cfg.objects[0].material.stiffness == v["stiffness"]
    # The bound from the built model itself: ω² ≤ max_i 2 k n_i / m_i.
    scene = build_scene(cfg, device="cpu")
    m = scene.model.particle_mass.numpy()
    n = np.bincount(scene.model.spring_indices.numpy().ravel(), minlength=len(m))
    omega = np.sqrt(np.max(2 * v["stiffness"] * n / m))
    assert omega * scene.frame_dt / scene.substeps <= 1.0 + 1e-9
    cfg.scene.frames = 5
    traj = scene.simulator().run(5, progress=False)  # DivergenceError if unstable
    # (The mesh is centred at y = 0: the ground lifts it in frame 1; after that it moves at a few cm/frame.)
    assert np.all(np.isfinite(traj.x)) and np.abs(traj.x[-1] - traj.x[-2]).max() < 0.05
    # At a quarter of the substeps (ω·Δt ≈ 4 > 2), the same scene does diverge: the count matters.
    cfg.scene.substeps = max(1, v["substeps"] // 4)
    with pytest.raises(pl.DivergenceError):
        build_scene(cfg, device="cpu").simulator().run(5, progress=False)


@pytest.mark.parametrize("kind", ["mesh", "points"])
def test_rotation_and_up_turn_the_file_points(tmp_path, kind):
    """Positions equal the file's points rotated (Euler degrees about fixed x, y, z) then moved by origin;
    up = "z" maps the file's +z to +y."""
    import trimesh

    from pliant.scene import build_scene, parse_scene

    box = trimesh.creation.box(extents=(0.2, 0.4, 1.0))
    tm = trimesh.Trimesh(box.vertices, box.faces)
    tm.export(tmp_path / "b.obj")
    pts = np.asarray(tm.vertices, np.float64)
    if kind == "points":
        pts = pts - pts.mean(axis=0)
    head = f'[[objects]]\nkind = "{kind}"\npath = "b.obj"\nmaterial = {{ stiffness = 500 }}\n'
    if kind == "points":
        head += "radius = 1.5\n"

    def positions(extra: str) -> np.ndarray:
        cfg = parse_scene(head + "origin = [1, 2, 3]\n" + extra, "t.toml", tmp_path)
        return build_scene(cfg, device="cpu", dtype="float64").model.particle_q.numpy()[: len(pts)]

    a = np.radians([30.0, 45.0, 60.0])
    rx = np.array([[1, 0, 0], [0, np.cos(a[0]), -np.sin(a[0])], [0, np.sin(a[0]), np.cos(a[0])]])
    ry = np.array([[np.cos(a[1]), 0, np.sin(a[1])], [0, 1, 0], [-np.sin(a[1]), 0, np.cos(a[1])]])
    rz = np.array([[np.cos(a[2]), -np.sin(a[2]), 0], [np.sin(a[2]), np.cos(a[2]), 0], [0, 0, 1]])
    np.testing.assert_allclose(
        positions("rotation = [30, 45, 60]\n"), pts @ (rz @ ry @ rx).T + [1, 2, 3], atol=1e-9
    )
    upright = positions('up = "z"\n') - [1, 2, 3]
    np.testing.assert_allclose(upright, np.stack([pts[:, 0], pts[:, 2], -pts[:, 1]], axis=1), atol=1e-9)
    assert np.ptp(upright[:, 1]) == pytest.approx(1.0)  # the file's 1 m along z now stands along y
    np.testing.assert_allclose(positions(""), pts + [1, 2, 3], atol=1e-12)


def test_build_parser_has_no_warp_dependency():
    """The parser is usable as a library call (for completion, docs)."""
    p = build_parser()
    assert p.parse_args(["run", "rope", "--set", "a=1", "--set", "b=2"]).overrides == ["a=1", "b=2"]
