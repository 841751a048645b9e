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
from tests.test_friction_incline import DURATION, RADIUS, SIDE, THETA, G, _box, _check


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
