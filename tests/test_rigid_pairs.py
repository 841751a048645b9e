"""Rigid bodies meet each other (issue 39 item 1, the rigid family, body to body).

RigidBodySolver solves the contacts between bodies (particle spheres of different bodies overlapping)
together with the ground's by one Gauss–Seidel pass (pliant/solvers/rigid/_pairs.py). These tests pin what
that promises, in float64: Coulomb's two regimes between bodies (a box on a slab on the incline of
tests/test_friction_incline.py rests for μ = 0.6; a box on a held body slides at g(sin θ − μ cos θ), 2 %,
for μ = 0.3 and 0.45), a head-on impact's 1D closed forms for e = 1 and e = 0 (1 %), momentum and angular
momentum kept (1e-9 relative, off-centre impacts with friction too), a stack of three boxes that stays put
(1 mm over 2 s) without overlap (1 % of the radius), bodies that stay rigid (pairwise distances to 1e-9 m),
and bodies that touch no other body moving bit for bit as with the per-body solve.
"""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl
from tests.test_friction_incline import SIDE, THETA, TILTED, G, coulomb

CUBE = 0.5 * SIDE * np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)


def _distances(x: np.ndarray) -> np.ndarray:
    return np.linalg.norm(x[:, None] - x[None], axis=-1)


def _boxes(centres, velocities, radius: float, gravity, ground_mu: float | None = None) -> pl.Model:
    """10 cm cubes of 8 corner particles (1 kg, radius ``radius``) at ``centres`` moving at ``velocities``."""
    b = pl.ModelBuilder(gravity=gravity)
    for c, v in zip(centres, velocities, strict=True):
        b.add_particles(CUBE + c, [0.125] * 8, velocities=np.tile(v, (8, 1)), radius=radius)
    if ground_mu is not None:
        b.add_ground(0.0, friction=ground_mu, restitution=0.0)
    return b.finalize(device="cpu", dtype="float64")


def _bodies(count: int) -> list[np.ndarray]:
    return [np.arange(8 * k, 8 * k + 8) for k in range(count)]


def _overlap(x: np.ndarray, radius: float, count: int) -> float:
    """The largest overlap [m] of particle spheres of different bodies (0 if none)."""
    d = _distances(x)
    body = np.repeat(np.arange(count), 8)
    other = body[:, None] != body[None]
    return float(max((2 * radius - d)[other].max(), 0.0))


def _run(model: pl.Model, solver, dt: float, steps: int, control=None):
    """States' positions and velocities every step, and the largest in-body distance change [m]."""
    s0, s1 = model.state(), model.state()
    count = model.particle_count // 8
    d0 = [_distances(s0.particle_q.numpy()[8 * k : 8 * k + 8]) for k in range(count)]
    xs, vs, bend = [], [], 0.0
    for _ in range(steps):
        solver.step(s0, s1, control, dt)
        s0, s1 = s1, s0
        x = s0.particle_q.numpy()
        for k in range(count):
            bend = max(bend, float(np.abs(_distances(x[8 * k : 8 * k + 8]) - d0[k]).max()))
        xs.append(x.copy())
        vs.append(s0.particle_qd.numpy().copy())
    return np.array(xs), np.array(vs), bend


