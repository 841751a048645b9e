"""Coulomb friction and restitution for RigidBodySolver's bodies (issue 39, the rigid family).

The same incline as tests/test_friction_incline.py (gravity tilted to tan θ = 0.5): a rigid 10 cm box of
8 corner particles slides at g (sin θ − μ cos θ) (2 %) for μ = 0.3, 0.45 and travels at most 1 mm over
1.5 s for μ = 0.6, on the ground and on a tilted box collider. Contact is solved on the body (sequential
impulses on v and ω), so its particles stay a rigid arrangement through contact (pairwise distances to
1e-9 m), an impact has restitution e at the contact and a friction impulse at most μ times the normal one,
and a body that touches nothing moves exactly as without the ground and colliders.
"""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl
from tests.test_friction_incline import DURATION, RADIUS, SIDE, THETA, TILTED, G, _box, _check


def _distances(x: np.ndarray) -> np.ndarray:
    return np.linalg.norm(x[:, None] - x[None], axis=-1)


def _run_rigid(model: pl.Model, solver, dt: float, axis=(1.0, 0.0, 0.0)):
    """Times [s], centre-of-mass travel [m] and velocity [m/s] along ``axis`` (60 samples a second), and
    the largest change of a pairwise particle distance [m] over the run (checked every step)."""
    s0, s1 = model.state(), model.state()
    m = model.particle_mass.numpy()
    a = np.asarray(axis, float)
    d0 = _distances(s0.particle_q.numpy())
    n, every = int(round(DURATION / dt)), max(1, int(round(1 / (60 * dt))))
    x0 = (m @ s0.particle_q.numpy()) / m.sum() @ a
    ts, xs, vs, bend = [], [], [], 0.0
    for k in range(n):
        solver.step(s0, s1, None, dt)
        s0, s1 = s1, s0
        x = s0.particle_q.numpy()
        bend = max(bend, float(np.abs(_distances(x) - d0).max()))
        if (k + 1) % every == 0:
            ts.append((k + 1) * dt)
            xs.append((m @ x) / m.sum() @ a - x0)
            vs.append((m @ s0.particle_qd.numpy()) / m.sum() @ a)
    return np.array(ts), np.array(xs), np.array(vs), bend


@pytest.mark.parametrize("mu", [0.3, 0.45, 0.6])
def test_a_rigid_box_on_an_incline_slides_at_coulombs_rate_or_rests(mu: float):
    """Slides at g(sin θ − μ cos θ) (2 %) for μ < tan θ, rests (≤ 1 mm over 1.5 s) for μ = 0.6, and stays
    rigid (pairwise distances to 1e-9 m) while its bottom face is in contact with the ground."""
    model = _box(mu, fem=False)
    solver = pl.solvers.RigidBodySolver(model)
    ts, xs, vs, bend = _run_rigid(model, solver, 1 / 600)
    _check(mu, ts, xs, vs)
    assert bend < 1e-9, f"the body bent by {bend:.3e} m in contact"


@pytest.mark.parametrize("mu", [0.3, 0.6])
def test_a_rigid_box_on_a_tilted_box_collider_slides_or_rests(mu: float):
    """Gravity straight down, a box collider rotated by θ about z (test_friction_incline's scene): the two
    regimes along the collider's slope, the body rigid throughout."""
    c, s = np.cos(THETA), np.sin(THETA)
    down, normal = np.array([c, -s, 0.0]), np.array([s, c, 0.0])
    centre = 0.5 * (SIDE + 2 * RADIUS) * normal + 0.02 * down
    model = _box(mu, fem=False, gravity=(0.0, -G, 0.0), ground=False, origin=tuple(centre))
    x = model.particle_q.numpy()
    rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    model.particle_q.assign((x - centre) @ rot.T + centre)
    colliders = pl.collision.Colliders()
    quat = (0.0, 0.0, -np.sin(THETA / 2), np.cos(THETA / 2))
    colliders.add_box(-1.0 * normal, (3.0, 1.0, 1.0), rotation=quat, friction=mu, restitution=0.0)
    solver = pl.solvers.RigidBodySolver(model, collisions=[colliders])
    ts, xs, vs, bend = _run_rigid(model, solver, 1 / 600, axis=down)
    _check(mu, ts, xs, vs)
    assert bend < 1e-9, f"the body bent by {bend:.3e} m in contact"


