"""XPBD/PBD solver loop: pendulum, iteration-independent stretch, convergence, contacts, rigid bodies."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant.constraints as pc
from pliant.model import ModelBuilder
from pliant.solvers import PBD, XPBD

wp.init()
wp.config.quiet = True

G = 9.81


def run(model, solver, steps: int, dt: float, control=None, each=None):
    """Step ``steps`` times from the model's initial state; ``each(state)`` after every step."""
    s0, s1 = model.state(), model.state()
    for _ in range(steps):
        solver.step(s0, s1, control, dt)
        s0, s1 = s1, s0
        if each is not None:
            each(s0)
    return s0


def pendulum_model(L: float, theta0: float):
    b = ModelBuilder(gravity=(0.0, -G, 0.0))
    b.add_particles([[0.0, 0.0, 0.0], [L * np.sin(theta0), -L * np.cos(theta0), 0.0]], [1.0, 0.5])
    b.pin([0])
    return b.finalize(device="cpu", dtype="float64")


def test_pendulum_small_angle_period():
    """A pendulum of one zero-compliance distance constraint swings with period 2π√(L/g) within 1%."""
    L, dt = 1.0, 5e-4
    model = pendulum_model(L, 0.05)
    solver = XPBD(model, iterations=1, constraints=[pc.Distance([[0, 1]], compliance=0.0)])
    xs = []
    run(model, solver, int(4.5 / dt), dt, each=lambda s: xs.append(s.particle_q.numpy()[1, 0]))
    x = np.asarray(xs)
    t = dt * np.arange(1, len(x) + 1)
    k = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))  # upward zero crossings, interpolated
    crossings = t[k] + dt * (-x[k]) / (x[k + 1] - x[k])
    period = np.diff(crossings).mean()
    expected = 2 * np.pi * np.sqrt(L / G)
    assert len(crossings) >= 2
    assert abs(period - expected) / expected < 0.01, f"period {period:.5f} s, expected {expected:.5f} s"


def chain_model(n: int = 4, m: float = 0.1, seg: float = 0.1, k: float = 100.0):
    b = ModelBuilder(gravity=(0.0, -G, 0.0))
    b.add_rope(
        n_segments=n, length=n * seg, mass=m * (n + 1), stiffness=k, start=(0, 0, 0), direction=(0, -1, 0)
    )
    return b.finalize(device="cpu", dtype="float64")


@pytest.mark.parametrize("schedule", ["coloring", "jacobi"])
def test_hanging_chain_static_stretch_independent_of_iterations_and_dt(schedule):
    """XPBD's static stretch of a hanging chain is Σ m g/k within 2% for 5, 20, 100 iterations and two Δt.

    Here Δt √(k/m) ≤ 0.32, where a few sweeps converge each step's solve (see the next test for when not).
    """
    n, m, k = 4, 0.1, 100.0
    model = chain_model(n, m, 0.1, k)
    expected = m * G * sum(range(1, n + 1)) / k  # link j carries the weight of the particles below it
    stretches = {}
    for dt in (1e-2, 2e-3):
        for it in (5, 20, 100):
            solver = XPBD(model, iterations=it, schedule=schedule, damping=8.0)
            s = run(model, solver, int(3.0 / dt), dt)
            y = s.particle_q.numpy()[:, 1]
            stretches[(dt, it)] = -y.min() - n * 0.1
    for key, st in stretches.items():
        assert abs(st - expected) / expected < 0.02, (
            f"{schedule} {key}: stretch {st:.5f} m, expected {expected:.5f}"
        )


def _top_link_stretch(model, schedule: str, iterations: int, substeps: int) -> float:
    """Stretch [m] of the top link after 2 s hanging at ``substeps`` XPBD steps per 1/60 s frame."""
    dt = 1.0 / 60.0 / substeps
    solver = XPBD(model, iterations=iterations, schedule=schedule, damping=8.0)
    y = run(model, solver, int(round(2.0 / dt)), dt).particle_q.numpy()[:, 1]
    return (y[0] - y[1]) - 0.1


