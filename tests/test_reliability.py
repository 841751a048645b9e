"""Issue 11 regressions outside the scene layer: outputs confined to --out, third-party failures wrapped,
non-finite and teleporting states reported as divergence, solve_static's singular start, load steps and
per-component constraints, validated checkpoints. One test (or more) per item; the names say which."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import pliant as pl
from pliant.cli import main
from pliant.io import CheckpointError

ROPE = Path(pl.__file__).parent / "scenes" / "rope.toml"


def _rope_scene(
    tmp_path: Path, *, name: str = '"rope"', origin: str | None = None, fps: str | None = None
) -> Path:
    """A copy of the built-in rope scene, 2 frames, with its name (a TOML value) and origin replaced."""
    text = ROPE.read_text().replace('name = "rope"', f"name = {name}", 1).replace("frames = 90", "frames = 2")
    if origin is not None:
        text = text.replace("origin = [-0.4, 1.0, 0.0]", f"origin = {origin}")
    if fps is not None:
        text = text.replace("fps = 30", f"fps = {fps}")
    path = tmp_path / "scene.toml"
    path.write_text(text)
    return path


def _files(folder: Path) -> set[Path]:
    return {p for p in folder.rglob("*") if p.is_file()}


# ----------------------------------------------------------------------- item 1: outputs stay in --out
@pytest.mark.parametrize(
    "name",
    [
        '"../../escaped"',
        '"/tmp/pliant_abs_escape"',
        '"sub/dir"',
        '""',
        '"."',
        '".."',
        f'"{"x" * 300}"',
        '"a\\u0000b"',
    ],
)
def test_item1_scene_name_cannot_escape_out(tmp_path, capsys, name):
    """A scene name that is not one plain file name is an error (exit 1) before anything is written."""
    work = tmp_path / "work"
    work.mkdir()
    scene = _rope_scene(work, name=name)
    before = _files(tmp_path)
    out = work / "a" / "b" / "out"
    assert main(["run", str(scene), "--out", str(out), "--quiet", "--no-video", "--device", "cpu"]) == 1
    err = capsys.readouterr().err
    assert "pliant: error:" in err and "Traceback" not in err
    assert _files(tmp_path) == before, "a file was written for a rejected scene name"
    assert not Path("/tmp/pliant_abs_escape.npz").exists()


def test_item1_output_through_a_symlink_is_refused(tmp_path, capsys):
    """An output file in --out that is a symbolic link to elsewhere is refused, not written through."""
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    (out / "rope.npz").symlink_to(elsewhere / "stolen.npz")
    args = ["run", str(_rope_scene(tmp_path)), "--out", str(out), "--quiet", "--no-video", "--device", "cpu"]
    assert main(args) == 1
    assert "outside the output folder" in capsys.readouterr().err
    assert not (elsewhere / "stolen.npz").exists()


def test_item1_confined_accepts_plain_names(tmp_path):
    """Control: a plain name resolves into the folder (so the refusals above are not blanket ones)."""
    from pliant.io._paths import OutputPathError, confined

    assert confined(tmp_path / "new", "run_1.ckpt.npz") == (tmp_path / "new").resolve() / "run_1.ckpt.npz"
    with pytest.raises(OutputPathError, match="not a plain file name"):
        confined(tmp_path, "../x.npz")


# ---------------------------------------------- item 4/5: non-finite at frame 0, teleports, divergence
def test_item5_overflowing_origin_is_a_frame0_error_without_warning(tmp_path, capsys, recwarn):
    """origin = 1e39 overflows float32: exit 1 naming frame 0, no RuntimeWarning, nothing written."""
    scene = _rope_scene(tmp_path, origin="[-0.4, 1e39, 0.0]")
    out = tmp_path / "out"
    assert main(["run", str(scene), "--out", str(out), "--quiet", "--device", "cpu"]) == 1
    err = capsys.readouterr().err
    assert "pliant: error:" in err and "Traceback" not in err
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]
    assert not out.exists() or not _files(out)


def test_item5_simulator_checks_the_initial_state():
    """Simulator.run raises DivergenceError at frame 0 for a non-finite initial state (API path)."""
    b = pl.ModelBuilder()
    b.add_rope(n_segments=4, length=0.4, mass=0.05, stiffness=400.0, start=(0.0, 0.5, 0.0))
    model = b.finalize(device="cpu")
    sim = pl.Simulator(model, pl.solvers.ForceSolver(model))
    q = model.particle_q.numpy()
    q[2, 1] = np.inf
    sim.state_0.particle_q.assign(q)
    with pytest.raises(pl.DivergenceError) as info:
        sim.run(3, progress=False)
    assert info.value.frame == 0 and "initial" in str(info.value)


class _Teleport(pl.solvers.Solver):
    """Moves every particle by ``jump`` [m] per step without touching the velocities (like a collider
    that encloses the body, or a handle's kinematic target)."""

    def __init__(self, model, jump: float) -> None:
        super().__init__(model)
        self.jump = jump

    def step(self, state_in, state_out, control, dt):
        free = (self.model.particle_inv_mass.numpy() > 0)[:, None]  # pins stay: not a handle's motion
        jump = np.where(free, np.array([self.jump, 0.0, 0.0]), 0.0).astype(np.float32)
        state_out.particle_q.assign(state_in.particle_q.numpy() + jump)
        state_out.particle_qd.zero_()


@pytest.mark.parametrize("jump, diverges", [(1e9, True), (1.0, True), (1e-3, False)])
def test_item5_displacement_speed_is_bounded(jump, diverges):
    """A frame whose displacement / dt exceeds max_speed is a divergence with advice, although every
    velocity is zero; a slow motion is not (1 m per 1/60 s frame = 60 m/s > max_speed 50)."""
    b = pl.ModelBuilder()
    b.add_rope(n_segments=2, length=0.2, mass=0.05, stiffness=400.0, start=(0.0, 0.5, 0.0))
    model = b.finalize(device="cpu")
    sim = pl.Simulator(model, _Teleport(model, jump), frame_dt=1 / 60, substeps=1, max_speed=50.0)
    if not diverges:
        assert sim.run(3, progress=False).frame_count == 4
        return
    with pytest.raises(pl.DivergenceError, match="displacement") as info:
        sim.run(3, progress=False)
    assert info.value.frame == 1
    assert info.value.value == pytest.approx(jump * 60, rel=1e-3)
    assert "collider" in str(info.value) and "handle" in str(info.value)


# ----------------------------------------------------------------- item 4: deep third-party failures
def test_item4_locate_points_outside_the_tets_is_a_clear_error():
    """Points ~1e308 m away (no KD-tree neighbour) and points beyond max_distance: ValueError naming them
    and the distance, instead of an IndexError; points inside still locate."""
    from pliant.geometry import locate_points

    X = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    tets = np.array([[0, 1, 2, 3]])
    with pytest.raises(ValueError, match=r"#0 at \[1e\+308") as info:
        locate_points(np.array([[1e308, 0, 0], [0.1, 0.1, 0.1]]), X, tets)
    assert "1e+308 m" in str(info.value)
    with pytest.raises(ValueError, match=r"by more than 0\.5 m \(up to 8\.08 m") as info:  # (15 − 1)/√3
        locate_points(np.array([[0.1, 0.1, 0.1], [5.0, 5.0, 5.0]]), X, tets, max_distance=0.5)
    assert "#1 at [5.0, 5.0, 5.0]" in str(info.value)
    with pytest.raises(ValueError, match="NaN/inf"):
        locate_points(np.array([[np.nan, 0, 0]]), X, tets)
    ids, bary, inside = locate_points(np.array([[0.1, 0.2, 0.3]]), X, tets, max_distance=0.0)
    np.testing.assert_allclose(bary, [[0.4, 0.1, 0.2, 0.3]], atol=1e-12)
    assert inside.all()


def _lbfgs_box(dtype: str):
    b = pl.ModelBuilder()
    b.add_soft_box(cells=(2, 2, 2), size=(0.2, 0.2, 0.2), origin=(0.0, 0.12, 0.0), E=2e4, nu=0.3)
    b.add_ground(0.0)
    model = b.finalize(device="cpu", dtype=dtype)
    integ = pl.integrators.BackwardEuler()
    solver = pl.solvers.ForceSolver(model, [pl.energies.NeoHookean()], integ, minimizer={"method": "lbfgs"})
    return model, solver


def test_item4_lbfgs_singular_factor_is_a_clear_error():
    """dt = 1e30 in float32: h²K overflows, H₀ is singular; SingularSystemError saying to lower dt, not
    SciPy's RuntimeError. Control: a sane step works."""
    model, solver = _lbfgs_box("float32")
    s0, s1 = model.state(), model.state()
    with pytest.raises(pl.solvers.SingularSystemError, match="lower dt"):
        solver.step(s0, s1, model.control(), 1e30)
    model, solver = _lbfgs_box("float32")
    s0, s1 = model.state(), model.state()
    solver.step(s0, s1, model.control(), 1e-2)
    assert np.all(np.isfinite(s1.particle_q.numpy()))


@pytest.mark.parametrize("fov", [5e-324, 0.0, 179.9, 180.0, float("nan"), float("inf")])
def test_item4_camera_fov_out_of_range(fov):
    """fov tiny (the ZeroDivisionError of issue 11), 180° and beyond, NaN: a ValueError naming the range."""
    with pytest.raises(ValueError, match=r"fov_y must be in \[0\.01, 179\.0\]"):
        pl.render.Camera(eye=(1, 1, 3), target=(0, 0, 0), fov_y=fov)
    assert pl.render.Camera(eye=(1, 1, 3), target=(0, 0, 0), fov_y=0.01).focal_px > 0


def test_item4_collider_far_away_renders_without_division_by_zero():
    """A collider vertex at x = -1e308 (beyond float32) is not drawn, and the shadow pass does not divide
    by zero; the body is still drawn, as without the far vertex."""
    cam = pl.render.Camera(eye=(1, 1, 3), target=(0, 0.3, 0))
    r = pl.render.Renderer(cam, ground=0.0)
    body = np.array([[0.0, 0.3, 0.0], [0.2, 0.3, 0.0], [0.0, 0.5, 0.0]])
    far = np.vstack([body, [[-1e308, 0.35, 0.0]]])
    for faces in (np.array([[0, 1, 2]]), None):
        img = r.render(far, faces if faces is None else np.vstack([faces, [[1, 2, 3]]]))
        ref = r.render(body, faces)
        np.testing.assert_array_equal(img, ref)


# ---------------------------------------------------------- item 6: messages early and from pliant
@pytest.mark.parametrize("fps", [5e-324, 0.0, -1.0, 1e9, float("nan")])
def test_item6_fps_checked_before_any_rendering(tmp_path, fps):
    """output.fps out of range: ValueError before rendering or launching ffmpeg; no file."""
    path = tmp_path / "v.mp4"
    with pytest.raises(ValueError, match="fps must be in"):
        pl.render.render_video(np.zeros((2, 3, 3)), path, fps=fps, progress=False)
    assert not path.exists()


def test_item6_fps_in_scene_fails_before_simulating(tmp_path, capsys):
    """Through the CLI: exit 1 naming output.fps, before the simulation, nothing written."""
    out = tmp_path / "out"
    assert main(["run", str(_rope_scene(tmp_path, fps="5e-324")), "--out", str(out), "--quiet"]) == 1
    captured = capsys.readouterr()
    assert "fps" in captured.err and "ffmpeg" not in captured.err and "simulated" not in captured.out
    assert not out.exists()


def test_item6_eye_equals_target():
    """eye == target (or too far apart to subtract): ValueError saying so."""
    for eye, target in (((1, 2, 3), (1, 2, 3)), ((1e308, 0, 0), (-1e308, 0, 0))):
        with pytest.raises(ValueError, match="coincide"):
            pl.render.Camera(eye=eye, target=target)


def test_item6_video_writer_wraps_ffmpeg_failures(tmp_path, monkeypatch):
    """An ffmpeg failure (here: the binary cannot start) is a VideoError naming the file, not ffmpeg's
    command line."""
    import imageio_ffmpeg

    def broken(*args, **kwargs):
        raise RuntimeError("ffmpeg -y -f rawvideo ... (a long command line)\nEncoder libx264 not found")

    monkeypatch.setattr(imageio_ffmpeg, "write_frames", broken)
    with pytest.raises(pl.render.VideoError, match=r"v\.mp4.*libx264 not found"):
        pl.render.write_video([np.zeros((4, 4, 3), np.uint8)], tmp_path / "v.mp4", fps=30)


@pytest.mark.parametrize(
    "name, data",
    [
        ("garbage.obj", bytes(range(256)) * 2),
        ("empty.vtk", b""),
        ("empty.vtu", b""),
        ("empty.msh", b""),
        ("short.obj", b"v 1 2\nf 1 2 3\n"),
        ("garbage.stl", bytes(range(255, -1, -1)) * 3),
    ],
)
def test_item3_and_6_unreadable_mesh_files_are_value_errors(tmp_path, capsys, name, data):
    """meshio's sys.exit(1) and trimesh's raw errors become one ValueError naming the file; nothing is
    printed by the readers, and no 'charset_normalizer' or SystemExit."""
    path = tmp_path / name
    path.write_bytes(data)
    with pytest.raises(ValueError) as info:
        pl.geometry.load_mesh(path)
    text = str(info.value)
    assert str(path) in text and "charset_normalizer" not in text
    assert capsys.readouterr().out == ""


# ---------------------------------------- item 4 (singular statics) and solve_static's new options
def _chain(n: int = 10, L: float = 0.1, m: float = 0.05, k: float = 200.0):
    b = pl.ModelBuilder(gravity=(0.0, -9.81, 0.0))
    pos = np.zeros((n + 1, 3))
    pos[:, 1] = -L * np.arange(n + 1)
    b.add_particles(pos, m)
    b.pin(0)
    b.add_springs(np.stack([np.arange(n), np.arange(1, n + 1)], axis=1), stiffness=k)
    return b.finalize(device="cpu", dtype="float64")


@pytest.mark.parametrize("load_steps", [1, 4])
def test_item4_solve_static_singular_start_reaches_closed_form(load_steps):
    """A chain hanging straight at rest length has no transverse stiffness (H singular: SciPy's 'Factor is
    exactly singular' before). The Levenberg–Marquardt shift makes Newton converge to the closed form:
    spring j carries the weight of the n − j particles below it, stretching by (n − j) m g / k."""
    n, L, m, k, g = 10, 0.1, 0.05, 200.0, 9.81
    x, stats = pl.solvers.solve_static(
        _chain(n, L, m, k), [pl.energies.Springs(), pl.energies.Gravity()], load_steps=load_steps
    )
    exact = -np.concatenate([[0.0], np.cumsum(L + (n - np.arange(n)) * m * g / k)])
    np.testing.assert_allclose(x.numpy()[:, 1], exact, rtol=0, atol=1e-12)
    assert np.abs(x.numpy()[:, [0, 2]]).max() == 0.0
    assert stats.converged and stats.stop_reason == "converged"
    assert stats.regularized_steps >= 1 and stats.load_steps == load_steps


@pytest.mark.parametrize("linear_solver", ["direct", "cg"])
def test_solve_static_per_component_fixed_mask(linear_solver):
    """A particle tied to a pinned anchor by a stretched spring, held in y and z only ([N, 3] mask): it slides
    along x to where the spring has its rest length, x = sqrt(L² − y²); held in no component it goes
    radially instead."""
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles([[0.0, 0.0, 0.0], [0.5, 0.3, 0.0]], 1.0)
    b.pin(0)
    b.add_springs([[0, 1]], stiffness=100.0, rest_length=[0.5])
    model = b.finalize(device="cpu", dtype="float64")
    mask = np.zeros((2, 3), bool)
    mask[1, 1:] = True
    x, stats = pl.solvers.solve_static(
        model, [pl.energies.Springs()], fixed=mask, linear_solver=linear_solver
    )
    np.testing.assert_allclose(x.numpy()[1], [0.4, 0.3, 0.0], atol=1e-10)
    assert stats.fixed_dofs == 3 + 2 and stats.stop_reason == "converged"
    x, _ = pl.solvers.solve_static(model, [pl.energies.Springs()])
    np.testing.assert_allclose(x.numpy()[1], 0.5 * np.array([0.5, 0.3, 0.0]) / np.hypot(0.5, 0.3), atol=1e-10)
    with pytest.raises(ValueError, match=r"\(2, 3\) \(components\)"):
        pl.solvers.solve_static(model, [pl.energies.Springs()], fixed=np.zeros((2, 2), bool))


def test_solve_static_stop_reason_max_iterations():
    """One Newton iteration on the nonlinear chain from a sideways start: stop_reason says so."""
    model = _chain()
    x0 = model.particle_q.numpy()
    x0[1:, 0] += 0.05 * np.arange(1, x0.shape[0])
    _, stats = pl.solvers.solve_static(
        model, [pl.energies.Springs(), pl.energies.Gravity()], x0=x0, max_iterations=1
    )
    assert not stats.converged and stats.stop_reason == "max_iterations"


# ----------------------------------------------------------------- item 8: validated checkpoints
def _rope_sim() -> pl.Simulator:
    b = pl.ModelBuilder()
    b.add_rope(n_segments=4, length=0.4, mass=0.05, stiffness=400.0, damping=0.01, start=(0.0, 0.5, 0.0))
    b.pin(0)
    model = b.finalize(device="cpu")
    return pl.Simulator(model, pl.solvers.ForceSolver(model), frame_dt=1 / 60, substeps=4)


def _mutate(path: Path, **changes) -> None:
    with np.load(path) as z:
        data = {k: z[k] for k in z.files}
    for k, v in changes.items():
        if v is None:
            data.pop(k, None)
        else:
            data[k] = v
    np.savez(path, **data)


@pytest.mark.parametrize(
    "change, key",
    [
        ({"param___class__": np.zeros(3)}, "param___class__"),
        ({"frame": np.array(-5)}, "frame"),
        ({"frame": np.array(10**6)}, "frame"),
        ({"param_spring_stiffness": np.ones(2, np.float32)}, "param_spring_stiffness"),
        ({"v": np.zeros((3, 3), np.float32)}, "v"),
        ({"traj_x": np.zeros((2, 5, 3), np.float32)}, "traj_x"),
        ({"x": np.zeros((5, 3), np.float64)}, "x"),
        ({"x": np.full((5, 3), np.nan, np.float32)}, "x"),
        ({"time": np.array(123.0)}, "time"),
        ({"solver_foo": np.zeros(2)}, "solver"),
        ({"x": None}, "x"),
    ],
)
def test_item8_crafted_checkpoints_are_rejected(tmp_path, change, key):
    """Each crafted checkpoint of issue 11 is a CheckpointError naming the file and the key; the run is
    not started and the file is left alone."""
    ckpt = tmp_path / "c.ckpt.npz"
    _rope_sim().run(3, progress=False, checkpoint=ckpt)
    _mutate(ckpt, **change)
    stamp = ckpt.read_bytes()
    with pytest.raises(CheckpointError) as info:
        _rope_sim().run(5, progress=False, checkpoint=ckpt, resume=True)
    assert str(ckpt) in str(info.value) and key in str(info.value)
    assert ckpt.read_bytes() == stamp


def test_item8_crafted_checkpoint_through_cli(tmp_path, capsys):
    """`pliant run --resume` with param___class__ in the checkpoint: exit 1, one error line naming it."""
    scene, out = _rope_scene(tmp_path), tmp_path / "out"
    args = ["run", str(scene), "--out", str(out), "--quiet", "--no-video", "--device", "cpu"]
    assert main(args) == 0
    _mutate(out / "rope.ckpt.npz", param___class__=np.zeros(3))
    assert main([*args, "--frames", "4", "--resume"]) == 1
    err = capsys.readouterr().err
    assert "param___class__" in err and "Traceback" not in err


def test_item8_checkpoint_meta_is_json(tmp_path):
    """Control for the fuzz: an untouched checkpoint resumes; its meta is the trajectory's JSON."""
    ckpt = tmp_path / "c.ckpt.npz"
    _rope_sim().run(3, progress=False, checkpoint=ckpt)
    with np.load(ckpt) as z:
        assert json.loads(str(z["meta"]))["substeps"] == 4
    assert _rope_sim().run(5, progress=False, checkpoint=ckpt, resume=True).frame_count == 6


def test_item1_export_sequence_prefix_cannot_escape(tmp_path):
    """export_*_sequence writes only into its folder: a prefix with a separator is refused."""
    x = np.zeros((2, 3, 3))
    with pytest.raises(ValueError, match="not a plain file name"):
        pl.render.export_ply_sequence(tmp_path / "seq", x, prefix="../escaped_")
    assert not list(tmp_path.rglob("*.ply"))
    paths = pl.render.export_ply_sequence(tmp_path / "seq", x)
    assert all(p.parent == tmp_path / "seq" for p in paths) and len(paths) == 2


def test_item1_export_out_with_nul_is_a_cli_error(tmp_path, capsys):
    """`pliant export --out` with a NUL byte: exit 1 with pliant's message, before reading the input."""
    assert main(["export", str(tmp_path / "missing.npz"), "--out", str(tmp_path / "a\x00b.ply")]) == 1
    assert "is not a plain file name ('\\x00')" in capsys.readouterr().err
    assert main(["export", str(tmp_path / "missing.npz"), "--out", str(tmp_path / "a\x00b" / "x.ply")]) == 1
    assert "not a usable folder name" in capsys.readouterr().err


@pytest.mark.parametrize("speed, diverges", [(1e9, True), (1.0, False)])
def test_item5_fast_handle_is_a_divergence_naming_the_handle(speed, diverges):
    """A kinematic particle (a handle) driven at 1e9 m/s: DivergenceError that blames the handle, not dt;
    at 1 m/s the run completes."""
    b = pl.ModelBuilder()
    b.add_rope(n_segments=4, length=0.4, mass=0.05, stiffness=400.0, start=(0.0, 0.5, 0.0))
    b.add_kinematic([0])
    model = b.finalize(device="cpu")
    x0 = model.particle_q.numpy()[[0]].astype(np.float64)
    dt = 1 / 60

    def drive(t, control):
        control.set_kinematic_targets(x0 + np.array([speed * (t + dt), 0.0, 0.0]))

    sim = pl.Simulator(model, pl.solvers.ForceSolver(model), frame_dt=dt, substeps=8, control_fn=drive)
    if not diverges:
        assert sim.run(3, progress=False).frame_count == 4
        return
    with pytest.raises(pl.DivergenceError, match="handle") as info:
        sim.run(3, progress=False)
    assert info.value.frame == 1 and info.value.value == pytest.approx(speed, rel=1e-3)
    assert "lower dt" not in str(info.value)
