"""``pliant view SCENE``: the live viewer steps the simulation and moves its scene nodes; a drag (the mouse's
callback, or the session's grab / move / release it calls) pulls the object through the simulation with a
force solver, an implicit FEM solve and XPBD, bounded and finite; sliders write the model's arrays; the
record button writes a trajectory and a video; a headless Chromium sees the object mid-drag."""

from __future__ import annotations

import asyncio
import re
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import pliant as pl

viser = pytest.importorskip("viser", reason="the viewer extra: pip install 'pliant[viewer]'")

from pliant.live import LiveSession, serve_live, splat_arrays, write_parameter  # noqa: E402
from pliant.render._viewer import PALETTE, chromium, screenshot_page  # noqa: E402


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _scene(name: str, *overrides: str):
    return pl.scene.build_scene(pl.scene.load_scene(name, list(overrides)), device="cpu")


def _cloth():
    """The demo cloth at 10 × 10 cells, pinned at two corners (force solver, symplectic Euler)."""
    return _scene("cloth", "objects[0].nx=10", "objects[0].ny=10", "scene.substeps=40")


def _drag_callback(handle):
    """The callback the browser's drag on ``handle`` runs (what viser dispatches a pointer drag to)."""
    return handle._impl.drag_cb[0].callback


def _event(phase: str, start, end, camera=(0.0, 2.0, 3.0)):
    return SimpleNamespace(
        phase=phase,
        instance_index=None,
        start_position=tuple(start),
        end_position=tuple(end),
        client=SimpleNamespace(camera=SimpleNamespace(position=camera)),
    )


def test_live_server_steps_the_simulation_and_moves_the_scene_nodes():
    session = LiveSession(_cloth())
    v = serve_live(session, port=_free_port(), start=False)
    try:
        assert urllib.request.urlopen(v.url, timeout=10).status == 200
        assert v.nodes["/pliant/cloth"] == "mesh" and v.nodes["/pliant/ground"] == "ground"
        mesh = v._handles[0][0]
        x0 = np.array(mesh.vertices)
        for _ in range(3):
            assert v.run_frame()
        assert session.frame == 3
        np.testing.assert_array_equal(mesh.vertices, session.x[: x0.shape[0]])
        assert np.max(np.abs(mesh.vertices - x0)) > 1e-3  # the cloth fell: the node moved with it
        # The paced thread: frames advance on their own, and the rate it reports is the one it reaches.
        v.start()
        t0 = time.perf_counter()
        while session.frame < 8 and time.perf_counter() - t0 < 60:
            time.sleep(0.05)
        assert session.frame >= 8 and v.fps > 0
        v.paused = True
        time.sleep(0.3)
        f = session.frame
        time.sleep(0.3)
        assert session.frame == f  # paused: no frame
    finally:
        v.stop()


def _grab_run(scene, particle_at, lift: float, frames: int):
    """Grab the particle nearest ``particle_at`` at frame 0 (at rest), pull it ``lift`` m up, step; returns
    (session, particle, target, start positions, the work bound W [J], kinetic energies per frame)."""
    s = LiveSession(scene)
    x0 = s.x.astype(np.float64).copy()
    p = s.pick(None, None, hit=particle_at)
    target = x0[p] + [0.0, lift, 0.0]
    k, fmax = s.grab_spring(p)
    s.grab(p, target)
    mass = s._mass
    g = float(np.linalg.norm(s.model.gravity))
    path, ke, bound = 0.0, [], []
    prev = x0[p]
    ycm0 = float(np.sum(mass * x0[:, 1]) / mass.sum())
    for _ in range(frames):
        x = s.step(1).astype(np.float64)
        assert np.all(np.isfinite(x))
        path += float(np.linalg.norm(x[p] - prev))
        prev = x[p]
        ycm = float(np.sum(mass * x[:, 1]) / mass.sum())
        # From rest (no kinetic or elastic energy), KE ≤ the work of the capped grab (≤ F path) plus gravity's
        # (M g × the fall of the centre of mass): what holds with any stable, dissipative step.
        bound.append(fmax * path + mass.sum() * g * max(ycm0 - ycm, 0.0))
        ke.append(s.kinetic_energy())
    return s, p, target, x0, np.array(bound), np.array(ke)


