"""Scene files: built-in scenes load, build and run; every object kind builds; errors name file and field."""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl
from pliant.scene import SceneError, build_scene, builtin_scenes, load_scene, parse_scene

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


# ---------------------------------------------------------------------------------------------- new scenes
NEW_SCENES = [
    "rope_swing",
    "cloth_sphere",
    "cloth_pinned",
    "points_push",
    "xpbd_cloth_sphere",
    "xpbd_pile",
    "pendulum_chain",
    "xpbd_soft_body",
    "fem_drop",
    "cantilever",
    "fem_squeeze",
    "fem_embedded",
]


def _run(name: str, frames: int):
    scene = build_scene(load_scene(name), device="cpu")
    traj = scene.simulator().run(frames, progress=False)
    assert np.all(np.isfinite(traj.x)), f"{name}: non-finite positions"
    return scene, traj.x


def test_new_builtin_scenes_are_listed():
    """All 12 scenes of issues 4, 5 and 6 ship with the package."""
    assert set(NEW_SCENES) <= set(builtin_scenes())


def test_rope_swing_keeps_its_pin_and_swings():
    """rope_swing: the pinned end stays within 1e-6 m and the free end moves > 0.2 m in 15 frames."""
    _, x = _run("rope_swing", 15)
    assert np.abs(x[:, 0] - x[0, 0]).max() < 1e-6
    assert np.linalg.norm(x[-1, -1] - x[0, -1]) > 0.2


@pytest.mark.parametrize("name", ["cloth_sphere", "xpbd_cloth_sphere"])
def test_cloth_stays_outside_the_sphere_collider(name):
    """The draped cloth touches the sphere (within 2 cm) but no particle is > 5 mm inside it."""
    scene, x = _run(name, 15)
    c = scene.config.colliders[0]
    d = np.linalg.norm(x - np.asarray(c.center), axis=-1)
    assert d[-1].min() < c.radius + 0.02, "the cloth never reached the sphere"
    assert d.min() > c.radius - 5e-3, f"{name}: a particle went {c.radius - d.min():.4f} m into the sphere"


def test_cloth_pinned_holds_two_opposite_corners():
    """cloth_pinned: corners 0 and 624 stay within 1e-6 m while the free corners drop > 0.1 m."""
    _, x = _run("cloth_pinned", 10)
    assert np.abs(x[:, [0, 624]] - x[0, [0, 624]]).max() < 1e-6
    assert x[0, [24, 600], 1].min() - x[-1, [24, 600], 1].max() > 0.1


def test_points_push_moves_the_object_with_the_handle():
    """points_push: after 1 s the handle (0.3 m along +x) moved the blob's centroid > 0.15 m in +x, < 0.05 m
    sideways (measured 0.035 m: with static friction holding the blob's bottom, it rolls rather than slides,
    and its jittered points steer it a little)."""
    _, x = _run("points_push", 30)
    d = x[-1].mean(axis=0) - x[0].mean(axis=0)
    assert d[0] > 0.15 and abs(d[2]) < 0.05, d


def test_xpbd_pile_rigid_clusters_keep_their_shape():
    """xpbd_pile: once landed (frame 45) rigid clusters' pair distances match the rest ones to 1e-3 m, and
    every particle is above the ground."""
    scene, x = _run("xpbd_pile", 45)
    rigid = [o for o in scene.model.objects if o["name"].startswith("rigid")]
    assert len(rigid) == 4
    for o in rigid:
        p = x[:, o["start"] : o["start"] + o["count"]]
        d = np.linalg.norm(p[:, :, None] - p[:, None], axis=-1)
        assert np.abs(d[-1] - d[0]).max() < 1e-3, o["name"]
    assert x[:, :, 1].min() > -1e-3


def test_pendulum_chain_links_are_inextensible():
    """pendulum_chain: all six links stay 0.1 m long to within 1e-3 m over 30 frames."""
    _, x = _run("pendulum_chain", 30)
    links = np.linalg.norm(np.diff(x, axis=1), axis=-1)
    assert np.abs(links - 0.1).max() < 1e-3


def test_xpbd_soft_body_keeps_its_volume():
    """xpbd_soft_body: through the impact (30 frames) the volume stays within 5% and it stays above ground."""
    from pliant.geometry import signed_tet_volumes

    scene, x = _run("xpbd_soft_body", 30)
    tets = scene.model.tet_indices_np
    v = np.array([signed_tet_volumes(f, tets).sum() for f in x])
    assert np.abs(v / v[0] - 1).max() < 0.05
    assert x[:, :, 1].min() > -1e-3


def test_fem_drop_lands_without_exploding():
    """fem_drop: after 30 frames both bodies rest on the ground (lowest point < 1 cm, > -1 mm) and keep
    their size within 30%."""
    scene, x = _run("fem_drop", 30)
    for o in scene.model.objects:
        p = x[:, o["start"] : o["start"] + o["count"]]
        ext = p.max(axis=1) - p.min(axis=1)
        assert np.all(ext[-1] < 1.3 * ext[0]), o["name"]
        assert -1e-3 < p[-1, :, 1].min() < 0.01, o["name"]


