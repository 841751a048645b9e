"""Kinematic colliders (``velocity=``, ``angular_velocity=``): moved rigidly every step, with friction and
restitution relative to the surface's velocity v + ω × (p − c).

Closed forms: a particle set down at rest on a plate moving at u slips under Coulomb friction, so it
accelerates at μ g until it reaches u (time u/(μ g)), then is carried at u; a particle on top of a spinning
sphere (surface speed ωR) is dragged the same way, and once it sticks it turns with the sphere at ω.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl

G = 9.81
FAMILIES = ("symplectic_euler", "backward_euler", "fast_mass_spring", "xpbd")
DT = 1 / 600


def _solver(family: str, model: pl.Model, collisions: list):
    gravity = [pl.energies.Gravity()]
    if family == "symplectic_euler":
        return pl.solvers.ForceSolver(model, gravity, pl.integrators.SymplecticEuler(), collisions=collisions)
    if family == "backward_euler":
        integ = pl.integrators.BackwardEuler(newton_tol=1e-12)
        return pl.solvers.ForceSolver(model, gravity, integ, collisions=collisions)
    if family == "fast_mass_spring":
        return pl.solvers.FastMassSpring(model, collisions=collisions)
    return pl.solvers.XPBD(model, iterations=2, collisions=collisions)


def _particle(at, r: float = 0.01) -> pl.Model:
    b = pl.ModelBuilder(gravity=(0.0, -G, 0.0))
    b.add_particles([at], [0.01], radius=r)
    return b.finalize(device="cpu", dtype="float64")


def _run(model: pl.Model, solver, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    s0, s1 = model.state(), model.state()
    xs, vs = np.empty((steps, 3)), np.empty((steps, 3))
    for k in range(steps):
        solver.step(s0, s1, None, DT)
        s0, s1 = s1, s0
        xs[k], vs[k] = s0.particle_q.numpy()[0], s0.particle_qd.numpy()[0]
    return DT * np.arange(1, steps + 1), xs, vs


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("mu", [0.1, 1.0])
def test_a_moving_plate_carries_a_particle_or_slips_under_it(family: str, mu: float):
    """A box plate moving at u = 0.5 m/s: μ = 0.1 accelerates the particle at μ g (2 %) over the first
    0.4 s; μ = 1 brings it to u within 0.06 s (u/(μg) = 0.051 s), and then it rides along: velocity u to
    1e-3 m/s and a fixed offset to the plate (0.1 mm over the last 0.5 s). The plate's centre advances
    by u t exactly."""
    u, r = 0.5, 0.01
    colliders = pl.collision.Colliders()
    colliders.add_box((0.0, -0.05, 0.0), (5.0, 0.05, 5.0), friction=mu, velocity=(u, 0.0, 0.0))
    model = _particle((0.0, r, 0.0), r)
    solver = _solver(family, model, [colliders])
    steps = 600
    ts, xs, vs = _run(model, solver, steps)
    centre = colliders.arrays(model)["pos"].numpy()[0]
    assert centre == pytest.approx((u * steps * DT, -0.05, 0.0), abs=1e-9)
    assert np.abs(xs[:, 1] - r).max() < 1e-4
    if mu < 0.5:
        w = (ts > 0.02) & (ts < 0.4)
        accel = np.polyfit(ts[w], vs[w, 0], 1)[0]
        assert accel == pytest.approx(mu * G, rel=0.02)
        return
    assert vs[ts >= 0.06, 0] == pytest.approx(u, abs=1e-3)
    offset = xs[:, 0] - u * ts
    late = offset[ts >= 0.5]
    assert late.max() - late.min() < 1e-4


@pytest.mark.parametrize("family", ["symplectic_euler", "xpbd"])
def test_a_spinning_sphere_drags_a_resting_particle(family: str):
    """On top of a sphere (R = 5 m) spinning at ω = 0.2 rad/s about z (surface speed ωR = 1 m/s along −x):
    with μ = 0.2 the particle slips, dragged at μ g (3 % at 0.1 s, where the slope it has reached adds
    1 %); with μ = 1 it sticks within 0.15 s and then turns with the sphere at ω (1 %), on its surface."""
    R, r, w = 5.0, 0.01, 0.2
    for mu in (0.2, 1.0):
        colliders = pl.collision.Colliders()
        colliders.add_sphere((0.0, 0.0, 0.0), R, friction=mu, angular_velocity=(0.0, 0.0, w))
        model = _particle((0.0, R + r, 0.0), r)
        ts, xs, vs = _run(model, _solver(family, model, [colliders]), 180)
        if mu < 0.5:
            k = int(round(0.1 / DT)) - 1
            assert -vs[k, 0] == pytest.approx(mu * G * ts[k], rel=0.03)
            continue
        angle = np.unwrap(np.arctan2(xs[:, 1], xs[:, 0]))
        late = ts >= 0.15
        rate = np.polyfit(ts[late], angle[late], 1)[0]
        assert rate == pytest.approx(w, rel=0.01)
        assert np.linalg.norm(xs[late], axis=1) == pytest.approx(R + r, abs=1e-4)


def test_a_rising_plate_lifts_a_particle_and_reset_puts_it_back():
    """A plate moving up at 0.3 m/s carries a resting particle with it (on its surface, at its speed);
    ``reset()`` returns the plate to where it was added."""
    r = 0.01
    colliders = pl.collision.Colliders()
    colliders.add_box((0.0, -0.05, 0.0), (1.0, 0.05, 1.0), velocity=(0.0, 0.3, 0.0))
    model = _particle((0.0, r, 0.0), r)
    ts, xs, vs = _run(model, _solver("symplectic_euler", model, [colliders]), 300)
    assert xs[-1, 1] == pytest.approx(r + 0.3 * ts[-1], abs=1e-9)
    assert vs[-1, 1] == pytest.approx(0.3, abs=1e-9)
    colliders.reset()
    assert colliders.arrays(model)["pos"].numpy()[0] == pytest.approx((0.0, -0.05, 0.0))


def test_moving_colliders_refuse_a_recorded_step():
    """A moving collider's pose is updated in place: a recorded (out-of-place) step says so."""
    colliders = pl.collision.Colliders()
    colliders.add_sphere((0.0, 0.0, 0.0), 1.0, velocity=(1.0, 0.0, 0.0))
    model = _particle((0.0, 1.0, 0.0))
    x, v = model.particle_q, model.particle_qd
    with pytest.raises(pl.diff.GradientError, match="moving colliders"):
        colliders.apply_out(model, x, v, wp.clone(x), wp.clone(v), DT)


