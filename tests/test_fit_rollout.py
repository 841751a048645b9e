"""One stepping loop (issue 25 item 3): pl.fit's gradient stage steps through pl.diff.rollout, so the fit and
a user's rollout give identical losses and gradients for the same rollout; both equal a plain ``wp.Tape``
frame × substep loop (the loop pl.fit had of its own), and a one-frame FrameStep equals the Simulator's
frames bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from helpers import FIT_ROPE

import pliant as pl
from pliant.fit import Problem, observe
from pliant.fit._gradient import _Rollout
from pliant.fit._losses import track_loss
from pliant.fit._params import apply_globals


@pytest.fixture(scope="module")
def problem():
    cfg = pl.scene.parse_scene(FIT_ROPE)
    obs = observe(pl.scene.build_scene(cfg), tracks=7)
    return Problem(apply_globals(cfg, {"stiffness": 80.0}), obs, params=[], per_element="stiffness")


def _user_loss(r: _Rollout):
    """The track term written as a user of pl.diff would: per frame, into the rollout's accumulator."""
    p = r.problem

    def frame_loss(g, s, out):
        track_loss(
            s.particle_q,
            r.particle,
            r.points[g],
            r.visible[g],
            out,
            beta=p.beta,
            weight=1.0,
            normaliser=r.track_norm,
        )

    return frame_loss


def test_fit_and_diff_give_identical_losses_and_gradients(problem):
    """The fit's whole-training-window rollout (its L-BFGS path) against pl.diff.rollout called directly with
    the same per-frame loss, and against a hand-written tape loop: the same loss and ∂L/∂k per spring."""
    n = problem.n_train - 1
    r = _Rollout(problem, problem.nominal, shared=False, n_train=problem.n_train)
    r.start()
    fit_loss, _ = r.run(0, n, reset=True)
    fit_grad = r.grads["spring_stiffness"]

    m, solver = r.scene.model, r.scene.solver
    res = pl.diff.rollout(
        m,
        solver,
        None,
        frames=n,
        dt=r.scene.frame_dt / r.scene.substeps,
        substeps=r.scene.substeps,
        params=["spring_stiffness"],
        frame_loss=_user_loss(r),
        checkpoint_every=3,  # checkpointed: recomputation must not change anything
    )
    assert res.loss == fit_loss
    np.testing.assert_allclose(res.grads["spring_stiffness"], fit_grad, rtol=1e-12, atol=0.0)

    # The loop pl.fit used to run itself: frames × substeps on one tape.
    m.spring_stiffness.grad.zero_()
    h = r.scene.frame_dt / r.scene.substeps
    loss = wp.zeros(1, dtype=m.scalar, requires_grad=True)
    tape = wp.Tape()
    with tape:
        s = m.state()
        for f in range(n):
            for _ in range(r.scene.substeps):
                nxt = m.state()
                solver.step(s, nxt, m.control(), h)
                s = nxt
            _user_loss(r)(f + 1, s, loss)
    tape.backward(loss)
    assert float(loss.numpy()[0]) == pytest.approx(fit_loss, rel=1e-13)
    np.testing.assert_allclose(m.spring_stiffness.grad.numpy(), fit_grad, rtol=1e-10, atol=1e-14)
    assert np.abs(fit_grad).max() > 0


def test_rollout_adds_frame_losses_and_final_loss(problem):
    """frame_loss and loss_fn together: the rollout's loss is their sum and its gradient the sum of theirs."""
    r = _Rollout(problem, problem.nominal, shared=False, n_train=problem.n_train)
    m, solver, sc = r.scene.model, r.scene.solver, r.scene
    w = wp.array(np.random.default_rng(0).normal(size=(m.particle_count, 3)), dtype=m.vec3)

    @wp.kernel
    def dot(x: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d), out: wp.array(dtype=wp.float64)):
        i = wp.tid()
        wp.atomic_add(out, 0, wp.dot(x[i], w[i]))

    def final(s):
        out = wp.zeros(1, dtype=m.scalar, requires_grad=True)
        wp.launch(dot, m.particle_count, [s.particle_q, w, out])
        return out

    kw = dict(frames=4, dt=sc.frame_dt / sc.substeps, substeps=sc.substeps, params=["spring_stiffness"])
    a = pl.diff.rollout(m, solver, final, **kw)
    b = pl.diff.rollout(m, solver, None, frame_loss=_user_loss(r), **kw)
    both = pl.diff.rollout(m, solver, final, frame_loss=_user_loss(r), checkpoint_every=2, **kw)
    assert both.loss == pytest.approx(a.loss + b.loss, rel=1e-13)
    np.testing.assert_allclose(
        both.grads["spring_stiffness"], a.grads["spring_stiffness"] + b.grads["spring_stiffness"], rtol=1e-10
    )
    with pytest.raises(ValueError, match="give loss_fn"):
        pl.diff.rollout(m, solver, None, **kw)


def test_frame_step_is_the_simulators_frame(problem):
    """FrameStep in ping-pong mode (what the Simulator and the benchmarks run) and in fresh-state mode (what
    rollouts record) end a frame at the same positions, bit for bit."""
    scene = problem.build(problem.nominal)
    m, solver = scene.model, scene.solver
    h = scene.frame_dt / scene.substeps
    sim = pl.Simulator(m, solver, frame_dt=scene.frame_dt, substeps=scene.substeps)
    for _ in range(3):
        sim.step_frame()
    frame = pl.solvers.FrameStep(solver, h, scene.substeps)
    fresh = pl.solvers.FrameStep(solver, h, scene.substeps, fresh=True)
    s0, s1, s = m.state(), m.state(), m.state()
    for _ in range(3):
        s0, s1 = frame(s0, m.control(), s1)
        s, _ = fresh(s, m.control())
    np.testing.assert_array_equal(s0.particle_q.numpy(), sim.state_0.particle_q.numpy())
    np.testing.assert_array_equal(s.particle_q.numpy(), sim.state_0.particle_q.numpy())
    with pytest.raises(ValueError, match="substeps must be an integer >= 1"):
        pl.solvers.FrameStep(solver, h, 0)