@pytest.mark.parametrize("e", [1.0, 0.0])
def test_a_head_on_impact_has_the_1d_closed_form_and_keeps_momentum(e: float):
    """Two equal cubes in free space, face to face along x at 1 and −0.5 m/s, off the origin so that the
    angular momentum about it is not zero: after the impact the 1D closed forms
    v_a' = v̄ − e (v_a − v_b)/2, v_b' = v̄ + e (v_a − v_b)/2 (1 %), no spin (1e-6 rad/s), and the total momentum
    and angular momentum are those before (1e-9 relative); the cubes stay rigid (1e-9 m)."""
    r, va, vb = 0.01, 1.0, -0.5
    gap = SIDE + 2 * r + 0.02
    model = _boxes([(-gap / 2, 0.3, 0.2), (gap / 2, 0.3, 0.2)], [(va, 0, 0), (vb, 0, 0)], r, (0.0, 0.0, 0.0))
    solver = pl.solvers.RigidBodySolver(model, _bodies(2), body_restitution=e)
    xs, vs, bend = _run(model, solver, 1e-3, 100)
    m = model.particle_mass.numpy()
    P = (m[:, None] * vs).sum(axis=1)
    L = (m[:, None] * np.cross(xs, vs)).sum(axis=1)
    P0 = m[:8].sum() * (va + vb) * np.array([1.0, 0, 0])
    L0 = (m[:, None] * np.cross(model.particle_q.numpy(), model.particle_qd.numpy())).sum(axis=0)
    np.testing.assert_allclose(P, np.tile(P0, (len(P), 1)), atol=1e-9 * np.linalg.norm(P0))
    np.testing.assert_allclose(L, np.tile(L0, (len(L), 1)), atol=1e-9 * np.linalg.norm(L0))
    mean, half = 0.5 * (va + vb), 0.5 * (va - vb)
    v_after = [vs[-1, :8].mean(axis=0), vs[-1, 8:].mean(axis=0)]
    assert v_after[0][0] == pytest.approx(mean - e * half, rel=0.01, abs=0.01 * abs(va))
    assert v_after[1][0] == pytest.approx(mean + e * half, rel=0.01, abs=0.01 * abs(va))
    for k in range(2):
        spin = vs[-1, 8 * k : 8 * k + 8] - v_after[k]
        assert np.abs(spin).max() < 1e-6
    assert bend < 1e-9


def test_a_stack_of_three_boxes_stays_put_without_overlap():
    """Three cubes stacked corner on corner on the ground (μ = 0.5 everywhere, e = 0): over 2 s each moves at
    most 1 mm, spheres of different bodies overlap at most 1 % of their radius over the last second, and
    each stays rigid (1e-9 m). The stack's contacts take pair_sweeps = 100 sweeps (0.15 mm): impulses start
    from zero every step and the bottom contacts carry three weights through two bodies; with 20, the
    per-body default, the top cube drifts 3 mm sideways over 2 s."""
    r, h = 0.01, SIDE + 2 * 0.01
    centres = [(0.0, 0.5 * SIDE + r + k * h, 0.0) for k in range(3)]
    model = _boxes(centres, [(0, 0, 0)] * 3, r, (0.0, -G, 0.0), ground_mu=0.5)
    solver = pl.solvers.RigidBodySolver(model, _bodies(3))
    xs, _, bend = _run(model, solver, 1 / 600, 1200)
    for k in range(3):
        travel = np.linalg.norm(xs[:, 8 * k : 8 * k + 8].mean(axis=1) - centres[k], axis=1).max()
        assert travel <= 1e-3, f"box {k} moved {travel * 1e3:.3f} mm"
    overlap = max(_overlap(x, r, 3) for x in xs[600:])
    assert overlap <= 0.01 * r, f"overlap {overlap / r:.2%} of the radius"
    assert bend < 1e-9


def test_a_box_on_a_box_on_the_incline_rests_inside_the_cone():
    """Gravity tilted to tan θ = 0.5, the 10 cm cube on a 30 × 5 × 30 cm slab (32 particles, 4 × 2 × 4, its
    middle top particles under the cube's corners; wide, so that the pair does not topple as two stacked
    cubes would, tan θ > 0.05 / 0.11) on the ground, μ = 0.6 between them and with the ground, radius 1 cm:
    the cube moves ≤ 1 mm relative to the slab over 1.5 s, the slab ≤ 1 mm, both rigid (1e-9 m). With
    pair_sweeps = 20 instead of 100 the unconverged impulses let the cube creep 1 mm/s, until the
    sphere-on-sphere normals tilt past the cone and it slides off."""
    r = 0.01
    g = np.array(
        [[x, y, z] for x in (-1.5, -0.5, 0.5, 1.5) for y in (0.0, 0.5) for z in (-1.5, -0.5, 0.5, 1.5)]
    )
    slab = SIDE * g + [0.0, r, 0.0]
    b = pl.ModelBuilder(gravity=TILTED)
    b.add_particles(slab, [1 / 32] * 32, radius=r)
    cube = CUBE + [0.0, slab[:, 1].max() + 2 * r + 0.5 * SIDE, 0.0]
    b.add_particles(cube, [0.125] * 8, radius=r)
    b.add_ground(0.0, friction=0.6, restitution=0.0)
    model = b.finalize(device="cpu", dtype="float64")
    solver = pl.solvers.RigidBodySolver(
        model,
        [np.arange(32), np.arange(32, 40)],
        body_friction=0.6,
    )
    s0, s1 = model.state(), model.state()
    d0 = [_distances(slab), _distances(cube)]
    low0, top0, relative, travel, bend = slab.mean(axis=0), cube.mean(axis=0), 0.0, 0.0, 0.0
    for _ in range(900):
        solver.step(s0, s1, None, 1 / 600)
        s0, s1 = s1, s0
        x = s0.particle_q.numpy()
        low, top = x[:32].mean(axis=0), x[32:].mean(axis=0)
        relative = max(relative, float(np.linalg.norm((top - low) - (top0 - low0))))
        travel = max(travel, float(np.linalg.norm(low - low0)))
        bend = max(bend, *(float(np.abs(_distances(y) - d).max()) for y, d in zip((x[:32], x[32:]), d0)))
    assert relative <= 1e-3, f"the cube slid {relative * 1e3:.3f} mm on the slab"
    assert travel <= 1e-3, f"the slab slid {travel * 1e3:.3f} mm"
    assert bend < 1e-9


