"""Gradients through the collider contact handler (``collisions=[pl.collision.Colliders]``) of ForceSolver:
a cloth dropped with a sideways velocity onto a sphere and a rotated box (contact, restitution and
Coulomb friction active), ∂loss/∂(collider μ, e and centres, spring stiffness, x₀, v₀) from
``pl.diff.rollout`` against central finite differences (float64, relative error ≤ 1e-4), explicit and
implicit steps."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl

FRAMES, SUBSTEPS, DT = 4, 6, 2e-3


@wp.kernel
def _loss(
    x: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    w: wp.array(dtype=wp.vec3d),
    out: wp.array(dtype=wp.float64),
):
    i = wp.tid()
    wp.atomic_add(out, 0, wp.dot(x[i], w[i]) + wp.float64(0.05) * wp.dot(v[i], v[i]))


def _setup(integ: str):
    b = pl.ModelBuilder()
    b.add_cloth_grid(
        nx=4, ny=4, size=0.3, mass=0.05, stiffness=80.0, damping=0.02, origin=(-0.15, 0.205, -0.15)
    )
    m = b.finalize(device="cpu", dtype="float64", requires_grad=True)
    rng = np.random.default_rng(0)
    m.particle_qd.assign(np.array([0.4, -1.5, 0.2]) + 0.1 * rng.normal(size=(m.particle_count, 3)))
    col = pl.collision.Colliders()
    col.add_sphere((0.02, 0.0, 0.01), 0.2, friction=0.4, restitution=0.3)
    col.add_box(
        (0.2, 0.1, 0.0),
        (0.05, 0.1, 0.2),
        rotation=(0.0, 0.1494, 0.0498, 0.9875),
        friction=0.2,
        restitution=0.1,
    )
    integrator = (
        pl.integrators.SymplecticEuler()
        if integ == "symplectic"
        else pl.integrators.BackwardEuler(newton_tol=1e-12, max_newton_iterations=50)
    )
    solver = pl.solvers.ForceSolver(m, pl.energies.mass_spring(), integrator, collisions=[col])
    return m, solver, col


def _loss_fn(w):
    def loss(state):
        out = wp.zeros(1, dtype=wp.float64, requires_grad=True)
        wp.launch(_loss, state.particle_q.shape[0], [state.particle_q, state.particle_qd, w, out])
        return out

    return loss


PARAMS = ["collider_friction", "collider_restitution", "collider_pos", "spring_stiffness", "x0", "v0"]


def _array(m, solver, col, name):
    key = name.split("_", 1)[1] if name.startswith("collider_") else None
    if key is not None:
        return col.arrays(m)[key]
    return {"x0": m.particle_q, "v0": m.particle_qd}.get(name, getattr(m, name, None))


def _plain(integ, name, theta, w):
    m, solver, col = _setup(integ)
    _array(m, solver, col, name).assign(theta)
    s = m.state()
    for _ in range(FRAMES * SUBSTEPS):
        n = m.state()
        solver.step(s, n, None, DT)
        s = n
    return float(_loss_fn(w)(s).numpy()[0]), s


@pytest.mark.parametrize("integ", ["symplectic", "backward_euler"])
def test_collider_gradients_match_finite_differences(integ):
    m, solver, col = _setup(integ)
    w = wp.array(np.random.default_rng(1).normal(size=(m.particle_count, 3)), dtype=wp.vec3d)
    res = pl.diff.rollout(
        m, solver, _loss_fn(w), frames=FRAMES, substeps=SUBSTEPS, dt=DT, params=PARAMS, checkpoint_every=2
    )
    base, s = _plain(integ, "x0", m.particle_q.numpy(), w)
    assert res.loss == pytest.approx(base, rel=1e-12)
    # The set-up must exercise the contact: particles end on or inside the colliders' skin (within 1 µm:
    # friction moves a resting particle along the tangent after the push, δ²/2R off a curved surface).
    phi, _ = col.query(m, s.particle_q)
    assert (phi < m.particle_radius.numpy() + 1e-6).sum() >= 3
    rng = np.random.default_rng(2)
    for name in PARAMS:
        theta = _array(m, solver, col, name).numpy().astype(np.float64)
        d = rng.normal(size=theta.shape)
        eps = 1e-7 * max(float(np.abs(theta).mean()), 1e-1)
        fd = (_plain(integ, name, theta + eps * d, w)[0] - _plain(integ, name, theta - eps * d, w)[0]) / (
            2 * eps
        )
        ad = float(np.sum(res.grads[name] * d))
        assert abs(fd) > 1e-9, f"{name}: the loss does not depend on it (test set-up)"
        assert ad == pytest.approx(fd, rel=1e-4), f"{integ} {name}: rollout {ad} vs FD {fd}"


def test_mesh_colliders_and_foreign_handlers_are_refused():
    m, solver, col = _setup("symplectic")
    col.add_mesh(np.array([[0, -1, 0], [1, -1, 0], [0, -1, 1.0]]), np.array([[0, 1, 2]]))
    with pytest.raises(pl.diff.GradientError, match="mesh colliders"):
        pl.diff.rollout(m, solver, _loss_fn(wp.zeros(m.particle_count, dtype=wp.vec3d)), frames=1, dt=DT)

    class InPlace:
        def apply(self, model, state_in, state_out, dt):
            pass

    other = pl.solvers.ForceSolver(m, pl.energies.mass_spring(), collisions=[InPlace()])
    with pytest.raises(pl.diff.GradientError, match="InPlace"):
        pl.diff.rollout(m, other, _loss_fn(wp.zeros(m.particle_count, dtype=wp.vec3d)), frames=1, dt=DT)