def test_static_stretch_depends_on_iterations_unless_substeps_make_each_solve_converge():
    """What holds (docs/design.md, "XPBD schedules"): the converged static stretch is exact under both
    schedules, but λ restarts from 0 every step, so a truncated solve settles over-stretched when
    Δt √(k/m) is not small. 10-link chain, m = 0.1 kg, k = 1000 N/m (Δt √(k/m) = 1.67 at 1/60 s): top link
    exact 9.81 mm; one step per frame gives 17.4 mm at 5 Jacobi iterations (11.5 mm colouring) and the
    exact value at 100; 4 substeps bring 5 iterations within 1%, 20 substeps one iteration within 2%."""
    model = chain_model(10, 0.1, 0.1, 1000.0)
    exact = 10 * 0.1 * G / 1000.0
    rel = {
        (sched, it, sub): _top_link_stretch(model, sched, it, sub) / exact - 1.0
        for sched, it, sub in [
            ("jacobi", 5, 1),
            ("jacobi", 100, 1),
            ("coloring", 5, 1),
            ("coloring", 100, 1),
            ("jacobi", 5, 4),
            ("coloring", 5, 4),
            ("jacobi", 1, 20),
            ("coloring", 1, 20),
        ]
    }
    assert rel[("jacobi", 5, 1)] > 0.5 and rel[("coloring", 5, 1)] > 0.1, rel  # the dependence is real
    assert abs(rel[("jacobi", 100, 1)]) < 0.005 and abs(rel[("coloring", 100, 1)]) < 0.005, rel
    for key in [("jacobi", 5, 4), ("coloring", 5, 4)]:
        assert abs(rel[key]) < 0.01, (key, rel[key])
    for key in [("jacobi", 1, 20), ("coloring", 1, 20)]:
        assert abs(rel[key]) < 0.02, (key, rel[key])


def cloth_model(
    n: int = 12, *, height: float = 0.0, pin: str = "top-corners", ground: bool = False, dtype="float64"
):
    b = ModelBuilder(gravity=(0.0, -G, 0.0))
    b.add_cloth_grid(
        nx=n, ny=n, size=0.5, mass=0.1, stiffness=200.0, origin=(-0.25, height, -0.25), plane="xz", pin=pin
    )
    if ground:
        b.add_ground(0.0, friction=0.4)
    return b.finalize(device="cpu", dtype=dtype)


@pytest.mark.parametrize("schedule", ["coloring", "jacobi"])
def test_residual_falls_as_iterations_grow(schedule):
    """One step from a swinging cloth: the residual |C + α̃λ| falls as iterations grow (both schedules)."""
    model = cloth_model(12)
    warm = XPBD(model, iterations=5, schedule="coloring")
    s = run(model, warm, 20, 1e-2)
    residuals = []
    for it in (1, 4, 16, 64, 256):
        solver = XPBD(model, iterations=it, schedule=schedule)
        out = model.state()
        solver.step(s, out, None, 1e-2)
        residuals.append(solver.residual())
    assert all(b < a for a, b in zip(residuals, residuals[1:])), residuals
    assert residuals[-1] < 0.5 * residuals[0], residuals


