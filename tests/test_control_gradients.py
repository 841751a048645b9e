"""Gradients w.r.t. a control path: ControlPoints (PhysTwin's hand / gripper springs) moved every step by
per-step Warp arrays; ∂loss/∂(every step's control positions) from the plain wp.Tape path equals central
finite differences (float64), explicit (symplectic Euler) and implicit (backward Euler, IFT adjoint)."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
import warp as wp

import pliant as pl

STEPS = 20
DT = 2e-3


@wp.kernel
def _dot(x: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d), out: wp.array(dtype=wp.float64)):
    i = wp.tid()
    wp.atomic_add(out, 0, wp.dot(x[i], w[i]))


def _model():
    b = pl.ModelBuilder()
    b.add_rope(
        n_segments=8, length=0.4, mass=0.1, stiffness=300.0, damping=0.02, start=(0.0, 0.3, 0.0), pin="none"
    )
    return b.finalize(device="cpu", dtype="float64", requires_grad=True)


def _integrator(name: str):
    if name == "symplectic":
        return pl.integrators.SymplecticEuler()
    return pl.integrators.BackwardEuler(newton_tol=1e-12, max_newton_iterations=50)


def _path(delta: np.ndarray | None = None) -> np.ndarray:
    """[STEPS, 2, 3] control positions: the rope's two ends lifted and pulled apart over the rollout."""
    t = np.arange(1, STEPS + 1)[:, None] * DT
    p = np.stack(
        [
            np.array([[0.0, 0.3, 0.0]]) + t * [-0.5, 1.0, 0.0],
            np.array([[0.4, 0.3, 0.0]]) + t * [0.5, 1.0, 0.2],
        ],
        1,
    )
    return p if delta is None else p + delta


def _run(integ: str, path: np.ndarray, w: wp.array, record: bool):
    m = _model()
    # Links and their rest lengths from the unperturbed start, so that only the path varies.
    handle = pl.energies.ControlPoints(m, _path()[0], stiffness=500.0, radius=0.01, max_links=1)
    energies = [*pl.energies.mass_spring(), handle]
    solver = pl.solvers.ForceSolver(m, energies, _integrator(integ))
    arrays = [wp.array(p, dtype=wp.vec3d, requires_grad=True) for p in path]
    tape = wp.Tape() if record else None
    s = m.state()
    with tape if record else contextlib.nullcontext():
        for k in range(STEPS):
            handle.set_positions(arrays[k])
            n = m.state()
            solver.step(s, n, None, DT)
            s = n
        loss = wp.zeros(1, dtype=wp.float64, requires_grad=True)
        wp.launch(_dot, m.particle_count, [s.particle_q, w, loss])
    if record:
        tape.backward(loss)
        return float(loss.numpy()[0]), np.stack([a.grad.numpy() for a in arrays])
    return float(loss.numpy()[0]), None


@pytest.mark.parametrize("integ", ["symplectic", "backward_euler"])
def test_control_path_gradient_equals_central_differences(integ):
    w = wp.array(np.random.default_rng(2).normal(size=(9, 3)), dtype=wp.vec3d)
    path = _path()
    loss, grad = _run(integ, path, w, record=True)
    assert loss == pytest.approx(_run(integ, path, w, record=False)[0], rel=1e-12)
    # Every step's control positions matter (the gradient is not only on the last one).
    assert np.abs(grad[: STEPS // 2]).max() > 1e-6
    d = np.random.default_rng(4).normal(size=path.shape)
    eps = 1e-6
    fd = (_run(integ, _path(eps * d), w, False)[0] - _run(integ, _path(-eps * d), w, False)[0]) / (2 * eps)
    assert abs(fd) > 1e-8
    assert float(np.sum(grad * d)) == pytest.approx(fd, rel=1e-5 if integ == "symplectic" else 1e-4)


def test_control_points_reject_a_wrong_array():
    m = _model()
    handle = pl.energies.ControlPoints(m, [[0.0, 0.3, 0.0]], stiffness=500.0, radius=0.01)
    with pytest.raises(ValueError, match="expected a wp.array of 1"):
        handle.set_positions(wp.zeros(2, dtype=wp.vec3d))
