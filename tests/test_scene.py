"""Scene files: built-in scenes load, build and run; every object kind builds; errors name file and field."""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl
from pliant.io import SceneError, build_scene, builtin_scenes, load_scene, parse_scene

BUILTINS = ["cloth", "rope", "soft_box", "points"]


def test_builtin_scenes_are_listed():
    """The four documented built-in scenes ship with the package."""
    assert set(BUILTINS) <= set(builtin_scenes())


@pytest.mark.parametrize("name", builtin_scenes())
def test_builtin_scene_loads_builds_and_steps(name):
    """Each built-in scene validates, builds on the CPU and runs two finite frames."""
    cfg = load_scene(name)
    assert cfg.scene.name == name
    scene = build_scene(cfg, device="cpu")
    assert scene.model.particle_count > 0 and scene.frames > 0
    sim = scene.simulator()
    traj = sim.run(2, progress=False)
    assert traj.x.shape == (3, scene.model.particle_count, 3)
    assert np.all(np.isfinite(traj.x))


def _scene(body: str) -> str:
    return '[scene]\nname = "t"\nframes = 2\nsubsteps = 4\n\n' + body


def test_every_object_kind_builds(tmp_path):
    """cloth, rope, soft_box, mesh (OBJ surface filled by TetGen) and points (.npy) build into one model."""
    import trimesh

    trimesh.creation.box(extents=(0.2, 0.2, 0.2)).export(tmp_path / "box.obj")
    pts = np.random.default_rng(0).uniform(-0.1, 0.1, size=(60, 3))
    np.save(tmp_path / "pts.npy", pts)
    text = _scene(
        """
[[objects]]
kind = "cloth"
nx = 4
ny = 3
size = [0.4, 0.3]
pin = "top-corners"
material = { Et = 50.0 }

[[objects]]
kind = "rope"
n_segments = 5
material = { stiffness = 100.0 }

[[objects]]
kind = "soft_box"
cells = 2
material = { stiffness = 100.0 }

[[objects]]
kind = "mesh"
path = "box.obj"
origin = [0.0, 0.5, 0.0]
material = { stiffness = 100.0 }

[[objects]]
kind = "points"
path = "pts.npy"
radius = 0.08
material = { stiffness = 100.0 }

[ground]
height = 0.0
"""
    )
    cfg = parse_scene(text, "kinds.toml", tmp_path)
    scene = build_scene(cfg, device="cpu")
    kinds = [o["kind"] for o in scene.model.objects]
    assert kinds == ["cloth", "rope", "soft_box", "mesh", "points"]
    assert scene.model.particle_count == 20 + 6 + 27 + scene.model.objects[3]["count"] + 60
    assert np.all(np.isfinite(scene.simulator().run(1, progress=False).x))


@pytest.mark.parametrize(
    ("body", "line", "field", "hint"),
    [
        (
            '[[objects]]\nkind = "clth"\n',
            7,
            "objects[0].kind",
            "allowed: cloth, rope, soft_box, mesh, points",
        ),
        ('[[objects]]\nkind = "rope"\nn_segments = "ten"\n', 8, "objects[0].n_segments", "valid integer"),
        ('[[objects]]\nkind = "rope"\n', 6, "objects[0].material.stiffness", "needs stiffness"),
        ('[[objects]]\nkind = "rope"\nlenght = 1.0\n', 8, "objects[0].lenght", "unknown field 'lenght'"),
        (
            '[[objects]]\nkind = "cloth"\npin = "top"\nmaterial = {stiffness = 1.0}\n',
            8,
            "objects[0].pin",
            "allowed: none, top-corners",
        ),
    ],
    ids=["unknown-kind", "bad-type", "missing-field", "unknown-field", "bad-pin"],
)
def test_validation_errors_name_file_line_and_field(body, line, field, hint):
    """Each invalid scene raises SceneError naming the file, the line, the dotted field and the fix."""
    with pytest.raises(SceneError) as info:
        parse_scene(_scene(body), "bad.toml")
    msg = str(info.value)
    assert msg.startswith(f"bad.toml:{line}: {field}: "), msg
    assert hint in msg


def test_toml_syntax_error_names_file_and_line():
    """A TOML syntax error names the file and the line."""
    with pytest.raises(SceneError, match=r"^bad.toml:6: TOML syntax error"):
        parse_scene(_scene('[[objects]\nkind = "rope"\n'), "bad.toml")


def test_unknown_integrator_lists_available():
    """An unknown integrator name is reported with the integrators that exist."""
    cfg = parse_scene(
        _scene('[[objects]]\nkind = "rope"\nmaterial = {stiffness = 1.0}\n[solver]\nintegrator = "RK5"\n'),
        "s.toml",
    )
    with pytest.raises(SceneError, match=r"s.toml:10: solver.integrator: unknown integrator 'RK5'.*RK4"):
        build_scene(cfg, device="cpu")


def test_integrator_is_looked_up_by_name():
    """Any integrator of pliant.integrators can be named, case-insensitively (here rk4)."""
    cfg = parse_scene(
        _scene('[[objects]]\nkind = "rope"\nmaterial = {stiffness = 1.0}\n[solver]\nintegrator = "rk4"\n'),
        "s.toml",
    )
    assert isinstance(build_scene(cfg, device="cpu").solver.integrator, pl.integrators.RK4)


def test_fem_and_pbd_build_or_say_what_is_missing():
    """model = "fem" / "pbd" build when their pieces exist, else NotImplementedError names the class."""
    for body, needs in [
        ('[[objects]]\nkind = "soft_box"\ncells = 2\nmodel = "fem"\nmaterial = {E = 1e4}\n', "NeoHookean"),
        ('[[objects]]\nkind = "rope"\nmodel = "pbd"\n', "XPBD"),
    ]:
        cfg = parse_scene(_scene(body), "s.toml")
        try:
            scene = build_scene(cfg, device="cpu")
        except NotImplementedError as exc:
            assert needs in str(exc) and "not available in this version" in str(exc)
        else:
            assert np.all(np.isfinite(scene.simulator().run(1, progress=False).x))


@pytest.mark.slow
@pytest.mark.parametrize("name", builtin_scenes())
def test_builtin_scene_runs_to_the_end(name):
    """Each built-in scene runs all its frames without diverging and stays above the ground (slow)."""
    scene = build_scene(load_scene(name), device="cpu")
    traj = scene.simulator().run(scene.frames, progress=False)
    assert traj.frame_count == scene.frames + 1
    assert np.all(np.isfinite(traj.x))
    ground = scene.model.ground
    if ground is not None:
        lowest = float(traj.x[:, :, 1].min())
        assert lowest > ground.height - 1e-3, f"{name}: a particle went {lowest:.4f} m below the ground"