@pytest.mark.parametrize("schedule", ["coloring", "jacobi"])
def test_tolerance_stops_the_sweeps_once_the_residual_is_below_it(schedule):
    """With a tolerance a step stops sweeping once the RMS residual |C + α̃λ| reaches it: the residual is
    then within the tolerance, a tighter tolerance takes more sweeps, and the positions equal those of a
    fixed count of the sweeps it ran (the check only reads)."""
    model = cloth_model(12)
    s = run(model, XPBD(model, iterations=5, schedule="coloring"), 20, 1e-2)
    fixed = XPBD(model, iterations=1, schedule=schedule)
    fixed.step(s, model.state(), None, 1e-2)
    # One sweep leaves this much; Jacobi converges far slower than Gauss–Seidel colouring.
    loose_tol = (0.3 if schedule == "coloring" else 0.7) * fixed.residual()
    counts = []
    for tol in (loose_tol, (0.1 if schedule == "coloring" else 0.6) * loose_tol):
        solver = XPBD(model, iterations=400, schedule=schedule, tolerance=tol, check_every=2)
        out = model.state()
        solver.step(s, out, None, 1e-2)
        assert solver.last_iterations < 400, "the cap was reached: the test would not test the stop"
        assert solver.residual() <= tol
        counts.append(solver.last_iterations)
        same = XPBD(model, iterations=solver.last_iterations, schedule=schedule)
        ref = model.state()
        same.step(s, ref, None, 1e-2)
        np.testing.assert_array_equal(out.particle_q.numpy(), ref.particle_q.numpy())
    assert counts[1] > counts[0] >= 2, counts


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize(("iterations", "every"), [(9, 2), (12, 4), (5, 5)])
def test_tolerance_stops_where_the_host_loop_stopped(iterations, every, dtype):
    """The device-side test (a flag, ``wp.capture_while``) stops at the sweep the former host loop did:
    the first multiple of ``check_every`` below ``iterations`` whose residual is at most the tolerance,
    else the cap (the last ``iterations mod check_every`` sweeps unchecked). The reference is independent
    of the loop: ``residual()`` read on the host after a fixed count of k sweeps, for every k, and a
    tolerance equal to one of those residuals checks the ≤ at its boundary. The positions equal the
    fixed-count run's bit for bit and the device counts every sweep."""
    model = cloth_model(8, dtype=dtype)
    s = run(model, XPBD(model, iterations=5, schedule="coloring"), 10, 1e-2)
    res, xs = {}, {}
    for k in range(1, iterations + 1):
        fixed = XPBD(model, iterations=k, schedule="jacobi")
        out = model.state()
        fixed.step(s, out, None, 1e-2)
        res[k], xs[k] = fixed.residual(), out.particle_q.numpy()
    checked = list(range(every, iterations, every))
    tols = [res[k] for k in checked] + [0.5 * min(res.values())]  # the last one: nothing converges
    solver = XPBD(model, iterations=iterations, schedule="jacobi", check_every=every)
    total = 0
    for tol in tols:
        expected = next((k for k in checked if res[k] <= tol), iterations)
        solver.tolerance = tol
        out = model.state()
        solver.step(s, out, None, 1e-2)
        assert solver.last_iterations == expected, (tol, res)
        np.testing.assert_array_equal(out.particle_q.numpy(), xs[expected])
        total += expected
    assert solver.sweep_counts() == (len(tols), total)
    if checked:  # the Jacobi residual falls with each sweep here, so the cases differ
        assert len({next((k for k in checked if res[k] <= t), iterations) for t in tols}) == len(tols)


def test_tolerance_steps_replay_their_recorded_launches():
    """Repeated steps with a tolerance replay their recorded launches (``replay``), the loop bodies too:
    bit for bit the steps launched afresh, with the same sweep count per step although it changes from
    step to step (2 while the cloth barely moves, so the loop body first runs, and is recorded, in a
    replayed step; up to the cap of 30, where the unchecked last sweeps run)."""
    model = cloth_model(8)
    runs = []
    for replay in (True, False):
        solver = XPBD(model, iterations=30, tolerance=1e-3, check_every=2)
        solver.replay = replay
        counts: list[int] = []
        s = run(model, solver, 12, 1e-2, each=lambda _, sv=solver, c=counts: c.append(sv.last_iterations))
        runs.append((s.particle_q.numpy(), counts, len(solver._plans)))
    (x, counts, plans), (x_direct, counts_direct, no_plans) = runs
    np.testing.assert_array_equal(x, x_direct)
    assert counts == counts_direct
    assert counts[0] == 2 and counts[-1] == 30 and len(set(counts)) >= 3, counts
    assert plans == 2 and no_plans == 0  # one plan per ping-pong order of the states


def test_tolerance_is_refused_where_a_fixed_count_is_needed():
    model = cloth_model(4)
    with pytest.raises(ValueError, match="PBD"):
        PBD(model, tolerance=1e-3)
    with pytest.raises(ValueError, match="> 0"):
        XPBD(model, tolerance=0.0)
    b = ModelBuilder()
    b.add_cloth_grid(nx=3, ny=3, size=0.1, mass=0.1, stiffness=10.0)
    with pytest.raises(ValueError, match="requires_grad"):
        XPBD(b.finalize(device="cpu", requires_grad=True), tolerance=1e-3)