@pytest.mark.parametrize("mu", [0.3, 0.45, 0.6])
def test_a_box_on_a_held_body_slides_at_coulombs_rate(mu: float):
    """Particle spheres make bumpy surfaces, so the closed form needs a flat one: the lower body is a sphere
    of radius 10 km (its top flat to 1e-4 rad over the 2 m of sliding) with three small particles inside
    for a full inertia, 1e12 kg each, so it is held. Gravity is tilted to tan θ = 0.5 and given as forces on
    the cube only (the model's gravity is zero): the cube slides on the held body at g(sin θ − μ cos θ)
    (2 %, from 0.3 s on) for μ = 0.3 and 0.45, rests (≤ 1 mm over 1.5 s) for μ = 0.6, and stays rigid
    (1e-9 m)."""
    R, r = 1.0e4, 0.001
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles(CUBE + [0.0, 0.5 * SIDE + r, 0.0], [0.125] * 8, radius=r)
    inner = np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0], [0.0, 100.0, 0.0], [0.0, 0.0, 100.0]]) - [0, R, 0]
    b.add_particles(inner, [1e12] * 4, radius=np.array([R, 0.01, 0.01, 0.01]))
    model = b.finalize(device="cpu", dtype="float64")
    control = model.control()
    f = np.zeros((12, 3))
    f[:8] = 0.125 * np.asarray(TILTED)
    control.particle_f.assign(f)
    solver = pl.solvers.RigidBodySolver(model, [np.arange(8), np.arange(8, 12)], body_friction=mu)
    dt = 1 / 600
    xs, vs, _ = _run_cube(model, solver, dt, 900, control)
    ts = dt * np.arange(1, 901)
    if mu > np.tan(THETA):
        assert np.abs(xs[:, 0] - xs[0, 0]).max() <= 1e-3
        return
    window = ts >= 0.3
    accel = np.polyfit(ts[window], vs[window, 0], 1)[0]
    assert accel == pytest.approx(coulomb(mu), rel=0.02), f"{accel:.4f} vs {coulomb(mu):.4f} m/s²"


def _run_cube(model: pl.Model, solver, dt: float, steps: int, control):
    """The first body's (the cube's) centre and velocity every step; asserts it stays rigid (1e-9 m)."""
    s0, s1 = model.state(), model.state()
    d0 = _distances(s0.particle_q.numpy()[:8])
    xs, vs = [], []
    for _ in range(steps):
        solver.step(s0, s1, control, dt)
        s0, s1 = s1, s0
        x = s0.particle_q.numpy()[:8]
        assert np.abs(_distances(x) - d0).max() < 1e-9
        xs.append(x.mean(axis=0))
        vs.append(s0.particle_qd.numpy()[:8].mean(axis=0))
    return np.array(xs), np.array(vs), 0.0


