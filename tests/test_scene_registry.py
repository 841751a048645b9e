"""The scene registries from outside the package: a new object kind and a new solver kind are one registered
function each and run from a scene file; the renamed keys (frame_dt, stiffness_factor) and their old names;
FastMassSpring and [[energies]] / [[constraints]] from TOML."""

from __future__ import annotations

import warnings
from typing import Literal

import numpy as np
import pytest

import pliant as pl
from pliant.scene import SceneError, build_scene, load_scene, parse_scene

HEAD = '[scene]\nname = "t"\nframes = 1\nsubsteps = 4\nframe_dt = 0.02\ngravity = [0.0, -10.0, 0.0]\n'


# ---------------------------------------------------------------------------------------------- a new kind
class Ring(pl.scene.ObjectBase):
    """n particles on a horizontal circle, neighbours joined by springs."""

    kind: Literal["test_ring"]
    n: int = 8
    radius: float = 0.2
    height: float = 1.0
    mass: float = 0.08


def build_ring(ctx, o, index):
    a = 2 * np.pi * np.arange(o.n) / o.n
    pts = np.stack([o.radius * np.cos(a), np.full(o.n, o.height), o.radius * np.sin(a)], axis=1)
    b = ctx.builder
    first = b.add_particles(pts, o.mass / o.n, name=o.name or f"ring{index}")
    edges = np.stack([np.arange(o.n), (np.arange(o.n) + 1) % o.n], axis=1) + first
    b.add_springs(edges, stiffness=o.material.stiffness or 100.0)
    b.register_object(o.name or f"ring{index}", "test_ring", first)


class Ballistic(pl.solvers.Solver):
    """Free flight, symplectic Euler on the host (only what a scene needs of a solver: step)."""

    def step(self, state_in, state_out, control, dt):
        g = np.asarray(self.model.gravity_vec, float) if hasattr(self.model, "gravity_vec") else None
        g = np.array([0.0, -10.0, 0.0]) if g is None or g.shape != (3,) else g
        v = state_in.particle_qd.numpy() + dt * g
        x = state_in.particle_q.numpy() + dt * v
        state_out.particle_qd.assign(v.astype(state_out.particle_qd.numpy().dtype))
        state_out.particle_q.assign(x.astype(state_out.particle_q.numpy().dtype))


@pytest.fixture(scope="module", autouse=True)
def registered():
    pl.scene.register_object_kind("test_ring", Ring, build_ring, particles=lambda cfg, o: o.n)
    pl.scene.register_solver("test_ballistic", lambda ctx: Ballistic(ctx.model), models=("mass_spring",))
    pl.scene.register_energy("test_drag", lambda model, *, c=0.0: pl.energies.AirDrag(c))
    yield


def test_a_kind_registered_outside_the_package_builds_and_runs():
    """A `test_ring` object from a scene file: 8 particles on a 0.2 m circle; with the force solver and no
    ground it falls freely while the ring keeps its shape (springs at rest length)."""
    cfg = parse_scene(
        HEAD + '[[objects]]\nkind = "test_ring"\nn = 8\nmaterial = {stiffness = 100.0}\n', "ring.toml"
    )
    scene = build_scene(cfg, device="cpu")
    assert scene.model.objects[0]["kind"] == "test_ring" and scene.model.particle_count == 8
    x = scene.simulator().run(1, progress=False).x
    r = np.linalg.norm(x[-1][:, [0, 2]], axis=1)
    assert np.abs(r - 0.2).max() < 1e-5  # the ring neither stretches nor collapses in free fall
    assert x[-1, :, 1].max() < 1.0 - 1e-3


def test_registered_kind_gets_the_same_error_messages():
    """Unknown fields of the new kind and the list of kinds use the usual file:line: field: messages."""
    with pytest.raises(SceneError) as info:
        parse_scene(HEAD + '[[objects]]\nkind = "test_ring"\nradus = 0.2\n', "ring.toml")
    assert str(info.value).startswith("ring.toml:9: objects[0].radus: unknown field 'radus'; allowed: name")
    with pytest.raises(SceneError, match=r"allowed: cloth, rope, .*test_ring"):
        parse_scene(HEAD + '[[objects]]\nkind = "nope"\n', "ring.toml")