def test_pinned_particles_never_move_and_pbd_runs():
    """Pinned corners stay exactly in place under XPBD (both schedules) and PBD; the cloth stays finite."""
    model = cloth_model(8)
    pinned = model.particle_inv_mass.numpy() == 0
    x0 = model.particle_q.numpy()[pinned]
    for solver in (
        XPBD(model, iterations=3, schedule="jacobi"),
        XPBD(model, iterations=3, schedule="coloring"),
        PBD(model, iterations=3, stiffness=0.8),
    ):
        s = run(model, solver, 30, 1 / 120)
        x = s.particle_q.numpy()
        assert np.all(np.isfinite(x))
        np.testing.assert_array_equal(x[pinned], x0)
        assert x[:, 1].min() < -0.05  # it fell


def test_ground_no_particle_below_after_any_step():
    """A cloth dropped on the ground: after every step every particle is at or above y = r (1e-9)."""
    model = cloth_model(8, height=0.2, pin="none", ground=True)
    r = model.particle_radius.numpy()
    worst = []
    solver = XPBD(model, iterations=4, schedule="coloring")
    run(model, solver, 80, 1 / 120, each=lambda s: worst.append(np.min(s.particle_q.numpy()[:, 1] - r)))
    assert min(worst) > -1e-9, f"penetration {min(worst):.3g} m"
    # It came to rest on the ground (restitution 0): the last state lies on the plane.
    assert abs(worst[-1]) < 1e-6


def _cloth_over_obstacle(schedule: str):
    """A 0.5 m cloth falling onto a pinned 0.3 m square sheet (two layers of one model's triangles)."""
    from pliant.geometry import cloth_grid

    b = ModelBuilder(gravity=(0.0, -G, 0.0))
    table = cloth_grid(3, 3, size=0.3, origin=(-0.15, 0.0, -0.15), plane="xz")
    first = b.add_particles(table.points, 0.01)
    b.add_triangles(table.triangles + first)
    b.pin(np.arange(first, first + len(table.points)))
    b.add_cloth_grid(
        nx=10, ny=10, size=0.5, mass=0.05, stiffness=100.0, origin=(-0.25, 0.03, -0.25), plane="xz"
    )
    model = b.finalize(device="cpu", dtype="float64")
    contact = pc.PointTriangleCollision(thickness=0.01)
    solver = XPBD(model, iterations=5, schedule=schedule, constraints=[pc.Distance(), contact])
    return model, solver, contact, first + len(table.points)


@pytest.mark.parametrize("schedule", ["coloring", "jacobi"])
def test_no_particle_ends_inside_a_triangle_it_collided_with(schedule):
    """Cloth dropped on a triangle mesh: no contact ends inside its triangle (C > −0.05 h), no tunnel.

    C = s(q − x1)·n̂ − h < −h would put q on the wrong side; the averaged (Jacobi) contact sweeps leave at
    most a sliver of the thickness layer h unresolved.
    """
    model, solver, contact, cloth_start = _cloth_over_obstacle(schedule)
    worst, touched, tunnels = [], [], []
    prev = [model.particle_q.numpy()[cloth_start:]]

    def check(s):
        worst.append(contact.min_value(s.particle_q))
        touched.append(int(contact.contact_count.numpy()[0]))
        x = s.particle_q.numpy()[cloth_start:]
        # Crossing the obstacle's plane inside its footprint within one step is a tunnel.
        inside = np.all(np.abs(x[:, [0, 2]]) < 0.15, axis=1) & np.all(
            np.abs(prev[0][:, [0, 2]]) < 0.15, axis=1
        )
        tunnels.append(int(np.sum(inside & (prev[0][:, 1] > 0) & (x[:, 1] < 0))))
        prev[0] = x

    run(model, solver, 60, 1 / 240, each=check)
    assert max(touched) > 0, "the cloth never reached the obstacle"
    assert not contact.overflow
    assert min(worst) > -0.05 * contact.thickness, f"deepest contact violation {min(worst):.3g} m"
    assert sum(tunnels) == 0, f"{sum(tunnels)} particle crossings through the obstacle"