def test_pair_contact_refuses_bad_parameters_and_overflow():
    """Bad μ, e or room are refused at construction; a step with more pair contacts than room raises."""
    model = _boxes([(0, 0, 0), (SIDE + 0.015, 0, 0)], [(0, 0, 0)] * 2, 0.01, (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="body_friction must be >= 0"):
        pl.solvers.RigidBodySolver(model, _bodies(2), body_restitution=1.5)
    with pytest.raises(ValueError, match="pair_contacts must be >= 1"):
        pl.solvers.RigidBodySolver(model, _bodies(2), pair_contacts=0)
    solver = pl.solvers.RigidBodySolver(model, _bodies(2), pair_contacts=2)
    with pytest.raises(RuntimeError, match="4 body-to-body contacts.*larger pair_contacts"):
        solver.step(model.state(), model.state(), None, 1e-3)


def test_bodies_that_touch_no_other_body_move_as_with_the_per_body_solve():
    """Two cubes 1 m apart on the tilted ground (μ = 0.3, e = 0.5: one dropped from 5 cm so that it bounces,
    one spinning into a sphere collider) go through the coupled path; each is bit for bit the cube alone in
    a model of its own, which takes the per-body path."""
    spin = np.cross([3.0, -5.0, 8.0], CUBE)
    starts = [(CUBE + [0, 0.11, 0], np.zeros((8, 3))), (CUBE + [1.0, 0.06, 0], spin + [0.5, 0, 0.2])]
    colliders = pl.collision.Colliders()
    colliders.add_sphere((1.3, 0.0, 0.0), 0.1, friction=0.4, restitution=0.5)

    def run(parts) -> np.ndarray:
        b = pl.ModelBuilder(gravity=TILTED)
        for x, v in parts:
            b.add_particles(x, [0.125] * 8, velocities=v, radius=0.01)
        b.add_ground(0.0, friction=0.3, restitution=0.5)
        model = b.finalize(device="cpu", dtype="float64")
        solver = pl.solvers.RigidBodySolver(model, _bodies(len(parts)), collisions=[colliders])
        s0, s1 = model.state(), model.state()
        for _ in range(400):
            solver.step(s0, s1, None, 1 / 600)
            s0, s1 = s1, s0
        return np.stack([s0.particle_q.numpy(), s0.particle_qd.numpy()])

    both = run(starts)
    np.testing.assert_array_equal(both[:, :8], run(starts[:1]))
    np.testing.assert_array_equal(both[:, 8:], run(starts[1:]))
    assert np.abs(both[0, 8:, 0].mean() - 1.0) > 0.05  # the second cube moved (slid, hit the sphere)


@pytest.mark.parametrize(("dy", "mu", "e"), [(0.01, 0.5, 0.5), (0.015, 0.2, 1.0), (0.01, 0.0, 1.0)])
def test_an_off_centre_impact_keeps_momentum_and_angular_momentum(dy: float, mu: float, e: float):
    """Two cubes meet off centre (offset dy [m], one also moving in z), so that friction and the normal
    impulse both spin them: the total momentum and the angular momentum about the origin are those before
    (1e-9 relative, every step), the cubes spin afterwards, and with e = 1 and μ = 0 the kinetic energy is
    kept (1e-3: restitution is set on each contact's approach speed)."""
    r = 0.01
    gap = SIDE + 2 * r + 0.02
    centres = [(-gap / 2, 0.3, 0.2), (gap / 2, 0.3 + dy, 0.2)]
    model = _boxes(centres, [(1.0, 0.0, 0.0), (-0.5, 0.0, 0.05)], r, (0.0, 0.0, 0.0))
    solver = pl.solvers.RigidBodySolver(model, _bodies(2), body_friction=mu, body_restitution=e)
    xs, vs, bend = _run(model, solver, 1e-3, 150)
    m, x0, v0 = model.particle_mass.numpy(), model.particle_q.numpy(), model.particle_qd.numpy()
    P0, L0 = m @ v0, (m[:, None] * np.cross(x0, v0)).sum(axis=0)
    P, L = np.einsum("i,tij->tj", m, vs), (m[:, None] * np.cross(xs, vs)).sum(axis=1)
    assert np.abs(P - P0).max() <= 1e-9 * np.linalg.norm(P0)
    assert np.abs(L - L0).max() <= 1e-9 * np.linalg.norm(L0)
    spin = np.abs(vs[-1, :8] - vs[-1, :8].mean(axis=0)).max()
    assert spin > 0.01, "the off-centre impact should spin the cubes"
    if mu == 0.0 and e == 1.0:
        energy = 0.5 * (m[:, None] * vs[-1] ** 2).sum()
        assert energy == pytest.approx(0.5 * (m[:, None] * v0**2).sum(), rel=1e-3)
    assert bend < 1e-9
