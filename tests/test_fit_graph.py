"""Fitting with captured graphs (issue 24 item 4), on the CPU (Warp's CPU graphs): a CMA-ES generation's
batched simulation replays its frames, with the numbers of ``PLIANT_GRAPH=0`` bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import FIT_ROPE

import pliant as pl
from pliant.fit import Problem, observe
from pliant.fit._cmaes import batchable, evaluate_batch
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