def test_particle_collision_separates_spheres():
    """Two particles pushed together end a step at distance ≥ r_i + r_j (1e-9), momentum conserved."""
    b = ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles(
        [[0.0, 0.0, 0.0], [0.05, 0.0, 0.0]], [1.0, 3.0], velocities=[[1, 0, 0], [-1, 0, 0]], radius=0.04
    )
    model = b.finalize(device="cpu", dtype="float64")
    solver = XPBD(model, iterations=2, constraints=[pc.ParticleCollision()])
    s = run(model, solver, 1, 1e-2)
    x, v = s.particle_q.numpy(), s.particle_qd.numpy()
    assert np.linalg.norm(x[0] - x[1]) >= 0.08 - 1e-9
    np.testing.assert_allclose(1.0 * v[0] + 3.0 * v[1], [-2.0, 0.0, 0.0], atol=1e-9)


def _rigid_cluster(dtype: str = "float64"):
    rng = np.random.default_rng(4)
    pts = rng.uniform(-0.1, 0.1, size=(12, 3)) + [0.0, 1.0, 0.0]
    m = rng.uniform(0.05, 0.2, 12)
    com = m @ pts / m.sum()
    v0, w0 = np.array([1.0, 2.0, 0.5]), np.array([3.0, -5.0, 8.0])
    vel = v0 + np.cross(w0, pts - com)
    b = ModelBuilder(gravity=(0.0, -G, 0.0))
    b.add_particles(pts, m, velocities=vel)
    return b.finalize(device="cpu", dtype=dtype), pts, m, v0, w0


def test_rigid_shape_matching_keeps_pairwise_distances():
    """Shape matching with k_S = 1 keeps every pairwise distance of a thrown spinning cluster to 1e-5."""
    model, pts, m, v0, _ = _rigid_cluster()
    solver = XPBD(model, iterations=1, constraints=[pc.ShapeMatching(stiffness=1.0)])
    d0 = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    worst = []
    dt, steps = 1e-2, 60
    s = run(
        model,
        solver,
        steps,
        dt,
        each=lambda s: worst.append(
            np.abs(
                np.linalg.norm(s.particle_q.numpy()[:, None] - s.particle_q.numpy()[None], axis=-1) - d0
            ).max()
        ),
    )
    assert max(worst) < 1e-5, f"pairwise distance drift {max(worst):.3g} m"
    # The centre of mass follows the ballistic parabola of symplectic Euler.
    t = dt * steps
    com = m @ s.particle_q.numpy() / m.sum()
    expected = m @ pts / m.sum() + v0 * t + 0.5 * np.array([0, -G, 0]) * t * (t + dt)
    np.testing.assert_allclose(com, expected, atol=1e-9)


def test_oriented_particles_follow_cluster_rotation():
    """Oriented particles: each orientation is the cluster's rotation, ω the body's angular velocity (2%)."""
    model, pts, _, _, _ = _rigid_cluster()
    sm = pc.ShapeMatching(stiffness=1.0, radii=np.full(model.particle_count, 0.02))
    solver = XPBD(model, iterations=1, constraints=[sm])
    s = run(model, solver, 20, 1e-2)
    q = sm.orientation.numpy()
    x = s.particle_q.numpy()
    # The rotation that maps the rest shape to the current one, from the first three particles' frame.
    for k in range(model.particle_count):
        R = np.array(wp.quat_to_matrix(wp.quatd(*q[k]))).reshape(3, 3)
        np.testing.assert_allclose((pts - pts[0]) @ R.T, x - x[0], atol=1e-9)
    # Their angular velocity is the body's: L = I ω about the centre of mass, from the particle velocities.
    m, v = model.particle_mass_np, s.particle_qd.numpy()
    c = m @ x / m.sum()
    r = x - c
    L = (m[:, None] * np.cross(r, v - m @ v / m.sum())).sum(axis=0)
    I = np.eye(3) * np.sum(m * np.sum(r * r, axis=1)) - (r * m[:, None]).T @ r
    w = sm.angular_velocity.numpy()
    np.testing.assert_allclose(w, np.tile(np.linalg.solve(I, L), (len(w), 1)), rtol=0.02, atol=0.02)