@pytest.mark.parametrize(
    "name, scene",
    [
        ("mass-spring cloth", _cloth),
        ("FEM box (backward Euler)", lambda: _scene("soft_box_fem", "objects[0].cells=[3, 3, 3]")),
        ("XPBD ball", lambda: _scene("xpbd_soft_body", "objects[0].material.compliance=1e-4")),
    ],
)
def test_a_grab_pulls_the_particle_and_the_object_follows(name, scene):
    sc = scene()
    x = sc.model.particle_q_np
    top = x[np.argmax(x[:, 1] - 0.01 * np.abs(x[:, 0]))]  # a particle on top, near the middle
    s, p, target, x0, bound, ke = _grab_run(sc, top, lift=0.25, frames=30)
    x = s.x.astype(np.float64)
    d0 = np.linalg.norm(x0[p] - target)
    assert np.linalg.norm(x[p] - target) < 0.5 * d0, name  # pulled toward the cursor
    lo, hi = s.object_of(p)
    others = np.setdiff1d(np.arange(lo, hi), [p])
    # The rest of the object follows: its centre of mass rises with the grabbed particle (without the
    # grab, gravity would only pull it down), and the nearest neighbour moves up by a good part of it.
    m = s._mass[others]
    rise = np.sum(m * (x[others, 1] - x0[others, 1])) / m.sum()
    assert rise > 0.02, (name, rise)
    near = others[np.argmin(np.linalg.norm(x0[others] - x0[p], axis=1))]
    assert x[near, 1] - x0[near, 1] > 0.3 * (x[p, 1] - x0[p, 1]), name
    assert np.all(ke <= 1.5 * bound + 1e-9), (name, (ke / np.maximum(bound, 1e-12)).max())
    s.release()
    s.step(2)
    assert s.control.drag_index == -1 and np.all(np.isfinite(s.x))


def test_the_mouse_drag_callback_is_the_same_grab():
    """viser's drag events on the cloth node: start grabs the particle under the cursor, update moves the
    target (the pointer on the camera-facing plane), end lets go."""
    session = LiveSession(_cloth())
    v = serve_live(session, port=_free_port(), start=False)
    try:
        mesh = v._handles[0][0]
        cb = _drag_callback(mesh)
        x = session.x
        hit = x[60] + [0.001, 0.0, 0.0]
        up = x[60] + [0.0, 0.2, 0.0]
        asyncio.run(cb(_event("start", hit, hit)))
        assert session.grabbed == 60
        np.testing.assert_allclose(session.control.drag_target, hit)
        asyncio.run(cb(_event("update", hit, up)))
        np.testing.assert_allclose(session.control.drag_target, up)
        for _ in range(5):
            v.run_frame()
        assert session.latencies and all(0 < t < 60 for t in session.latencies)
        marker = v._marker
        assert marker.visible and np.allclose(marker.position, up)
        asyncio.run(cb(_event("end", hit, up)))
        assert session.grabbed is None and session.control.drag_index == -1
        v.run_frame()
        assert not marker.visible
    finally:
        v.stop()


def test_a_rope_is_grabbed_by_its_particle_spheres():
    """Lines cannot be clicked in the browser: each rope particle is also a sphere instance, and a drag on
    instance i grabs particle start + i."""
    session = LiveSession(_scene("rope"))
    v = serve_live(session, port=_free_port(), start=False)
    try:
        (node, kind), *_ = [(n, k) for n, k in v.nodes.items() if k == "spheres"]
        handle, part = next((h, p) for h, p in v._handles if p.kind == "spheres")
        np.testing.assert_allclose(handle.batched_positions, session.x[part.start : part.start + part.count])
        free = np.flatnonzero(session._inv_mass[part.start : part.start + part.count] > 0)
        i = int(free[-1])
        ev = _event("start", session.x[part.start + i], session.x[part.start + i] + [0.0, 0.1, 0.0])
        ev.instance_index = i
        asyncio.run(_drag_callback(handle)(ev))
        assert session.grabbed == part.start + i
        v.run_frame()
        np.testing.assert_allclose(handle.batched_positions, session.x[part.start : part.start + part.count])
    finally:
        v.stop()


def test_pick_takes_the_particle_nearest_the_ray_on_the_near_side():
    s = LiveSession(_scene("soft_box_fem", "objects[0].cells=[2, 2, 2]"))
    x = s.x.astype(np.float64)
    eye = np.array([0.0, 0.5, 3.0])
    far = x[np.argmin(x[:, 2])]  # a back corner: the ray through it passes a front particle first
    p = s.pick(eye, far - eye)
    dist = np.linalg.norm(np.cross(x - eye, (far - eye) / np.linalg.norm(far - eye)), axis=1)
    assert dist[p] <= 1.5 * dist.min() + 1e-12
    assert x[p, 2] >= far[2]  # never the one behind
    assert s.pick(eye, eye - far) is None  # nothing in front of the eye