def _corner_box(tilt: float, h: float, vx: float, mu: float, e: float):
    """A rigid 10 cm cube of 8 equal corner particles (1 kg, r = 1 mm), rotated by ``tilt`` [rad] about z,
    its lowest point h [m] above the ground (μ, e), moving at vx [m/s]; gravity −g y."""
    b = pl.ModelBuilder(gravity=(0.0, -G, 0.0))
    corners = 0.5 * SIDE * np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
    c, s = np.cos(tilt), np.sin(tilt)
    x = corners @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
    x[:, 1] += h + RADIUS - x[:, 1].min()
    b.add_particles(x, [0.125] * 8, velocities=np.tile([vx, 0.0, 0.0], (8, 1)), radius=RADIUS)
    b.add_ground(0.0, friction=mu, restitution=e)
    return b.finalize(device="cpu", dtype="float64")


def _body(model: pl.Model, state) -> tuple[np.ndarray, ...]:
    """Positions, velocities, centre of mass, its velocity, angular momentum about it [kg m²/s] and the
    world inertia tensor [kg m²]."""
    m = model.particle_mass.numpy()
    x, v = state.particle_q.numpy().copy(), state.particle_qd.numpy().copy()
    c, vc = m @ x / m.sum(), m @ v / m.sum()
    r = x - c
    L = (m[:, None] * np.cross(r, v - vc)).sum(axis=0)
    inertia = np.eye(3) * np.sum(m * np.sum(r * r, axis=1)) - (r * m[:, None]).T @ r
    return x, v, c, vc, L, inertia


def _impact(model: pl.Model, solver, dt: float):
    """Run until the step whose end velocity bounces upwards; the body (:func:`_body`) before and after it,
    and the state after it (to continue from)."""
    s0, s1 = model.state(), model.state()
    for _ in range(int(1.0 / dt)):
        solver.step(s0, s1, None, dt)
        if _body(model, s1)[3][1] > 0.0:
            return _body(model, s0), _body(model, s1), s1
        s0, s1 = s1, s0
    raise AssertionError("the body never bounced")


def test_a_flat_oblique_bounce_has_restitution_and_coulombs_impulse():
    """A cube landing flat from h = 0.1 m at v_x = 2 m/s (e = 0.5, μ = 0.2): the impact step turns its
    vertical velocity v_y⁻ (gravity's step included) into −e v_y⁻ (1e-4), removes μ Δv_y of v_x (1e-6: it
    slides through the impact, Coulomb's impulse on the whole normal impulse), leaves it without spin (the
    friction torque balanced by the front edge's larger normal impulse), rises to e² h (2 %), stays rigid."""
    h, e, mu, dt = 0.1, 0.5, 0.2, 1e-4
    model = _corner_box(0.0, h, 2.0, mu, e)
    solver = pl.solvers.RigidBodySolver(model)
    before, after, s0 = _impact(model, solver, dt)
    vy_free = before[3][1] - G * dt
    assert after[3][1] == pytest.approx(-e * vy_free, rel=1e-4)
    dvy = after[3][1] - vy_free
    assert after[3][0] - before[3][0] == pytest.approx(-mu * dvy, rel=1e-6)
    assert np.linalg.norm(after[4]) < 1e-4 * 0.5 * SIDE * mu * dvy, after[4]
    # The rise: from the impact on, the lowest point's height over the next half second.
    d0 = _distances(after[0])
    s1, peak, bend = model.state(), 0.0, 0.0
    for _ in range(int(0.5 / dt)):
        solver.step(s0, s1, None, dt)
        s0, s1 = s1, s0
        x = s0.particle_q.numpy()
        peak = max(peak, float(x[:, 1].min()) - RADIUS)
        bend = max(bend, float(np.abs(_distances(x) - d0).max()))
    assert peak == pytest.approx(e * e * vy_free**2 / (2 * G), rel=0.02)
    assert bend < 1e-9