def test_a_solver_registered_outside_the_package_runs_a_scene():
    """[solver] kind = "test_ballistic": 4 substeps of h = 5 ms from rest under g = 10 m/s² drop each particle
    by g h² (1+2+3+4) = 2.5 mm (symplectic Euler, closed form)."""
    body = '[[objects]]\nkind = "rope"\nn_segments = 3\npin = "none"\nmaterial = {stiffness = 10.0}\n'
    cfg = parse_scene(HEAD + body + '[solver]\nkind = "test_ballistic"\n', "b.toml")
    scene = build_scene(cfg, device="cpu", dtype="float64")
    assert isinstance(scene.solver, Ballistic)
    x = scene.simulator().run(1, progress=False).x
    assert np.allclose(x[1, :, 1] - x[0, :, 1], -10.0 * 0.005**2 * 10, atol=1e-12)


def test_a_registered_energy_is_usable_from_the_scene_file():
    """[[energies]] kind = "test_drag" adds the energy to the force solver; its options are checked."""
    body = '[[objects]]\nkind = "rope"\nn_segments = 3\nmaterial = {stiffness = 10.0}\n'
    cfg = parse_scene(HEAD + body + '[[energies]]\nkind = "test_drag"\nc = 0.5\n', "e.toml")
    solver = build_scene(cfg, device="cpu").solver
    assert any(isinstance(e, pl.energies.AirDrag) and e.coefficient == 0.5 for e in solver.energies)
    with pytest.raises(
        SceneError, match=r"energies\[0\]\.cc: test_drag has no option 'cc'; did you mean 'c'"
    ):
        parse_scene(HEAD + body + '[[energies]]\nkind = "test_drag"\ncc = 0.5\n', "e.toml")


def test_builtin_air_drag_and_particle_collision_entries():
    """The built-in [[energies]] air_drag and [[constraints]] particle_collision build into their solvers."""
    rope = '[[objects]]\nkind = "rope"\nn_segments = 3\nmaterial = {stiffness = 10.0}\n'
    s = build_scene(parse_scene(HEAD + rope + '[[energies]]\nkind = "air_drag"\ncoefficient = 0.1\n'), "cpu")
    assert any(isinstance(e, pl.energies.AirDrag) for e in s.solver.energies)
    pbd = '[[objects]]\nkind = "rope"\nn_segments = 3\nmodel = "pbd"\n'
    s = build_scene(parse_scene(HEAD + pbd + '[[constraints]]\nkind = "particle_collision"\n'), "cpu")
    assert any(isinstance(c, pl.constraints.ParticleCollision) for c in s.solver.constraints)
    with pytest.raises(SceneError, match=r'constraints\[0\]: extra constraints need solver kind "xpbd"'):
        parse_scene(HEAD + rope + '[[constraints]]\nkind = "particle_collision"\n')


def test_fast_mass_spring_from_a_scene_matches_the_api():
    """[solver] kind = "fast_mass_spring" builds pl.solvers.FastMassSpring with its options, and one frame
    equals the same solver built by hand bit for bit."""
    text = HEAD + (
        '[[objects]]\nkind = "cloth"\nnx = 4\nny = 4\npin = "top-corners"\nmaterial = {stiffness = 300.0}\n'
        '[solver]\nkind = "fast_mass_spring"\noptions = {method = "implicit", cg_iterations = 20}\n'
    )
    scene = build_scene(parse_scene(text, "f.toml"), device="cpu")
    assert isinstance(scene.solver, pl.solvers.FastMassSpring) and scene.solver.method == "implicit"
    x = scene.simulator().run(1, progress=False).x
    ref = pl.solvers.FastMassSpring(scene.model, method="implicit", cg_iterations=20)
    scene2 = build_scene(parse_scene(text, "f.toml"), device="cpu")
    y = pl.Simulator(scene2.model, ref, frame_dt=0.02, substeps=4).run(1, progress=False).x
    assert np.array_equal(x, y)
    with pytest.raises(
        SceneError, match=r"solver\.options\.metod: fast_mass_spring has no option 'metod'; did you"
    ):
        parse_scene(text.replace("method =", "metod ="), "f.toml")


# ---------------------------------------------------------------------------------------------- renames
def test_frame_dt_and_the_deprecated_dt_key():
    """[scene] frame_dt sets Scene.frame_dt; the old key dt still works with one DeprecationWarning naming
    frame_dt; giving both is an error; Scene.dt is a deprecated alias."""
    body = '[[objects]]\nkind = "rope"\nmaterial = {stiffness = 10.0}\n'
    new = parse_scene(HEAD + body)
    with pytest.warns(DeprecationWarning, match=r"\[scene\] dt is deprecated; rename it to frame_dt"):
        old = parse_scene(HEAD.replace("frame_dt", "dt") + body)
    assert new.scene.frame_dt == old.scene.frame_dt == 0.02
    with pytest.raises(SceneError, match=r"scene: give frame_dt only"):
        parse_scene(HEAD + "dt = 0.01\n" + body)
    scene = build_scene(new, device="cpu")
    with pytest.warns(DeprecationWarning, match="frame_dt"):
        assert scene.dt == scene.frame_dt == 0.02