@pytest.mark.parametrize("solver", ["force", "xpbd", "implicit"])
def test_the_drag_force_is_capped(solver):
    """One free particle (no gravity) held by the drag handle 100 m from its target, k = 1000 N/m capped at
    2 N: after one step of h its speed is h F / m with every solver (the uncapped spring: 1e5 N)."""
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles(np.zeros((1, 3)), 0.5)
    model = b.finalize(device="cpu", dtype="float64")
    if solver == "xpbd":
        sol = pl.solvers.XPBD(model)
    else:
        integ = pl.integrators.SymplecticEuler() if solver == "force" else pl.integrators.BackwardEuler()
        sol = pl.solvers.ForceSolver(model, energies=[], integrator=integ)
    control = model.control()
    control.set_drag(0, [100.0, 0.0, 0.0], 1000.0, max_force=2.0)
    s0, s1 = model.state(), model.state()
    h = 1e-2
    sol.step(s0, s1, control, h)
    np.testing.assert_allclose(s1.particle_qd.numpy()[0], [h * 2.0 / 0.5, 0.0, 0.0], rtol=1e-6, atol=1e-12)
    with pytest.raises(ValueError, match="max_force"):
        control.set_drag(0, [1.0, 0.0, 0.0], 10.0, max_force=0.0)


def test_sliders_write_the_running_models_arrays():
    session = LiveSession(_cloth())
    v = serve_live(session, port=_free_port(), start=False)
    try:
        k0 = session.model.spring_stiffness.numpy().copy()
        slider = v._gui["param:stiffness"]
        slider.value = 1.2  # as a browser's slider would
        t0 = time.perf_counter()
        while session.parameters["stiffness"].value != 1.2 and time.perf_counter() - t0 < 10:
            time.sleep(0.02)
        np.testing.assert_allclose(session.model.spring_stiffness.numpy(), 1.2 * k0, rtol=1e-6)
        # Symplectic Euler: the scene's substeps are stable up to Gershgorin's bound on M⁻¹K (h² λ ≤ 4); the
        # slider goes past it, to the knob's 10x, and a stiffer value adds substeps.
        h = session.sim.frame_dt / session.sim.substeps
        idx = session.model.spring_indices.numpy().reshape(-1, 2)
        ksum = np.bincount(idx.ravel(), weights=np.repeat(k0, 2), minlength=session.model.particle_count)
        free = session._inv_mass > 0
        bound = np.min(2.0 * session._mass[free] / (h * h * ksum[free]))
        stiffness = session.parameters["stiffness"]
        assert stiffness.stable == pytest.approx(max(bound, 1.0)) and 1.0 < stiffness.stable < 10.0
        assert stiffness.hi == 10.0 and session.sim.substeps == 40
        write_parameter(session, "damping_rate", 3.0)
        assert session.sim.solver.damping_rate == 3.0
        with pytest.raises(ValueError, match="outside"):
            write_parameter(session, "stiffness", 100.0)
        with pytest.raises(KeyError, match="stiffness"):
            write_parameter(session, "compliance", 1.0)
    finally:
        v.stop()
    xp = LiveSession(_scene("xpbd_soft_body"))
    arrays = xp.parameters["compliance"].arrays
    before = [a.numpy().copy() for a in arrays]
    write_parameter(xp, "compliance", 0.5)
    for a, b0 in zip(arrays, before, strict=True):
        np.testing.assert_allclose(a.numpy(), 0.5 * b0, rtol=1e-6)
    fem = LiveSession(_scene("soft_box_fem", "objects[0].cells=[2, 2, 2]"))
    mu0 = fem.model.tet_mu.numpy().copy()
    write_parameter(fem, "E", 3.0)
    np.testing.assert_allclose(fem.model.tet_mu.numpy(), 3.0 * mu0, rtol=1e-6)


