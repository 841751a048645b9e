"""Moving colliders inside the implicit step's energies (``ColliderPenalty``, ``BarrierContact``): the step
solves for the positions at its end, so the contact acts at the colliders' pose at the end of the step, the
barrier's lagged friction acts on the motion relative to the surface, and its minimiser starts from
positions clear of that pose.

Closed forms: a particle set down at rest on a plate moving at u accelerates at μ g until it reaches u, then
is carried at u; a plate rising at w carries a resting particle at w, on its surface (penetration m g / k
for the penalty); a sphere spinning about its centre keeps its distance field, so whatever it drags stays
outside it (ipctk judges the triangles).
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl
from tests.helpers import energy_fd_check

G = 9.81
DT = 1 / 600
R = 0.01  # particle radius [m]
M = 0.01  # particle mass [kg]


def _particle(at) -> pl.Model:
    b = pl.ModelBuilder(gravity=(0.0, -G, 0.0))
    b.add_particles([at], [M], radius=R)
    return b.finalize(device="cpu", dtype="float64")


def _contact(kind: str, colliders: pl.collision.Colliders) -> tuple[list, list]:
    """(energies, post-step handlers) of the penalty path or the barrier path, both with lagged friction
    (ForceSolver adds the colliders' motion handler)."""
    if kind == "penalty":
        return [pl.energies.ColliderPenalty(colliders, stiffness=1e4, friction=True)], []
    bar = pl.energies.BarrierContact(dhat=1e-3, kappa=50.0, ground=False, colliders=colliders, friction=True)
    return [bar], []


def _run(model, solver, steps: int, dt: float = DT):
    s0, s1 = model.state(), model.state()
    xs, vs = np.empty((steps, model.particle_count, 3)), np.empty((steps, model.particle_count, 3))
    for k in range(steps):
        solver.step(s0, s1, None, dt)
        s0, s1 = s1, s0
        xs[k], vs[k] = s0.particle_q.numpy(), s0.particle_qd.numpy()
    return dt * np.arange(1, steps + 1), xs, vs


def _solver(model, kind: str, colliders) -> pl.solvers.ForceSolver:
    energies, handlers = _contact(kind, colliders)
    integ = pl.integrators.BackwardEuler(newton_tol=1e-10)
    return pl.solvers.ForceSolver(model, [pl.energies.Gravity(), *energies], integ, collisions=handlers)


@pytest.mark.parametrize("kind", ["penalty", "barrier"])
@pytest.mark.parametrize("mu", [0.1, 1.0])
def test_a_moving_plate_carries_or_drags_a_particle_in_the_implicit_step(kind: str, mu: float):
    """A box plate moving at u = 0.5 m/s under BackwardEuler: μ = 1 carries the particle at u (1 %) after
    0.1 s; μ = 0.1 accelerates it at μ g (3 %) over the first 0.4 s. The plate advances by u t."""
    u = 0.5
    cols = pl.collision.Colliders()
    cols.add_box((0.0, -0.05, 0.0), (5.0, 0.05, 5.0), friction=mu, velocity=(u, 0.0, 0.0))
    y0 = R if kind == "penalty" else 5e-4  # the barrier acts on the point itself, inside d̂
    model = _particle((0.0, y0, 0.0))
    steps = 300
    ts, xs, vs = _run(model, _solver(model, kind, cols), steps)
    assert cols.arrays(model)["pos"].numpy()[0, 0] == pytest.approx(u * steps * DT, abs=1e-9)
    assert np.abs(xs[:, 0, 1] - y0).max() < 1e-3
    if mu > 0.5:
        assert vs[ts >= 0.1, 0, 0] == pytest.approx(u, rel=0.01)
        return
    w = (ts > 0.02) & (ts < 0.4)
    accel = np.polyfit(ts[w], vs[w, 0, 0], 1)[0]
    assert accel == pytest.approx(mu * G, rel=0.03)


@pytest.mark.parametrize("kind", ["penalty", "barrier"])
def test_a_rising_plate_is_met_at_its_end_pose(kind: str):
    """A plate rising at 0.5 m/s (0.83 mm per step, more than d̂ and 80 × m g / k): with the contact at the
    end pose the particle rides on it at its speed; penetration at most 2 m g / k for the penalty (after
    0.1 s: the plate starts at full speed under a particle at rest, an impact), and
    clear of the plate after every step for the barrier (its start is carried up with the plate)."""
    w = 0.5
    cols = pl.collision.Colliders()
    cols.add_box((0.0, -0.05, 0.0), (1.0, 0.05, 1.0), friction=0.5, velocity=(0.0, w, 0.0))
    y0 = R if kind == "penalty" else 5e-4
    model = _particle((0.0, y0, 0.0))
    ts, xs, vs = _run(model, _solver(model, kind, cols), 120)
    gap = xs[:, 0, 1] - w * ts  # height above the plate's top (which is at w t)
    if kind == "penalty":
        assert (R - gap[60:]).max() < 2 * M * G / 1e4  # after the start's impact has rung out
    else:
        assert gap.min() > 0.0 and gap.max() < 1e-3
    assert vs[-20:, 0, 1] == pytest.approx(w, rel=0.01)


def test_a_cloth_on_a_spinning_sphere_never_intersects_it():
    """A 9 × 9 cloth dropped onto a sphere (R = 0.3 m) spinning at 3 rad/s about z, barrier contact with
    friction, Δt = 1/60: ipctk finds no intersection between the cloth and the sphere (an inscribed mesh
    that turns with it) in any of 45 frames, and the cloth is dragged along the spin (−x)."""
    from tests.intersections import Part, grid_triangles, intersecting_frames, sphere_mesh

    rad, spin = 0.3, 3.0
    cols = pl.collision.Colliders()
    cols.add_sphere((0.0, 0.0, 0.0), rad, friction=0.8, angular_velocity=(0.0, 0.0, spin))
    b = pl.ModelBuilder(gravity=(0.0, -G, 0.0))
    b.add_cloth_grid(nx=8, ny=8, size=0.2, mass=0.02, stiffness=200.0, origin=(-0.1, rad + 0.004, -0.1))
    model = b.finalize(device="cpu", dtype="float64")
    bar = pl.energies.BarrierContact(dhat=2e-3, ground=False, colliders=cols, friction=True)
    energies = [*pl.energies.mass_spring(), bar]
    solver = pl.solvers.ForceSolver(model, energies, pl.integrators.BackwardEuler(newton_tol=1e-6))
    s0, s1 = model.state(), model.state()
    verts, faces = sphere_mesh((0.0, 0.0, 0.0), rad - 1e-3, subdivisions=3)  # chords: inside by < 1 mm
    cloth, ball = [], []
    for _ in range(45):
        solver.step(s0, s1, None, 1 / 60)
        s0, s1 = s1, s0
        cloth.append(s0.particle_q.numpy().copy())
        rot = cols.arrays(model)["rot"].numpy()[0]
        ball.append(verts @ rot.T)
        assert np.linalg.norm(cloth[-1], axis=1).min() > rad
    tris = np.asarray(model.tri_indices.numpy()).reshape(-1, 3)
    assert len(tris) == len(grid_triangles(8, 8))
    assert intersecting_frames([Part(tris, np.array(cloth)), Part(faces, np.array(ball))]) == []
    assert cloth[-1][:, 0].mean() < -0.02


def test_a_spinning_paddle_pushes_particles_without_intersection():
    """A box paddle (half-length 0.2 m) spinning at 3 rad/s about z, Δt = 1/60: its tips sweep 1 cm per
    step past particles 4 mm from its faces (no gravity). Barrier contact starts each step from the
    particles carried by the paddle where it reaches them, so every step ends with every particle outside
    the paddle at its end pose (signed distance > 0), and the paddle has pushed them round."""
    cols = pl.collision.Colliders()
    cols.add_box((0.0, 0.0, 0.0), (0.2, 0.02, 0.05), friction=0.2, angular_velocity=(0.0, 0.0, 3.0))
    xs = np.linspace(-0.18, 0.18, 7)
    pts = [[x, s * 0.024, 0.0] for x in xs for s in (1.0, -1.0)]
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles(pts, [M] * len(pts), radius=R)
    model = b.finalize(device="cpu", dtype="float64")
    bar = pl.energies.BarrierContact(dhat=5e-3, kappa=1.0, ground=False, colliders=cols)
    solver = pl.solvers.ForceSolver(model, [bar], pl.integrators.BackwardEuler(newton_tol=1e-8))
    s0, s1 = model.state(), model.state()
    for _ in range(30):
        solver.step(s0, s1, None, 1 / 60)
        s0, s1 = s1, s0
        phi, _ = cols.query(model, s0.particle_q)
        assert phi.min() > 0.0
    angle = np.arctan2(s0.particle_q.numpy()[:, 1], s0.particle_q.numpy()[:, 0])
    assert np.abs(np.sin(angle)).max() > 0.5  # turned well away from the x axis


def _moving_sphere(first, mu: float) -> tuple[pl.collision.Colliders, pl.Model]:
    cols = pl.collision.Colliders()
    spin = dict(velocity=(0.3, -0.2, 0.1), angular_velocity=(0.0, 2.0, 5.0))
    cols.add_sphere((0.0, 0.5, 0.0), 0.2, friction=mu, **spin)
    b = pl.ModelBuilder()
    b.add_particles([first, [0.2, 0.45, 0.3], [0.9, 0.5, 0.0], [0.02, 0.7035, 0.01]], 0.1, radius=0.01)
    return cols, b.finalize(device="cpu", dtype="float64")


def test_penalty_derivatives_and_pose_with_a_moving_collider():
    """After begin_step(Δt) the penalty acts on the sphere moved by v Δt (its value is that of a static
    sphere there, to 1e-12), and its gradient and Hessian, lagged friction included, match central
    differences (float64)."""
    h = 0.05
    cols, model = _moving_sphere([0.05, 0.31, 0.02], 0.3)  # the first inside
    e = pl.energies.ColliderPenalty(cols, stiffness=1e3, friction=True)
    x = model.particle_q_np.copy()
    x[0] += [0.003, -0.001, 0.001]  # slides relative to the surface
    v = wp.zeros(model.particle_count, dtype=wp.vec3d)
    g, g_fd, H, H_fd = energy_fd_check(model, e, x, eps=1e-7, begin=(model.particle_q, v, h))
    assert np.abs(g).max() > 0
    assert np.abs(g - g_fd).max() <= 1e-6 * np.abs(g_fd).max()
    assert np.abs(H - H_fd).max() <= 1e-5 * np.abs(H_fd).max()
    moved = pl.collision.Colliders()
    moved.add_sphere((0.3 * h, 0.5 - 0.2 * h, 0.1 * h), 0.2)
    bare = pl.energies.ColliderPenalty(cols, stiffness=1e3)  # the normal term alone
    bare.begin_step(model, model.particle_q, v, h)
    vals = []
    for energy in (bare, pl.energies.ColliderPenalty(moved, stiffness=1e3)):
        out = wp.zeros(1, dtype=wp.float64)
        energy.value(model, model.particle_q, out)
        vals.append(out.numpy()[0])
    assert vals[0] > 0 and vals[0] == pytest.approx(vals[1], abs=1e-12)
    assert cols.arrays(model)["pos"].numpy()[0] == pytest.approx((0.0, 0.5, 0.0))  # not moved yet


def test_barrier_derivatives_and_relative_friction_with_a_moving_collider():
    """Barrier and lagged friction against a moving, spinning sphere: gradient and Hessian match central
    differences (float64); a particle carried by the sphere's rigid motion feels no friction."""
    h = 0.02
    cols, model = _moving_sphere([0.0, 0.295, 0.01], 0.4)
    e = pl.energies.BarrierContact(dhat=0.01, kappa=50.0, ground=False, colliders=cols, friction=True)
    x = model.particle_q_np.copy()
    x[0] += [0.003, -0.001, 0.001]
    x[3] += [0.0002, 0.0, -0.0001]
    v = wp.zeros(model.particle_count, dtype=wp.vec3d)
    g, g_fd, H, H_fd = energy_fd_check(model, e, x, eps=1e-7, begin=(model.particle_q, v, h))
    assert np.abs(g - g_fd).max() <= 1e-6 * np.abs(g_fd).max()
    assert np.abs(H - H_fd).max() <= 1e-5 * np.abs(H_fd).max()
    # Carried: x = R(x_t − c) + c + v h, the material point's position at the end; only the normal
    # barrier acts then, so the gradient is along the end pose's normal.
    a = cols.arrays(model)
    c0, vel, om = a["centre"].numpy()[0], a["vel"].numpy()[0], a["omega"].numpy()[0]
    ang = np.linalg.norm(om) * h
    k = om / np.linalg.norm(om)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    Rm = np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K
    xt = model.particle_q_np
    carried = (xt - c0) @ Rm.T + c0 + vel * h
    out = wp.zeros(model.particle_count, dtype=wp.vec3d)
    e.gradient(model, wp.array(carried, dtype=wp.vec3d), out)
    g0 = out.numpy()[3]
    n = (carried[3] - (c0 + vel * h)) / np.linalg.norm(carried[3] - (c0 + vel * h))
    assert np.linalg.norm(g0) > 0
    assert np.linalg.norm(g0 - np.dot(g0, n) * n) <= 1e-9 * np.linalg.norm(g0)


def test_compliant_colliders_are_refused_by_the_energies():
    """A compliant collider's κ belongs to the post-step response: the penalty and the barrier say so."""
    cols = pl.collision.Colliders()
    cols.add_sphere((0.0, 0.0, 0.0), 1.0, stiffness=400.0)
    with pytest.raises(ValueError, match=r"ColliderPenalty: colliders \[0\] are compliant"):
        pl.energies.ColliderPenalty(cols)
    with pytest.raises(ValueError, match=r"BarrierContact: colliders \[0\] are compliant"):
        pl.energies.BarrierContact(ground=False, colliders=cols)


def test_a_barrier_scene_moves_its_colliders_after_each_step():
    """``[ground] contact = "barrier"`` takes the colliders out of the post-step handlers; with a moving
    sphere ForceSolver adds their motion handler, so the sphere rises by v t and the cloth stays outside
    it where it is after every step; the handler's ``reset`` (what ``Simulator.restart`` calls) puts it
    back."""
    from tests.test_barrier import BARRIER_SCENE

    text = BARRIER_SCENE.replace("radius = 0.27\n", "radius = 0.27\nvelocity = [0.0, 0.05, 0.0]\n")
    scene = pl.scene.build_scene(pl.scene.parse_scene(text))
    assert [type(c).__name__ for c in scene.solver.collisions] == ["ColliderMotion"]
    cols = scene.solver.collisions[0].colliders
    s0, s1 = scene.model.state(), scene.model.state()
    for k in range(1, 4):
        scene.solver.step(s0, s1, None, 0.1)
        s0, s1 = s1, s0
        centre = cols.arrays(scene.model)["pos"].numpy()[0]
        assert centre == pytest.approx((0.0, -0.25 + 0.005 * k, 0.0), abs=1e-6)  # a float32 scene
        assert (np.linalg.norm(s0.particle_q.numpy() - centre, axis=1) > 0.27).all()
    scene.solver.collisions[0].reset()
    assert cols.arrays(scene.model)["pos"].numpy()[0] == pytest.approx((0.0, -0.25, 0.0))


def test_a_resumed_barrier_run_continues_a_moving_collider_bit_for_bit(tmp_path):
    """The motion handler's checkpoint holds the pose: a barrier run on a moving plate, stopped after 2
    frames and resumed in a fresh simulator to 4, is the straight 4-frame run bit for bit."""

    def fresh():
        cols = pl.collision.Colliders()
        cols.add_box((0.0, -0.05, 0.0), (5.0, 0.05, 5.0), friction=0.5, velocity=(0.5, 0.0, 0.1))
        model = _particle((0.0, 5e-4, 0.0))
        return (
            pl.sim.Simulator(model, _solver(model, "barrier", cols), frame_dt=1 / 60, substeps=2),
            cols,
            model,
        )

    sim, _, _ = fresh()
    straight = sim.run(4, progress=False).x[-1]
    path = tmp_path / "ck.npz"
    sim, _, _ = fresh()
    sim.run(2, progress=False, checkpoint=path, checkpoint_every=1)
    sim, cols, model = fresh()
    resumed = sim.run(4, progress=False, checkpoint=path, resume=True).x[-1]
    np.testing.assert_array_equal(resumed, straight)
    assert cols.arrays(model)["pos"].numpy()[0, 0] == pytest.approx(0.5 * 4 / 60, abs=1e-12)
    assert straight[0, 0] > 0.005  # dragged along (μ g t²/2 = 0.011 m)