def test_cantilever_tip_sags_below_the_clamped_root():
    """cantilever: after 20 frames the root stays put (1e-6 m) and the tip sits > 5 cm below it."""
    _, x = _run("cantilever", 20)
    root = x[0, :, 0] < -0.299
    tip = x[0, :, 0] > 0.299
    assert np.abs(x[:, root] - x[0, root]).max() < 1e-6
    assert x[-1, root, 1].mean() - x[-1, tip, 1].mean() > 0.05


def test_fem_squeeze_follows_the_press():
    """fem_squeeze: at t = 1 s the top cap is 9 cm lower (to 2 mm) and the ball stays above ground."""
    _, x = _run("fem_squeeze", 30)
    assert abs((x[0, :, 1].max() - x[-1, :, 1].max()) - 0.09) < 2e-3
    assert x[:, :, 1].min() > -1e-3


def test_fem_embedded_render_mesh_follows_the_tets():
    """fem_embedded: the 5120-triangle render mesh reproduces the icosphere at frame 0 (1e-5 m) and moves
    with the body (its centroid within 1 cm of the tet mesh's)."""
    import trimesh

    scene, x = _run("fem_embedded", 10)
    xr, faces, colors = scene.render_mesh(x, None)
    n = scene.model.particle_count
    assert faces.shape == (5120, 3) and faces.min() >= n
    ico = trimesh.creation.icosphere(subdivisions=4, radius=0.145).vertices + np.array([0.0, 0.45, 0.0])
    assert np.abs(xr[0, n:] - ico).max() < 1e-5
    assert np.linalg.norm(xr[-1, n:].mean(0) - x[-1].mean(0)) < 0.01
    assert colors.shape == (xr.shape[1], 3)


def test_collider_is_drawn_as_a_static_mesh():
    """A [[colliders]] sphere adds one grey static mesh (642 vertices at icosphere level 3) to the video."""
    scene = build_scene(load_scene("cloth_sphere"), device="cpu")
    x = scene.model.particle_q_np[None]
    xr, faces, colors = scene.render_mesh(x, scene.model.render_faces)
    assert xr.shape[1] == scene.model.particle_count + 642
    assert np.allclose(colors[-1], (0.55, 0.62, 0.72))


@pytest.mark.parametrize(
    ("body", "line", "field", "hint"),
    [
        (
            '[[objects]]\nkind = "rope"\nmaterial = {stiffness = 1.0}\n[[colliders]]\nkind = "cone"\n',
            10,
            "colliders[0].kind",
            "allowed: sphere, box, capsule, mesh",
        ),
        (
            '[[objects]]\nkind = "rope"\nmaterial = {stiffness = 1.0}\n[[colliders]]\nkind = "sphere"\n'
            "center = [0.0, 0.0, 0.0]\n",
            9,
            "colliders[0].radius",
            "missing required field 'radius'",
        ),
        (
            '[[objects]]\nkind = "rope"\nmaterial = {stiffness = 1.0}\n[[colliders]]\nkind = "box"\n'
            "center = [0.0, 0.0, 0.0]\nhalf_extent = 0.1\n",
            12,
            "colliders[0].half_extent",
            "damping_ratio, kind, center, half_extents",
        ),
        (
            '[[objects]]\nkind = "rope"\nmaterial = {stiffness = 1.0}\n[[handles]]\nkind = "points"\n'
            "points = [[0.0, 1.0, 0.0]]\nradius = 0.1\n",
            9,
            "handles[0].stiffness",
            "needs stiffness",
        ),
        (
            '[[objects]]\nkind = "rope"\nmodel = "pbd"\n[[handles]]\nkind = "points"\n'
            "points = [[0.0, 1.0, 0.0]]\nradius = 0.1\nstiffness = 10.0\n",
            9,
            "handles[0].mode",
            'need solver kind "force"',
        ),
        (
            '[[objects]]\nkind = "rope"\nmaterial = {stiffness = 1.0}\n[[handles]]\nkind = "box"\n'
            "center = [0.0, 1.0, 0.0]\nhalf_extents = 0.1\npath = [[0.0, 0, 0, 0], [0.0, 1, 0, 0]]\n",
            13,
            "handles[0].path",
            "keyframe times must increase",
        ),
        (
            '[[objects]]\nkind = "cluster"\n[solver]\nkind = "force"\n',
            9,
            "solver.kind",
            'needs kind = "xpbd"',
        ),
        (
            '[[objects]]\nkind = "rope"\nmaterial = {stiffness = 1.0}\n[solver]\nself_collision = {}\n',
            10,
            "solver.self_collision.thickness",
            "missing required field 'thickness'",
        ),
    ],
    ids=[
        "unknown-collider",
        "missing-radius",
        "collider-typo",
        "springs-no-stiffness",
        "springs-xpbd",
        "bad-keyframes",
        "cluster-force",
        "self-collision-thickness",
    ],
)
def test_new_sections_errors_name_file_line_and_field(body, line, field, hint):
    """Errors in [[colliders]], [[handles]], clusters, self_collision name the file, line, field and fix."""
    with pytest.raises(SceneError) as info:
        parse_scene(_scene(body), "bad.toml")
    msg = str(info.value)
    assert f"bad.toml:{line}: {field}: " in msg, msg
    assert hint in msg, msg