def test_a_stiffness_past_the_explicit_limit_adds_substeps():
    """The cloth under symplectic Euler at 10x its springs' k: n = ⌈n₀ √(10 / stable)⌉ substeps per frame
    (λ_max ∝ k, h = frame_dt / n) keep it finite and its energy bounded while it is dragged, where the
    scene's own 40 diverge; back at 1x it steps 40 again."""
    from pliant.sim import DivergenceError

    session = LiveSession(_cloth())
    stable = session.parameters["stiffness"].stable
    session.grab(60, session.x[60] + [0.0, 0.2, 0.0])
    write_parameter(session, "stiffness", 10.0)
    n = int(np.ceil(40 * np.sqrt(10.0 / stable)))
    assert session.sim.substeps == n > 40 and f"{n} substeps" in session.note
    k, _ = session.grab_spring(60)  # the grab follows the new step
    assert session.control.drag_stiffness == pytest.approx(k)
    for _ in range(40):
        session.step(1)
    assert np.all(np.isfinite(session.x)) and np.ptp(session.x[:, 1]) < 2.0
    write_parameter(session, "stiffness", 1.0)
    assert session.sim.substeps == 40 and session.note == ""
    forced = LiveSession(_cloth())
    write_parameter(forced, "stiffness", 10.0)
    forced.sim.substeps = 40  # what the slider did before: the same k at the scene's step
    with pytest.raises(DivergenceError):
        forced.step(40)


def test_record_writes_a_trajectory_pliant_view_reads_and_a_video(tmp_path):
    from pliant.io import Trajectory
    from pliant.render._viewer import serve_viewer

    session = LiveSession(_cloth())
    v = serve_live(session, port=_free_port(), start=False, record_dir=tmp_path)
    try:
        v.run_frame()
        assert v.record() == []  # starts
        session.grab(60, session.x[60] + [0.0, 0.2, 0.0])
        for _ in range(4):
            v.run_frame()
        files = v.record()  # stops and writes
    finally:
        v.stop()
    assert [f.suffix for f in files] == [".npz", ".mp4"] and all(f.stat().st_size > 0 for f in files)
    traj = Trajectory.load(files[0])
    assert traj.frame_count == 5 and traj.meta["ground"] == 0.0 and traj.meta["objects"][0]["name"] == "cloth"
    np.testing.assert_allclose(traj.x[-1], session.x, atol=1e-6)
    pv = serve_viewer(traj, port=_free_port())
    pv.stop()


def test_splats_follow_the_live_simulation():
    session = LiveSession(_scene("splat_cloth"))
    v = serve_live(session, port=_free_port(), start=False)
    try:
        assert v.nodes["/pliant/splats"] == "splats"
        node = v._splat_node
        c0 = np.array(node.centers)
        session.grab(60, session.x[60] + [0.0, 0.3, 0.0])
        for _ in range(3):
            v.run_frame()
        c, cov, rgb, op = splat_arrays(v._splats, session.x)
        np.testing.assert_allclose(node.centers, c, atol=1e-6)
        assert np.max(np.abs(c - c0)) > 1e-3
        assert np.all(np.linalg.eigvalsh(cov.astype(np.float64)) > -1e-9) and np.all((op > 0) & (op < 1))
    finally:
        v.stop()


