"""One post-step contact-handler path for every solver (``collisions=``), XPBD and PBD included."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl
from pliant.model import ModelBuilder
from pliant.solvers import PBD, XPBD, RigidBodySolver

wp.init()
wp.config.quiet = True


def _cloth_over_sphere():
    b = ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_cloth_grid(nx=8, ny=8, size=0.5, mass=0.1, stiffness=200.0, origin=(-0.25, 0.3, -0.25), plane="xz")
    b.add_ground(0.0, friction=0.4)
    return b.finalize(device="cpu", dtype="float64")


def _sphere():
    c = pl.collision.Colliders()
    c.add_sphere((0.0, 0.15, 0.0), 0.12, friction=0.3)
    return c


def _old_subclass(cls: type) -> type:
    """The run-time subclass pliant/io/_scene.py used before ``collisions=`` (``_with_post_step``)."""

    def step(self, state_in, state_out, control, dt):
        cls.step(self, state_in, state_out, control, dt)
        for c in self.post_step:
            c.apply(self.model, state_in, state_out, dt)

    return type(cls.__name__, (cls,), {"step": step, "post_step": (), "__module__": cls.__module__})


def _rollout(solver, model, steps=40, dt=1.0 / 240.0):
    s0, s1 = model.state(), model.state()
    for _ in range(steps):
        solver.step(s0, s1, None, dt)
        s0, s1 = s1, s0
    return s0.particle_q.numpy()


@pytest.mark.parametrize("cls", [XPBD, PBD])
def test_collisions_keyword_equals_the_old_run_time_subclass_bit_for_bit(cls):
    """A sphere collider through ``collisions=[...]`` gives exactly the old ``_with_post_step`` motion."""
    model = _cloth_over_sphere()
    new = _rollout(cls(model, iterations=5, collisions=[_sphere()]), model)
    old_solver = _old_subclass(cls)(model, iterations=5)
    old_solver.post_step = [_sphere()]
    old = _rollout(old_solver, model)
    np.testing.assert_array_equal(new, old)
    # The collider acted: without it the cloth centre falls through the sphere's top (y = 0.27 m).
    free = _rollout(cls(model, iterations=5), model)
    assert np.abs(new - free).max() > 1e-3
    centre = np.argmin(np.linalg.norm(new[:, [0, 2]], axis=1))
    assert np.linalg.norm(new[centre] - np.array([0.0, 0.15, 0.0])) >= 0.12 - 1e-9


def test_every_solver_checks_its_handlers():
    """A handler without ``apply`` is rejected by the shared base, whatever the solver."""
    model = _cloth_over_sphere()
    for make in (lambda c: XPBD(model, collisions=c), lambda c: RigidBodySolver(model, collisions=c)):
        with pytest.raises(TypeError, match="apply"):
            make([object()])


def test_rigid_body_solver_runs_its_handlers():
    """RigidBodySolver calls each handler once per step, after its own update."""
    b = ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_particles([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]], [1.0] * 4)
    model = b.finalize(device="cpu", dtype="float64")
    calls = []

    class Probe:
        def apply(self, model, state_in, state_out, dt):
            calls.append(state_out.particle_q.numpy().copy())

    solver = RigidBodySolver(model, collisions=[Probe()])
    out = _rollout(solver, model, steps=3)
    assert len(calls) == 3
    np.testing.assert_array_equal(calls[-1], out)


@wp.kernel
def _drift(
    dt: wp.float64,
    x_in: wp.array(dtype=wp.vec3d),
    v_in: wp.array(dtype=wp.vec3d),
    x_out: wp.array(dtype=wp.vec3d),
    v_out: wp.array(dtype=wp.vec3d),
):
    i = wp.tid()
    x_out[i] = x_in[i] + dt * v_in[i]
    v_out[i] = v_in[i]


def _post_stages(requires_grad: bool, penalty: float | None, stages: bool = True) -> np.ndarray:
    """One ``finish_step`` (a drift, then kinematic targets, the ground, a sphere and a box) on a model
    whose particles start inside the ground and the colliders, with or without gradients."""
    from pliant.collision import ground_coefficients
    from pliant.solvers._post import finish_step

    rng = np.random.default_rng(4)
    b = ModelBuilder()
    b.add_particles(rng.uniform([-0.4, -0.05, -0.2], [0.4, 0.3, 0.2], size=(64, 3)), 0.01, radius=0.01)
    b.add_kinematic([0, 7])
    b.add_ground(0.0, friction=0.4, restitution=0.3)
    m = b.finalize(device="cpu", dtype="float64", requires_grad=requires_grad)
    col = pl.collision.Colliders()
    col.add_sphere((-0.2, 0.1, 0.0), 0.15, friction=0.3, restitution=0.2)
    col.add_box((0.2, 0.1, 0.0), (0.15, 0.1, 0.15), rotation=(0.0, 0.38, 0.0, 0.92), friction=0.6)
    s0, s1 = m.state(), m.state()
    s0.particle_qd.assign(rng.normal(0.0, 1.0, size=(64, 3)))
    control = m.control()
    control.set_kinematic_targets(control.kinematic_targets.numpy() + 0.01)
    dt = 1e-2

    def integrate(x, v):
        wp.launch(
            _drift, m.particle_count, [wp.float64(dt), s0.particle_q, s0.particle_qd, x, v], device="cpu"
        )

    if not stages:
        finish_step(m, None, s0, s1, dt, integrate)
    else:
        g = ground_coefficients(m)
        finish_step(m, control, s0, s1, dt, integrate, ground=g, collisions=[col], ground_penalty=penalty)
    return np.concatenate([s1.particle_q.numpy(), s1.particle_qd.numpy()])


@pytest.mark.parametrize("penalty", [None, 1.0e4], ids=["projection", "penalty_friction"])
def test_recorded_and_plain_post_step_write_the_same_bits(penalty, capfd):
    """One path for the post-step: on a requires_grad model under a tape (fresh arrays per stage, Warp's
    read-then-write check on) the stages give exactly the bits of the in-place gradient-free step. (Warp
    checks only kernels whose module was built with the check on: the recorded run goes first.)"""
    prev = wp.config.verify_autograd_array_access
    wp.config.verify_autograd_array_access = True
    try:
        capfd.readouterr()
        with wp.Tape():
            recorded = _post_stages(True, penalty)
        err = capfd.readouterr().err
    finally:
        wp.config.verify_autograd_array_access = prev
    plain = _post_stages(False, penalty)
    assert "been read" not in "\n".join(ln for ln in err.splitlines() if "apply_deltas" not in ln), err
    np.testing.assert_array_equal(recorded, plain)
    # Every stage acted: without them the state differs in positions and velocities.
    free = _post_stages(False, penalty, stages=False)
    assert np.abs(plain - free)[:64].max() > 1e-3 and np.abs(plain - free)[64:].max() > 1e-1