def test_pbd_stiffness_factor_and_its_old_name():
    """[solver] stiffness_factor (PBD's k in [0, 1]) reaches PBD; the old key stiffness warns and works;
    stiffness_factor with XPBD is rejected as not applying to it."""
    body = '[[objects]]\nkind = "rope"\nmodel = "pbd"\nn_segments = 3\n[solver]\nkind = "pbd"\n'
    s = build_scene(parse_scene(HEAD + body + "stiffness_factor = 0.25\n"), device="cpu")
    assert s.solver._stiffness("stiffness") == 0.25
    with pytest.warns(DeprecationWarning, match="rename it to stiffness_factor"):
        cfg = parse_scene(HEAD + body + "stiffness = 0.25\n")
    assert cfg.solver.stiffness_factor == 0.25
    with pytest.raises(SceneError, match=r"solver\.stiffness_factor: does not apply to solver kind 'xpbd'"):
        parse_scene(HEAD + body.replace('kind = "pbd"', 'kind = "xpbd"') + "stiffness_factor = 0.5\n")


def test_builtin_scenes_use_the_new_keys():
    """No built-in scene uses a deprecated key (loading them raises no DeprecationWarning)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        for name in pl.scene.builtin_scenes():
            load_scene(name)


def test_io_keeps_only_trajectory_files():
    """pliant.io holds trajectories, checkpoints, observation files (fitting) and camera files (`pliant run
    --cameras`), and how they are written and read (atomically, to checked output paths; NPZ headers checked
    against the memory available before loading; observed images as unit floats) only; scene files are
    pliant.scene."""
    assert set(pl.io.__all__) == {
        "atomic_output",
        "atomic_write_text",
        "available_memory",
        "npz_headers",
        "npz_memory_problem",
        "read_npz",
        "CameraFile",
        "CameraFileError",
        "load_camera_file",
        "CheckpointError",
        "CheckpointSpec",
        "Trajectory",
        "atomic_savez",
        "load_checkpoint",
        "save_checkpoint",
        "ObservationError",
        "Observations",
        "OutputPathError",
        "check_file_stem",
        "check_out_dir",
        "check_writable_dir",
        "confined",
        "to_unit_float",
    }
    assert pl.scene.load_scene is load_scene


def test_cli_frame_dt_and_deprecated_dt(tmp_path, capsys):
    """`pliant run --frame-dt` sets the frame duration; `--dt` still works and prints a note naming
    --frame-dt; a scene file with the old key prints a note naming frame_dt."""
    from pliant.cli import main

    args = [
        "run",
        "rope",
        "--frames",
        "1",
        "--out",
        str(tmp_path),
        "--quiet",
        "--no-video",
        "--device",
        "cpu",
    ]
    assert main([*args, "--frame-dt", "0.02"]) == 0
    assert np.allclose(pl.Trajectory.load(tmp_path / "rope.npz").t, [0.0, 0.02])
    assert main([*args, "--dt", "0.01"]) == 0
    assert "--dt is deprecated; use --frame-dt" in capsys.readouterr().err
    assert np.allclose(pl.Trajectory.load(tmp_path / "rope.npz").t, [0.0, 0.01])
    old = tmp_path / "old.toml"
    old.write_text(
        '[scene]\nname = "old"\ndt = 0.02\n[[objects]]\nkind = "rope"\nmaterial = {stiffness = 10.0}\n'
    )
    assert main(["run", str(old), *args[2:]]) == 0
    assert "pliant: note: [scene] dt is deprecated; rename it to frame_dt" in capsys.readouterr().err


def test_registering_a_schema_without_its_tag_is_refused():
    """A schema must declare kind: Literal[name] and subclass ObjectBase, else registration says so."""
    with pytest.raises(TypeError, match=r'must declare kind: Literal\["other"\]'):
        pl.scene.register_object_kind("other", Ring, build_ring)
    with pytest.raises(TypeError, match="must subclass pliant.scene.ObjectBase"):
        pl.scene.register_object_kind("other", pl.scene.Material, build_ring)
    assert "other" not in pl.scene._registry.OBJECT_KINDS