def test_missing_viser_gives_the_install_advice(monkeypatch, capsys):
    from pliant._extras import pip_install
    from pliant.cli import main
    from pliant.render._viewer import ViewerError

    advice = pip_install("viewer")  # pliant[viewer], or in a checkout pip install -e '.[viewer]'
    monkeypatch.setitem(sys.modules, "viser", None)
    with pytest.raises(ViewerError, match=re.escape(advice)):
        serve_live(LiveSession(_cloth()))
    assert main(["view", "cloth"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and advice in err[0]


CHROMIUM = chromium()


@pytest.mark.skipif(
    CHROMIUM is None, reason="no chromium on this machine (.ci/run installs Debian's package)"
)
def test_headless_chromium_screenshot_shows_the_cloth_mid_drag(tmp_path):
    import imageio.v3 as iio

    session = LiveSession(_cloth())
    v = serve_live(session, port=_free_port(), start=False)
    try:
        # A free corner (the pins hold the two at z = +0.5).
        corner = int(np.argmax(np.where(session._inv_mass > 0, session.x[:, 0] - session.x[:, 2], -np.inf)))
        session.grab(corner, session.x[corner] + [0.0, 0.45, 0.2])
        for _ in range(25):
            v.run_frame()
        assert session.grabbed == corner
        for attempt, budget in enumerate((8000, 30000)):
            shot = screenshot_page(v.url, tmp_path / f"shot{attempt}.png", budget_ms=budget)
            assert shot.exists()
            img = np.asarray(iio.imread(Path(shot)))[..., :3].astype(int)
            blue = (img[..., 2] > img[..., 0] + 40) & (img[..., 2] > 150)
            red = (img[..., 0] > 180) & (img[..., 1] < 90) & (img[..., 2] < 90)
            if blue.mean() > 0.01 and red.sum() > 3:
                break
    finally:
        v.stop()
    r, g, b = PALETTE[0]
    assert blue.mean() > 0.01, f"cloth colour {(r, g, b)} covers {blue.mean():.3%} of the view"
    assert red.sum() > 3, "the grab target (red ball) is not in the view"


def test_pliant_view_of_a_scene_serves_it_live(tmp_path):
    """The command: a built-in scene name is built, served and stepped until interrupted."""
    import os
    import signal

    port = _free_port()
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    proc = subprocess.Popen(
        [sys.executable, "-m", "pliant.cli", "view", "rope", "--port", str(port), "--out", str(tmp_path)]
        + ["--token", "t0k"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    try:
        line = ""
        t0 = time.perf_counter()
        while "pliant view:" not in line and time.perf_counter() - t0 < 180:
            line = proc.stdout.readline()
            assert line or proc.poll() is None, "pliant view exited early"
        assert "rope live" in line and f":{port}" in line and f"ws://127.0.0.1:{port}/?token=t0k" in line, (
            line
        )
        assert urllib.request.urlopen(f"http://127.0.0.1:{port}", timeout=10).status == 200
        from pliant.live._probe import probe

        url = line.split(" at ", 1)[1].split()[0]
        refused, good = (asyncio.run(probe(u, 1.5)) for u in (f"http://127.0.0.1:{port}", url))
        assert refused.closed == 1008 and good.closed is None and good.messages > 0
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)


_MOVING_BOX = """
[scene]
name = "turntable"
frame_dt = 0.03333333333333333
substeps = 20
frames = 10

[[objects]]
kind = "cloth"
name = "cloth"
nx = 6
ny = 6
size = 0.4
origin = [-0.2, 0.33, -0.2]
plane = "xz"
mass = 0.05
pin = "none"
material = { stiffness = 100.0 }

[[colliders]]
kind = "box"
center = [0.0, 0.15, 0.0]
half_extents = [0.2, 0.15, 0.2]
velocity = [0.2, 0.0, -0.1]
angular_velocity = [0.3, 2.0, 0.0]

[[colliders]]
kind = "box"
center = [1.0, 0.1, 0.0]
half_extents = [0.1, 0.1, 0.1]

[solver]
kind = "force"
integrator = "SymplecticEuler"
"""


def test_a_moving_collider_is_drawn_at_the_simulated_time_and_back_at_reset(tmp_path):
    """The live view draws a moving, spinning box at ``collider_points(meta, t)`` (1e-9 m, float64) for the
    session's simulated time t after each frame, where the simulation has it (its centre c + v t); a reset
    puts both back to t = 0; the static box's drawing never changes."""
    from pliant.render import collider_points

    path = tmp_path / "turntable.toml"
    path.write_text(_MOVING_BOX)
    scene = pl.scene.build_scene(pl.scene.load_scene(path), device="cpu")
    moving, static = scene.trajectory_meta()["colliders"]
    session = LiveSession(scene)
    v = serve_live(session, port=_free_port(), start=False)
    node, still = "/pliant/colliders/collider0", "/pliant/colliders/collider1"
    handle = next(h for h, p in v._handles if p.name == node)
    centre = scene.colliders.arrays(scene.model)["centre"]

    def check(frames: int) -> None:
        t = frames * scene.frame_dt
        assert session.frame == frames and session.t == pytest.approx(t, abs=1e-12)
        drawn = v.colliders[node]
        np.testing.assert_allclose(drawn, collider_points(moving, [t])[0], rtol=0, atol=1e-9)
        np.testing.assert_allclose(handle.vertices, drawn, rtol=0, atol=1e-6)
        c_t = np.asarray(moving["centre"]) + t * np.asarray(moving["velocity"])
        np.testing.assert_allclose(centre.numpy()[0], c_t, rtol=0, atol=1e-5)  # where the simulation has it
        np.testing.assert_array_equal(v.colliders[still], static["points"])

    try:
        check(0)
        for k in range(1, 4):
            assert v.run_frame()
            check(k)
        assert np.abs(v.colliders[node] - moving["points"]).max() > 0.02  # it moved and turned
        session.reset()  # what the reset button does
        v.show(session.x)
        check(0)
        np.testing.assert_allclose(v.colliders[node], moving["points"], rtol=0, atol=1e-12)
        assert v.run_frame()
        check(1)
    finally:
        v.stop()