@pytest.mark.parametrize("vx", [1.0, 3.0])
def test_an_edge_first_bounce_has_restitution_at_the_contact_and_a_coulomb_impulse(vx: float):
    """A cube tilted by 0.3 rad lands on one edge (e = 0.5, μ = 0.2). The impulse ΔP = M Δv − M g Δt acts at
    the edge: ΔL = r × ΔP about the centre of mass (1e-4 of |r||ΔP|), the edge's normal velocity goes from
    u_n⁻ to −e u_n⁻ (1e-4), and |ΔP_t| ≤ μ ΔP_n. At v_x = 3 m/s the edge slides through the impact
    (|ΔP_t| = μ ΔP_n, 1e-6); at 1 m/s the cone holds it: its tangential velocity stops (< 1 mm/s)."""
    e, mu, dt = 0.5, 0.2, 1e-4
    model = _corner_box(0.3, 0.1, vx, mu, e)
    solver = pl.solvers.RigidBodySolver(model)
    (x0, v0, c0, vc0, L0, _), (x1, _, c1, vc1, L1, inertia1), _ = _impact(model, solver, dt)
    M = float(model.particle_mass.numpy().sum())
    edge = x1[:, 1] < x1[:, 1].min() + 1e-6
    assert edge.sum() == 2
    # Before the impact the cube does not turn: the contact levers of the step are x₀ − c₀.
    r = x0[edge] - c0
    dP = M * (vc1 - vc0) - M * np.array([0.0, -G, 0.0]) * dt
    np.testing.assert_allclose(L1 - L0, np.cross(r.mean(axis=0), dP), atol=1e-4 * 0.1 * np.linalg.norm(dP))
    u1 = vc1 + np.cross(np.linalg.solve(inertia1, L1), r)
    un_free = v0[edge, 1] - G * dt
    np.testing.assert_allclose(u1[:, 1], -e * un_free, rtol=1e-4)
    ratio = np.hypot(dP[0], dP[2]) / dP[1]
    if vx > 2.0:
        assert ratio == pytest.approx(mu, rel=1e-6)
    else:
        assert ratio < mu
        assert np.abs(u1[:, [0, 2]]).max() < 1e-3


def test_a_body_that_touches_nothing_moves_as_without_contact():
    """Two bodies without gravity: a cube thrown down onto the ground (it bounces) and a spinning cube that
    passes a sphere collider above the ground without touching either. The spinning cube's trajectory is bit
    for bit the one of a model that holds it alone, with no ground and no collider; its momentum is constant
    (1e-12) and its angular momentum about its centre of mass too (1e-9: no torque on an isotropic body)."""
    cube = 0.5 * SIDE * np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
    spinner = cube + [1.0, 1.0, 0.0]
    spinner_v = [0.5, 0.2, 0.0] + np.cross([3.0, -5.0, 8.0], cube)
    dt, steps = 1e-3, 300

    def run(alone: bool) -> np.ndarray:
        b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
        if not alone:
            b.add_particles(cube + [0, 0.06, 0], [0.125] * 8, velocities=[[0, -1.0, 0]] * 8, radius=0.01)
            b.add_ground(0.0, friction=0.5, restitution=0.5)
        b.add_particles(spinner, [0.125] * 8, velocities=spinner_v, radius=0.01)
        model = b.finalize(device="cpu", dtype="float64")
        if alone:
            solver = pl.solvers.RigidBodySolver(model)
        else:
            colliders = pl.collision.Colliders()
            colliders.add_sphere((1.0, 0.5, 0.0), 0.2)
            solver = pl.solvers.RigidBodySolver(
                model, [np.arange(8), np.arange(8, 16)], collisions=[colliders]
            )
        s0, s1 = model.state(), model.state()
        for _ in range(steps):
            solver.step(s0, s1, None, dt)
            s0, s1 = s1, s0
        return np.stack([s0.particle_q.numpy(), s0.particle_qd.numpy()])

    alone, both = run(True), run(False)
    np.testing.assert_array_equal(both[:, 8:], alone)
    assert both[1, :8, 1].mean() == pytest.approx(0.5, rel=1e-3)  # the thrown cube bounced with e = 0.5
    r0, r1 = cube, alone[0] - alone[0].mean(axis=0)
    v1 = alone[1] - alone[1].mean(axis=0)
    np.testing.assert_allclose(0.125 * alone[1].sum(axis=0), [0.5, 0.2, 0.0], atol=1e-12)
    L0 = 0.125 * np.cross(r0, np.cross([3.0, -5.0, 8.0], cube)).sum(axis=0)
    np.testing.assert_allclose(0.125 * np.cross(r1, v1).sum(axis=0), L0, atol=1e-9 * np.linalg.norm(L0))