def test_rigid_body_solver_keeps_shape_and_momenta():
    """RigidBodySolver: pairwise distances exact (1e-9), COM on the parabola, |L| about COM kept to 1e-3."""
    from pliant.solvers import RigidBodySolver

    model, pts, m, v0, _ = _rigid_cluster()
    solver = RigidBodySolver(model)
    d0 = np.linalg.norm(pts[:, None] - pts[None], axis=-1)

    def ang_mom(s):
        x, v = s.particle_q.numpy(), s.particle_qd.numpy()
        c = m @ x / m.sum()
        return (m[:, None] * np.cross(x - c, v - m @ v / m.sum())).sum(axis=0)

    L0 = ang_mom(model.state())
    dt, steps = 1e-3, 300
    s = run(model, solver, steps, dt)
    x = s.particle_q.numpy()
    assert np.abs(np.linalg.norm(x[:, None] - x[None], axis=-1) - d0).max() < 1e-9
    t = dt * steps
    expected = m @ pts / m.sum() + v0 * t + 0.5 * np.array([0, -G, 0]) * t * (t + dt)
    np.testing.assert_allclose(m @ x / m.sum(), expected, atol=1e-9)
    L = ang_mom(s)
    assert np.linalg.norm(L - L0) < 1e-3 * np.linalg.norm(L0), (L, L0)


def test_rigid_body_solver_agrees_with_rigid_shape_matching():
    """RigidBodySolver and XPBD shape matching (k_S = 1) agree to first order: the gap halves with Δt."""
    from pliant.solvers import RigidBodySolver

    model, *_ = _rigid_cluster()
    gaps = []
    for dt in (1e-3, 5e-4):
        steps = int(round(0.3 / dt))
        a = run(model, RigidBodySolver(model), steps, dt).particle_q.numpy()
        b = run(model, XPBD(model, iterations=1, constraints=[pc.ShapeMatching(stiffness=1.0)]), steps, dt)
        gaps.append(np.abs(a - b.particle_q.numpy()).max())
    assert gaps[0] < 5e-3, gaps
    assert 1.7 < gaps[0] / gaps[1] < 2.3, f"gaps {gaps} do not shrink like Δt"


def test_fused_cpu_sweep_equals_colour_by_colour_launches(monkeypatch):
    """On the CPU one launch over the colour-sorted list is bit-identical to per-colour launches."""
    import pliant.constraints._base as base

    model = cloth_model(10, dtype="float32")
    results = []
    for fused in (True, False):
        monkeypatch.setattr(base, "FUSE_CPU_COLORS", fused)
        solver = XPBD(model, iterations=3, schedule="coloring")
        ranges = solver.constraints[0].color_ranges(True)
        assert (len(ranges) == 1) == fused
        results.append(run(model, solver, 10, 1 / 240).particle_q.numpy())
    np.testing.assert_array_equal(results[0], results[1])


def test_kinematic_targets_are_followed():
    """A kinematic particle ends each step on its target with velocity (target − x)/Δt; the rest follow."""
    b = ModelBuilder(gravity=(0.0, -G, 0.0))
    b.add_rope(n_segments=4, length=0.4, mass=0.5, stiffness=1e3, start=(0, 0, 0), pin="none")
    b.add_kinematic([0])
    model = b.finalize(device="cpu", dtype="float64")
    control = model.control()
    solver = XPBD(model, iterations=10, schedule="coloring")
    s0, s1 = model.state(), model.state()
    for k in range(1, 21):
        target = np.array([[0.0, 0.01 * k, 0.0]])
        control.set_kinematic_targets(target)
        solver.step(s0, s1, control, 1e-2)
        s0, s1 = s1, s0
        np.testing.assert_allclose(s0.particle_q.numpy()[0], target[0], atol=1e-14)
        np.testing.assert_allclose(s0.particle_qd.numpy()[0], [0.0, 1.0, 0.0], atol=1e-9)
    assert s0.particle_q.numpy()[1:, 1].max() > 0.0  # the rope was lifted