def test_box_handle_outside_the_object_is_an_error():
    """A box handle that holds no particle fails at build time naming handles[0].center."""
    cfg = parse_scene(
        _scene(
            '[[objects]]\nkind = "rope"\nmaterial = {stiffness = 1.0}\n[[handles]]\nkind = "box"\n'
            "center = [5.0, 5.0, 5.0]\nhalf_extents = 0.1\n"
        ),
        "s.toml",
    )
    with pytest.raises(SceneError, match=r"s.toml:11: handles\[0\].center: the box holds no particle"):
        build_scene(cfg, device="cpu")


def test_every_collider_kind_and_an_xpbd_kinematic_handle(tmp_path):
    """box, capsule and mesh colliders build with XPBD; a kinematic handle with velocity 0.6 m/s along x puts
    the grabbed particle 0.02 m further after one 1/30 s frame (to 1e-5 m)."""
    import trimesh

    trimesh.creation.box(extents=(0.2, 0.2, 0.2)).export(tmp_path / "obstacle.obj")
    text = _scene(
        """
[[objects]]
kind = "rope"
name = "r"
model = "pbd"
n_segments = 4
origin = [0.0, 1.0, 0.0]
pin = "none"

[[colliders]]
kind = "box"
center = [0.0, 0.2, 0.0]
half_extents = [0.3, 0.05, 0.3]

[[colliders]]
kind = "capsule"
a = [-0.5, 0.5, 0.5]
b = [0.5, 0.5, 0.5]
radius = 0.05

[[colliders]]
kind = "mesh"
path = "obstacle.obj"
origin = [0.0, 0.6, -0.5]

[[handles]]
kind = "box"
object = "r"
center = [0.0, 1.0, 0.0]
half_extents = 0.01
velocity = [0.6, 0.0, 0.0]
"""
    ).replace("frames = 2", "frames = 2\ndt = 0.03333333333333333")
    scene = build_scene(parse_scene(text, "c.toml", tmp_path), device="cpu")
    assert len(scene.colliders) == 3 and len(scene.static_meshes) == 3
    x = scene.simulator().run(1, progress=False).x
    assert np.abs(x[1, 0] - (x[0, 0] + [0.02, 0.0, 0.0])).max() < 1e-5
    assert np.all(np.isfinite(x))


@pytest.mark.slow
@pytest.mark.parametrize(
    "name", [n for n in builtin_scenes() if "fem" in n or n in ("cantilever", "xpbd_soft_body")]
)
def test_volumetric_scene_does_not_blow_up(name):
    """Over all its frames no body of a volumetric scene grows beyond 1.5 times its initial extent (slow)."""
    scene = build_scene(load_scene(name), device="cpu")
    x = scene.simulator().run(scene.frames, progress=False).x
    for o in scene.model.objects:
        p = x[:, o["start"] : o["start"] + o["count"]]
        ext = (p.max(axis=1) - p.min(axis=1)).max(axis=1)
        assert ext.max() < 1.5 * ext[0], f"{name}/{o['name']}: extent {ext.max():.3f} m vs {ext[0]:.3f} m"


def test_ground_stiffness_sets_the_ground_penalty():
    """``[ground] stiffness`` is the κ of the GroundPenalty an implicit integrator minimises (the default
    1e6 otherwise) and, once stated, the model's compliant ground, which explicit integrators meet after
    each step (no energy; without it they keep the projection); κ ≤ 0 is an error naming the field."""
    body = (
        '[[objects]]\nkind = "soft_box"\nmodel = "fem"\ncells = [1, 1, 1]\nsize = [0.1, 0.1, 0.1]\n'
        "origin = [0.0, 0.2, 0.0]\nmaterial = { E = 1e5, nu = 0.3 }\n\n[ground]\nstiffness = 3e6\n\n"
        '[solver]\nintegrator = "{integ}"\n'
    )

    def kappas(integ: str) -> list[float]:
        scene = build_scene(parse_scene(_scene(body.replace("{integ}", integ)), "g.toml"), device="cpu")
        return [e.stiffness for e in scene.solver.energies if isinstance(e, pl.energies.GroundPenalty)]

    assert kappas("BackwardEuler") == [3e6]
    assert kappas("SymplecticEuler") == []
    explicit = build_scene(
        parse_scene(_scene(body.replace("{integ}", "SymplecticEuler")), "g.toml"), device="cpu"
    )
    assert explicit.model.ground.compliant and explicit.model.ground.stiffness == 3e6
    unset = build_scene(
        parse_scene(
            _scene(body.replace("stiffness = 3e6\n", "").replace("{integ}", "SymplecticEuler")), "g.toml"
        ),
        device="cpu",
    )
    assert not any(isinstance(e, pl.energies.GroundPenalty) for e in unset.solver.energies)
    with pytest.raises(SceneError, match=r"ground\.stiffness"):
        parse_scene(_scene(body.replace("3e6", "-1.0").replace("{integ}", "BackwardEuler")), "g.toml")