def test_rigid_contact_refuses_what_it_cannot_do():
    """Compliant ground (a spring–damper per particle) and fewer than one contact sweep are refused at
    construction, naming the fix."""
    b = pl.ModelBuilder(gravity=(0.0, -G, 0.0))
    b.add_particles(np.vstack([0.05 * np.eye(3), np.zeros(3)]), [0.1] * 4, radius=RADIUS)
    b.add_ground(-1.0, stiffness=1e4)
    model = b.finalize(device="cpu", dtype="float64")
    with pytest.raises(NotImplementedError, match="compliant ground.*without stiffness"):
        pl.solvers.RigidBodySolver(model)
    b = pl.ModelBuilder()
    b.add_particles(np.vstack([0.05 * np.eye(3), np.zeros(3)]), [0.1] * 4)
    with pytest.raises(ValueError, match="contact_iterations must be >= 1"):
        pl.solvers.RigidBodySolver(b.finalize(device="cpu"), contact_iterations=0)


def test_a_resting_body_with_restitution_does_not_hop():
    """Restitution acts on impacts, not on resting contact (whose approach speed is gravity's |g|Δt per
    step): with e = 0.5 the box inside the cone (μ = 0.6) still travels ≤ 1 mm over 1.5 s, and its lowest
    corner never rises 1 µm above the ground (reflected, |g|Δt e would lift it 7 µm every step)."""
    b = pl.ModelBuilder(gravity=TILTED)
    b.add_particles(
        0.5 * SIDE * np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
        + [0.0, 0.5 * SIDE + RADIUS, 0.0],
        [0.125] * 8,
        radius=RADIUS,
    )
    b.add_ground(0.0, friction=0.6, restitution=0.5)
    model = b.finalize(device="cpu", dtype="float64")
    solver = pl.solvers.RigidBodySolver(model)
    s0, s1 = model.state(), model.state()
    c0, lift = s0.particle_q.numpy().mean(axis=0), 0.0
    for _ in range(int(DURATION * 600)):
        solver.step(s0, s1, None, 1 / 600)
        s0, s1 = s1, s0
        lift = max(lift, float(s0.particle_q.numpy()[:, 1].min()) - RADIUS)
    assert np.linalg.norm(s0.particle_q.numpy().mean(axis=0) - c0) <= 1e-3
    assert lift < 1e-6, f"the box hopped {lift * 1e6:.2f} µm"


def test_penetration_is_removed_by_position_not_velocity():
    """A cube started 5 mm inside the ground (e = 0) is out after one step (its lowest corner on the surface
    to 1e-9 m, so level) and at rest (1e-4 m/s, what 20 sweeps leave of gravity's g Δt = 16 mm/s): the
    split impulse moves the pose and adds no energy, where a velocity push-out would launch it at
    5 mm / Δt = 3 m/s."""
    b = pl.ModelBuilder(gravity=(0.0, -G, 0.0))
    cube = 0.5 * SIDE * np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
    b.add_particles(cube + [0.0, 0.5 * SIDE + RADIUS - 0.005, 0.0], [0.125] * 8, radius=RADIUS)
    b.add_ground(0.0, friction=0.5, restitution=0.0)
    model = b.finalize(device="cpu", dtype="float64")
    s0, s1 = model.state(), model.state()
    pl.solvers.RigidBodySolver(model).step(s0, s1, None, 1 / 600)
    x, v = s1.particle_q.numpy(), s1.particle_qd.numpy()
    np.testing.assert_allclose(x[:, 1][cube[:, 1] < 0], RADIUS, atol=1e-9)
    np.testing.assert_allclose(v, 0.0, atol=1e-4)
