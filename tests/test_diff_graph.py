"""Differentiable rollouts replayed as captured graphs (pliant.diff._graph): the forward launches, the tape's
backward pass and the losses of a repeated pl.diff.rollout replay as one graph, with the direct run's loss,
gradients and end state bit for bit; what cannot be replayed runs directly and is reported once."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import warp as wp
from test_devices_grad import ROWS, _weighted_sum, weighted_loss

import pliant as pl
from pliant.diff import _graph


def _setup(row: str):
    make_model, make_solver, name, frames, substeps, dt, every, _ = ROWS[row]
    m = make_model("cpu")
    solver = make_solver(m)
    loss = weighted_loss(m, "cpu")
    entry = pl.diff.PARAMETERS[name](m, solver, m.state(), None)
    kw = {"frames": frames, "substeps": substeps, "dt": dt, "params": [name, "v0"]}
    return m, solver, loss, entry, kw, every


def _same(a: pl.diff.RolloutResult, b: pl.diff.RolloutResult) -> None:
    assert np.float64(a.loss).tobytes() == np.float64(b.loss).tobytes()
    for k in b.grads:
        np.testing.assert_array_equal(a.grads[k], b.grads[k])
    assert a.state is not None and b.state is not None
    np.testing.assert_array_equal(a.state.particle_q.numpy(), b.state.particle_q.numpy())
    np.testing.assert_array_equal(a.state.particle_qd.numpy(), b.state.particle_qd.numpy())


@pytest.mark.parametrize("whole", [False, True], ids=["checkpointed", "one-tape"])
@pytest.mark.parametrize(
    "row",
    ["springs-symplectic", "fem-explicit", "xpbd-jacobi", "fast-mass-spring", "fast-mass-spring-implicit"],
)
def test_replayed_rollouts_equal_direct_ones_bit_for_bit(row: str, whole: bool) -> None:
    """A gradient loop (the parameter changed in place before every call): from the third call on the
    rollout is replayed, and every call's loss, gradients and end state equal a direct run's exactly."""
    m, solver, loss, param, kw, every = _setup(row)
    every = kw["frames"] if whole else 1
    base = param.numpy().copy()
    replayed = []
    for i in range(4):
        param.assign(base * (1.0 + 0.01 * i))
        res = pl.diff.rollout(m, solver, loss, checkpoint_every=every, **kw)
        _same(res, pl.diff.rollout(m, solver, loss, checkpoint_every=every, graph=False, **kw))
        replayed.append(res.replayed)
    assert replayed == [False, False, True, True]
    graphs = _graph.rollout_graphs(solver)
    assert graphs.captures == 1 and graphs.replays == 2


def test_replayed_gradient_equals_central_differences() -> None:
    """The replayed ∂loss/∂(spring damping) along a random direction equals central differences taken with
    direct rollouts (relative 1e-4)."""
    m, solver, loss, param, kw, every = _setup("springs-symplectic")
    for _ in range(3):
        res = pl.diff.rollout(m, solver, loss, checkpoint_every=every, **kw)
    assert res.replayed
    base = param.numpy().copy()
    d = np.random.default_rng(1).normal(size=base.shape) * base
    h = 1e-3

    def at(eps: float) -> float:
        param.assign(base + eps * d)
        return pl.diff.rollout(m, solver, loss, checkpoint_every=every, graph=False, **kw).loss

    fd = (at(h) - at(-h)) / (2 * h)
    assert abs(fd) > 1e-10
    assert float(np.sum(res.grads[kw["params"][0]] * d)) == pytest.approx(fd, rel=1e-4)


def test_frame_losses_and_moving_controls_replay() -> None:
    """A trajectory loss (frame_loss) and a force that changes every frame (control_fn writing host values):
    the replays equal direct runs bit for bit, including ∂loss/∂(particle force)."""
    m, solver, _, _, kw, _ = _setup("springs-symplectic")
    w = wp.array(np.random.default_rng(2).normal(size=(m.particle_count, 3)), dtype=wp.vec3d)
    forces = np.random.default_rng(3).normal(scale=1e-2, size=(kw["frames"], m.particle_count, 3))

    def frame_loss(frame: int, state: pl.State, out: wp.array) -> None:
        wp.launch(_weighted_sum, state.particle_q.shape[0], [state.particle_q, w, out])

    def control_fn(frame: int, control: pl.Control) -> None:
        control.particle_f.assign(forces[frame])

    kw = {**kw, "params": ["particle_f", "v0"], "frame_loss": frame_loss, "control_fn": control_fn}
    control = m.control()
    for _ in range(4):  # the first call makes the control's gradient buffers: a new key after it
        res = pl.diff.rollout(m, solver, None, control=control, **kw)
    assert res.replayed
    _same(res, pl.diff.rollout(m, solver, None, control=control, graph=False, **kw))
    assert np.abs(res.grads["particle_f"]).max() > 0


def test_returned_state_is_not_overwritten_by_the_next_replay() -> None:
    m, solver, loss, param, kw, every = _setup("springs-symplectic")
    results = [pl.diff.rollout(m, solver, loss, checkpoint_every=every, **kw) for _ in range(3)]
    assert results[2].replayed
    x = results[2].state.particle_q.numpy().copy()
    param.assign(param.numpy() * 2.0)
    assert pl.diff.rollout(m, solver, loss, checkpoint_every=every, **kw).replayed
    np.testing.assert_array_equal(results[2].state.particle_q.numpy(), x)


def test_implicit_rollouts_run_directly_and_say_why_once(caplog) -> None:
    """Backward Euler's adjoint is a linear solve run from Python: its rollouts are never captured, the
    reason is on the result, and the log says so once per process."""
    _graph._REPORTED.clear()
    m, solver, loss, _, kw, every = _setup("implicit-backward-euler")
    with caplog.at_level(logging.INFO, logger="pliant"):
        results = [pl.diff.rollout(m, solver, loss, checkpoint_every=every, **kw) for _ in range(3)]
    assert not any(r.replayed for r in results)
    assert all(
        "BackwardEuler is differentiated by the implicit-function adjoint" in (r.graph_reason or "")
        for r in results
    )
    lines = [r.message for r in caplog.records if "no graph" in r.message]
    assert len(lines) == 1 and "BackwardEuler" in lines[0]


def test_a_host_read_in_the_loss_is_caught_by_the_check() -> None:
    """A loss computed on the host (it reads the state with .numpy()) would replay a stale value: the
    capturing call's comparison with a direct run finds the difference, the rollout runs directly from then
    on, and every result is the direct one."""
    m, solver, _, param, kw, every = _setup("springs-symplectic")

    def host_loss(state: pl.State) -> wp.array:
        value = float(np.sum(state.particle_q.numpy()[:, 1]))
        return wp.array([value], dtype=wp.float64, requires_grad=True)

    kw = {**kw, "params": []}
    values = []
    for i in range(4):
        param.assign(param.numpy() * 1.1)
        res = pl.diff.rollout(m, solver, host_loss, checkpoint_every=every, **kw)
        assert (
            res.loss == pl.diff.rollout(m, solver, host_loss, checkpoint_every=every, graph=False, **kw).loss
        )
        assert not res.replayed
        values.append(res.loss)
    assert "differed from the direct run" in (res.graph_reason or "")
    assert len(set(values)) == 4


def test_a_new_closure_each_call_is_a_new_key() -> None:
    """Callbacks are keyed by identity: a loss made afresh for every call (it may launch something else)
    is never replayed, and the remembered keys stay bounded."""
    m, solver, _, _, kw, every = _setup("springs-symplectic")
    w = wp.array(np.ones((m.particle_count, 3)), dtype=wp.vec3d)
    for _ in range(3 * _graph._MAX_WARM):

        def loss(state: pl.State) -> wp.array:
            out = wp.zeros(1, dtype=wp.float64, requires_grad=True)
            wp.launch(_weighted_sum, state.particle_q.shape[0], [state.particle_q, w, out])
            return out

        assert not pl.diff.rollout(m, solver, loss, checkpoint_every=every, **kw).replayed
    graphs = _graph.rollout_graphs(solver)
    assert graphs.captures == 0 and len(graphs._entries) <= _graph._MAX_WARM


def test_environment_switch_turns_rollout_graphs_off(monkeypatch) -> None:
    monkeypatch.setenv("PLIANT_GRAPH", "0")
    m, solver, loss, _, kw, every = _setup("springs-symplectic")
    results = [pl.diff.rollout(m, solver, loss, checkpoint_every=every, **kw) for _ in range(3)]
    assert not any(r.replayed for r in results) and results[-1].graph_reason == "graph=False"
    assert _graph.rollout_graphs(solver).captures == 0


def test_a_python_callback_on_the_tape_keeps_the_rollout_direct(monkeypatch: pytest.MonkeyPatch) -> None:
    """A Python callback recorded with wp.Tape.record_func and not marked ``graph_safe`` (here
    FastMassSpring's implicit adjoint with its mark taken off): the capturing call finds it on the tape,
    names it, and every call returns the direct run's numbers."""
    from pliant.solvers.fast_mass_spring._adjoint import _Adjoint

    monkeypatch.setattr(_Adjoint.backward, "graph_safe", False)
    m, solver, loss, param, kw, every = _setup("fast-mass-spring-implicit")
    for _ in range(3):
        param.assign(param.numpy() * 1.01)
        res = pl.diff.rollout(m, solver, loss, checkpoint_every=every, **kw)
        _same(res, pl.diff.rollout(m, solver, loss, checkpoint_every=every, graph=False, **kw))
        assert not res.replayed
    assert "Python callbacks (_Adjoint.backward)" in (res.graph_reason or "")
    assert _graph.rollout_graphs(solver).captures == 0


def test_a_target_rebound_to_a_new_array_is_a_new_key() -> None:
    """The loss reads a target array from its closure: rebinding it to a new array between calls (instead of
    assign) changes what the callback reads, so the call is not replayed with the old array; every result
    equals the direct run's."""
    m, solver, _, _, kw, every = _setup("springs-symplectic")
    rng = np.random.default_rng(4)
    target = wp.array(rng.normal(size=(m.particle_count, 3)), dtype=wp.vec3d)

    def loss(state: pl.State) -> wp.array:
        out = wp.zeros(1, dtype=wp.float64, requires_grad=True)
        wp.launch(_weighted_sum, state.particle_q.shape[0], [state.particle_q, target, out])
        return out

    for _ in range(3):
        pl.diff.rollout(m, solver, loss, checkpoint_every=every, **kw)
    target = wp.array(rng.normal(size=(m.particle_count, 3)), dtype=wp.vec3d)
    res = pl.diff.rollout(m, solver, loss, checkpoint_every=every, **kw)
    assert not res.replayed
    _same(res, pl.diff.rollout(m, solver, loss, checkpoint_every=every, graph=False, **kw))
