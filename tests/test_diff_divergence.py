"""pl.diff.rollout refuses a rollout that blew up (issue 27): an explicit step above its stability limit
gives a finite but meaningless loss (1e53 on the README cloth) long before anything overflows."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl


@wp.kernel
def _mean_height(q: wp.array(dtype=wp.vec3d), loss: wp.array(dtype=wp.float64)):
    wp.atomic_add(loss, 0, q[wp.tid()][1] / wp.float64(q.shape[0]))


def _cloth():
    b = pl.ModelBuilder()
    b.add_cloth_grid(
        nx=8, ny=8, size=1.0, mass=0.2, stiffness=300.0, origin=(-0.5, 0.9, -0.5), pin="top-corners"
    )
    model = b.finalize(device="cpu", dtype="float64", requires_grad=True)
    solver = pl.solvers.ForceSolver(model, pl.energies.mass_spring(), pl.integrators.RK4())

    def loss(state):
        out = wp.zeros(1, dtype=wp.float64, device="cpu", requires_grad=True)
        wp.launch(_mean_height, model.particle_count, [state.particle_q, out], device="cpu")
        return out

    return model, solver, loss


def _first_fast_frame(model, solver, dt, substeps, frames, max_speed=1e3):
    """Independent reference: plain stepping, checking after every frame."""
    s = model.state()
    for f in range(1, frames + 1):
        for _ in range(substeps):
            nxt = model.state()
            solver.step(s, nxt, None, dt)
            s = nxt
        v = s.particle_qd.numpy()
        if not np.all(np.isfinite(v)) or np.linalg.norm(v, axis=1).max() > max_speed:
            return f
    return None


@pytest.mark.parametrize("checkpoint_every", [1, 4])
def test_a_blown_up_rollout_names_its_first_diverged_frame(checkpoint_every):
    model, solver, loss = _cloth()
    dt, substeps, frames = 4e-3, 2, 10  # RK4 above its limit on this cloth: grows slowly, frame by frame
    first = _first_fast_frame(model, solver, dt, substeps, frames)
    assert first is not None and first > 1
    with pytest.raises(pl.DivergenceError) as e:
        pl.diff.rollout(
            model,
            solver,
            loss,
            frames=frames,
            substeps=substeps,
            dt=dt,
            params=["spring_stiffness"],
            checkpoint_every=checkpoint_every,
        )
    assert e.value.frame == first
    msg = str(e.value)
    assert msg.startswith(f"diverged at frame {first}:") and "lower dt (substep 0.004 s" in msg
    assert "implicit integrator" in msg


def test_a_stable_rollout_is_unchanged_and_a_nan_loss_is_refused():
    model, solver, loss = _cloth()
    res = pl.diff.rollout(model, solver, loss, frames=3, substeps=10, dt=5e-4, params=["spring_stiffness"])
    assert np.isfinite(res.loss) and np.all(np.isfinite(res.grads["spring_stiffness"]))

    def nan_loss(state):
        out = loss(state)
        return wp.array([np.nan], dtype=wp.float64, device="cpu", requires_grad=True) if out else out

    with pytest.raises(ValueError, match="loss_fn returned nan from a finite final state"):
        pl.diff.rollout(model, solver, nan_loss, frames=2, substeps=2, dt=5e-4)


def test_check_rollout_refuses_a_non_finite_gradient():
    model, solver, _ = _cloth()
    state = model.state()
    with pytest.raises(pl.DivergenceError, match="non-finite gradient of 'spring_stiffness'"):
        pl.diff.check_rollout(
            0.5,
            {"spring_stiffness": np.array([1.0, np.inf])},
            state,
            solver=solver,
            dt=1e-3,
            substeps=1,
            frames=4,
        )


def test_fit_gradient_stage_refuses_a_blown_up_rollout():
    """`pliant fit`'s gradient stage: a stiffness its substeps cannot carry is a one-line error naming the
    frames and the stability advice, not a NaN fit."""
    from pliant.fit import FitError, Problem, gradient_stage, observe
    from pliant.fit._params import apply_globals
    from tests.test_fit_stages import ROPE

    cfg = pl.scene.parse_scene(ROPE)
    obs = observe(pl.scene.build_scene(cfg), tracks=7)
    # Softer than the truth (50 N/m): the first Adam step raises every spring's k by e^8 (×3000), which the
    # scene's 10 substeps cannot carry.
    p = Problem(apply_globals(cfg, {"stiffness": 20.0}), obs, params=[], per_element="stiffness")
    with pytest.raises(
        FitError, match=r"rollout over frames \d+-\d+ blew up \(diverged at frame \d+: .*lower dt \(substep"
    ):
        gradient_stage(p, p.nominal, iterations=3, lr=8.0, max_factor=1e5)