@pytest.mark.parametrize("graph", [False, True])
def test_a_restarted_simulator_replays_a_moving_collider_bit_for_bit(graph: bool):
    """``Simulator.restart()`` puts a moving collider back (in place, so a captured frame graph still reads
    its arrays): the second run is the first, bit for bit, and the box has moved 3 frames' worth."""
    colliders = pl.collision.Colliders()
    colliders.add_box((0.0, -0.05, 0.0), (5.0, 0.05, 5.0), friction=1.0, velocity=(0.5, 0.0, 0.0))
    model = _particle((0.0, 0.01, 0.0))
    solver = _solver("symplectic_euler", model, [colliders])
    sim = pl.sim.Simulator(model, solver, frame_dt=1 / 60, substeps=10, graph=graph)
    runs = []
    for _ in range(2):
        for _ in range(3):
            sim.step_frame()
        runs.append(sim.state_0.particle_q.numpy().copy())
        assert colliders.arrays(model)["pos"].numpy()[0, 0] == pytest.approx(0.5 * 3 / 60, abs=1e-12)
        sim.restart()
    np.testing.assert_array_equal(runs[0], runs[1])
    assert runs[0][0, 0] > 0.01  # carried along


def test_a_resumed_run_continues_a_moving_collider_bit_for_bit(tmp_path):
    """The checkpoint holds a moving collider's pose (``solver_handler0_pose_*``): 3 frames, stop, resume
    in a fresh simulator to 6 frames gives the straight 6-frame run bit for bit."""

    def fresh():
        colliders = pl.collision.Colliders()
        colliders.add_box((0.0, -0.05, 0.0), (5.0, 0.05, 5.0), friction=0.2, velocity=(0.5, 0.0, 0.1))
        model = _particle((0.0, 0.01, 0.0))
        solver = _solver("symplectic_euler", model, [colliders])
        return pl.sim.Simulator(model, solver, frame_dt=1 / 60, substeps=10), colliders, model

    sim, _, _ = fresh()
    straight = sim.run(6, progress=False).x[-1]
    path = tmp_path / "ck.npz"
    sim, _, _ = fresh()
    sim.run(3, progress=False, checkpoint=path, checkpoint_every=1)
    sim, colliders, model = fresh()
    resumed = sim.run(6, progress=False, checkpoint=path, resume=True).x[-1]
    np.testing.assert_array_equal(resumed, straight)
    assert colliders.arrays(model)["pos"].numpy()[0, 0] == pytest.approx(0.05, abs=1e-12)


