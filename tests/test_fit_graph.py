"""Fitting with captured graphs (issue 24 item 4), on the CPU (Warp's CPU graphs): a CMA-ES generation's
batched simulation replays its frames, and the gradient stage replays each horizon's taped rollout as one
graph; both give the numbers of ``PLIANT_GRAPH=0`` bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import FIT_ROPE

import pliant as pl
from pliant.diff import _graph as diff_graph
from pliant.fit import Problem, gradient_stage, observe
from pliant.fit._cmaes import batchable, evaluate_batch
from pliant.fit._gradient import _Rollout
from pliant.fit._params import apply_globals
from pliant.sim import _graph as sim_graph


@pytest.fixture(scope="module")
def truth():
    cfg = pl.scene.parse_scene(FIT_ROPE)
    return cfg, observe(pl.scene.build_scene(cfg), tracks=6, seed=3, noise=0.001)


def _spy(monkeypatch, cls) -> list:
    """Every graph store of ``cls`` that ran a frame or rollout, in order."""
    seen: list = []
    run = cls.run

    def spy(self, *args, **kwargs):
        if all(s is not self for s in seen):
            seen.append(self)
        return run(self, *args, **kwargs)

    monkeypatch.setattr(cls, "run", spy)
    return seen


def test_cmaes_generation_replays_its_frames(truth, monkeypatch):
    """One generation (three candidates as copies in one model) is one Simulator: its frames are replayed
    from one capture, and the losses equal those of launch-by-launch frames bit for bit."""
    cfg, obs = truth
    p = Problem(cfg, obs, params=["stiffness", "damping"])
    assert batchable(p)
    cands = [{"stiffness": k, "damping": g} for k, g in ((30.0, 0.01), (50.0, 0.02), (90.0, 0.005))]
    stores = _spy(monkeypatch, sim_graph.FrameGraphs)
    replayed = evaluate_batch(p, cands)
    (store,) = stores  # one simulation for the whole generation
    frames = p.n_train - 1
    # A new scene each generation: its first frame runs directly (and a solver that allocates on its first
    # step changes the key once more), its second is captured; every other frame is a replay.
    assert store.captures == 1 and store.replays >= frames - 3, (store.captures, store.replays)
    monkeypatch.setenv("PLIANT_GRAPH", "0")
    stores.clear()
    direct = evaluate_batch(p, cands)
    assert stores == []  # no graph store at all: launch by launch
    assert np.array(replayed).tobytes() == np.array(direct).tobytes()


CASES = {
    "one_frame_horizons": dict(shooting=0, kw=dict(iterations=4, lr=0.05)),
    "acceleration_shooting_h3": dict(shooting=3, acc=0.01, kw=dict(iterations=4, lr=0.05, horizon=3)),
    "shooting_smoothness": dict(shooting=2, kw=dict(iterations=3, lr=0.05, smoothness=0.1)),
    "lbfgs": dict(shooting=0, kw=dict(iterations=4, optimizer="lbfgs")),
}


@pytest.mark.parametrize("case", list(CASES))
def test_gradient_stage_replays_horizons_bit_for_bit(truth, monkeypatch, case):
    """The gradient stage's horizons are replayed graphs (one capture per horizon shape: frames, history
    depth, reset) and its losses and parameter trajectory equal ``PLIANT_GRAPH=0``'s bit for bit, with the
    acceleration term's history, teacher forcing and L-BFGS."""
    cfg, obs = truth
    c = CASES[case]
    p = Problem(
        apply_globals(cfg, {"stiffness": 120.0}),
        obs,
        params=[],
        per_element="stiffness",
        shooting=c["shooting"],
        acceleration_weight=c.get("acc", 0.0),
    )
    trail: list[np.ndarray] = []
    set_theta = _Rollout.set_theta

    def record(self, theta):
        trail.append(np.array(theta))
        set_theta(self, theta)

    monkeypatch.setattr(_Rollout, "set_theta", record)
    stores = _spy(monkeypatch, diff_graph.RolloutGraphs)
    graphed = gradient_stage(p, p.nominal, **c["kw"])
    (g,) = stores
    runs = g.captures + g.replays + g.direct
    assert runs == graphed.evaluations
    # Each shape costs at most a direct first call, one more when the solver allocates on its first step,
    # and a capture; every other horizon is a replay.
    assert g.replays > 0 and g.replays >= runs - 3 * g.captures - 1, (g.captures, g.replays, g.direct)
    with_graphs = list(trail)

    monkeypatch.setenv("PLIANT_GRAPH", "0")
    trail.clear()
    stores.clear()
    direct = gradient_stage(p, p.nominal, **c["kw"])
    assert stores == []  # launch by launch
    assert np.array(graphed.history).tobytes() == np.array(direct.history).tobytes()
    assert len(with_graphs) == len(trail) == direct.evaluations
    for a, b in zip(with_graphs, trail, strict=True):
        assert a.tobytes() == b.tobytes()
    for k, v in direct.per_element.items():
        assert graphed.per_element[k].tobytes() == v.tobytes()


def test_restart_replays_the_same_run():
    """``Simulator.restart`` goes back to frame 0 keeping the captured graphs: the second run is the first
    bit for bit, every frame a replay."""
    scene = pl.scene.build_scene(pl.scene.parse_scene(FIT_ROPE))
    sim = pl.Simulator(scene.model, scene.solver, **scene.sim_kwargs)
    first = sim.run(8, progress=False).x
    g = sim._graphs
    assert g is not None and g.captures == 1
    replays = g.replays
    sim.restart()
    assert sim.frame == 0 and sim.time == 0.0
    second = sim.run(8, progress=False).x
    assert second.tobytes() == first.tobytes()
    assert g.captures == 1 and g.replays - replays == 8