@pytest.mark.parametrize("kind", tuple(pl.collision.CONTACT_KINDS))
def test_every_kind_moves_rigidly(kind: str):
    """Each kind's floor() given v and ω, advanced 100 steps of Δt: its centre at c₀ + v t and its
    geometry rotated by ω t about it (Rodrigues), to 1e-12 — points, directions and rotations alike."""
    from scipy.spatial.transform import Rotation

    v, w, n, dt = np.array([0.3, -0.1, 0.2]), np.array([0.2, 0.5, -0.4]), 100, 1e-3
    colliders = pl.collision.Colliders()
    colliders.add(kind, **pl.collision.CONTACT_KINDS[kind].floor(), velocity=v, angular_velocity=w)
    model = _particle((100.0, 100.0, 100.0))  # far from everything: only the pose changes
    a = colliders.arrays(model)
    start = {k: a[k].numpy()[0].copy() for k in ("pos", "aux", "rot", "centre")}
    s0, s1 = model.state(), model.state()
    for _ in range(n):
        colliders.apply(model, s0, s1, dt)
    R = Rotation.from_rotvec(w * n * dt).as_matrix()
    c1 = start["centre"] + v * n * dt
    close = dict(rel=1e-13, abs=1e-12)  # the 10 km radii of floor() put some points 1e4 m away
    assert a["centre"].numpy()[0] == pytest.approx(c1, **close)
    assert a["pos"].numpy()[0] == pytest.approx(c1 + R @ (start["pos"] - start["centre"]), **close)
    np.testing.assert_allclose(a["rot"].numpy()[0], R @ start["rot"], atol=1e-12)
    motion = pl.collision.CONTACT_KINDS[kind].aux_motion
    aux = {0: start["aux"], 1: c1 + R @ (start["aux"] - start["centre"]), 2: R @ start["aux"]}[motion]
    assert a["aux"].numpy()[0] == pytest.approx(aux, **close)


def test_a_turntable_box_carries_a_particle_round():
    """A box spinning at ω = 1 rad/s about the vertical through its centre (μ = 1): a particle resting
    ρ = 0.2 m from the axis turns with it at ω (1 %): the surface velocity ω × (p − c) of a rotating box.
    Its radius shrinks by the first-order step's Δt ω² ρ / 2 per second (0.17 mm over 1 s at Δt = 1/600 s,
    checked to 20 %): each step moves it along the velocity it had, then friction turns that velocity."""
    colliders = pl.collision.Colliders()
    colliders.add_box((0.0, -0.05, 0.0), (1.0, 0.05, 1.0), friction=1.0, angular_velocity=(0.0, 1.0, 0.0))
    model = _particle((0.2, 0.01, 0.0))
    ts, xs, vs = _run(model, _solver("symplectic_euler", model, [colliders]), 600)
    angle = np.unwrap(np.arctan2(-xs[:, 2], xs[:, 0]))
    late = ts >= 0.2
    assert np.polyfit(ts[late], angle[late], 1)[0] == pytest.approx(1.0, rel=0.01)
    drift = 0.2 - np.hypot(xs[-1, 0], xs[-1, 2])
    assert drift == pytest.approx(DT * 0.2 / 2 * ts[-1], rel=0.2)


def test_a_moving_collider_is_drawn_where_it_is():
    """A scene's spinning, sliding box is drawn at each frame's pose: its drawn corners at the last frame
    are the device pose's, pos(t) + rot(t) · (its corners in its own frame), to 1e-9 m, and the trajectory
    meta carries the motion that :func:`pl.render.collider_points` poses it with."""
    raw = pl.scene.load_scene("points_push").model_dump()
    raw["colliders"] = [
        dict(kind="box", center=[3, 1, 0], half_extents=[0.2, 0.1, 0.3], velocity=[0.4, 0, -0.2],
             angular_velocity=[0.3, 1.0, 0.5])
    ]  # fmt: skip
    raw["scene"]["frames"] = 5
    scene = pl.scene.build_scene(pl.scene.SceneConfig.model_validate(raw), device="cpu", dtype="float64")
    traj = scene.simulator().run(frames=5, progress=False)
    start, faces = scene.static_meshes[0]
    local = start - np.array([3.0, 1.0, 0.0])  # axis aligned at t = 0
    xr, _, _ = scene.render_mesh(traj.x, traj.faces, traj.t)
    a = scene.colliders.arrays(scene.model)
    pose = a["pos"].numpy()[0] + local @ a["rot"].numpy()[0].T
    assert np.abs(pose - start).max() > 0.05  # it has moved
    np.testing.assert_allclose(xr[-1, -len(start) :], pose, atol=1e-9)
    np.testing.assert_array_equal(scene.render_mesh(traj.x, traj.faces)[0][-1, -len(start) :], start)
    meta = scene.trajectory_meta()["colliders"][0]
    assert meta["velocity"] == [0.4, 0.0, -0.2] and meta["centre"] == [3.0, 1.0, 0.0]
