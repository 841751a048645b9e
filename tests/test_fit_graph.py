"""Fitting with captured graphs (issue 24 item 4), on the CPU (Warp's CPU graphs): a CMA-ES generation's
batched simulation replays its frames, and the gradient stage replays each horizon's taped rollout as one
graph; both give the numbers of ``PLIANT_GRAPH=0`` bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import FIT_ROPE
from test_fit_defaults import CLOTH_ET
from test_fit_stages import POINTS

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


#: FIT_ROPE's solver line per case.
ROPE_SOLVERS = {
    "explicit": 'integrator = "SymplecticEuler"',
    "fast_mass_spring": 'kind = "fast_mass_spring"',
    "implicit": 'integrator = "BackwardEuler"',
    "implicit_lbfgs": 'integrator = "BackwardEuler"\noptions = { minimizer = { method = "lbfgs" } }',
}
#: A pbd point cloud under XPBD, searched in its spring radius (topology: a batchable parameter that no
#: in-place write can give).
PBD_BLOB = (
    POINTS.replace('kind = "points"', 'kind = "points"\nmodel = "pbd"').replace(
        "origin = [0.0, 0.3, 0.0]", "origin = [0.0, 0.07, 0.0]"
    )
    + '[ground]\nheight = 0.0\n[solver]\nkind = "xpbd"\niterations = 4\n'
)
CMAES = {
    "explicit": "reused across generations",
    "fast_mass_spring": "reused across generations",
    "implicit": "reused across generations",
    "implicit_lbfgs": r"ForceSolver\(BackwardEuler\) with L-BFGS keeps a lagged Hessian",
    "xpbd_topology": "radius is not held in the model's per-element arrays",
}


def _cmaes_problem(case: str) -> Problem:
    if case == "xpbd_topology":
        cfg, params = pl.scene.parse_scene(PBD_BLOB), ["radius"]
    else:
        cfg = pl.scene.parse_scene(FIT_ROPE.replace(ROPE_SOLVERS["explicit"], ROPE_SOLVERS[case]))
        params = ["stiffness", "damping"]
    return Problem(cfg, observe(pl.scene.build_scene(cfg), tracks=6, seed=3, noise=0.001), params=params)


@pytest.mark.parametrize("case", list(CMAES))
def test_cmaes_runs_every_generation_on_one_scene_where_it_is_exact(case, monkeypatch, caplog):
    """A CMA-ES run keeps one batched scene and its captured frame graphs across generations, the
    candidates' values written into the model's arrays in place, where the solver reads those arrays in its
    step (explicit ForceSolver, an implicit one with Newton) or packs them again in place (FastMassSpring): 2
    captures for the whole run where frames replay (the start's own run and the batched scene) instead of one
    per generation, and every generation's losses those of a scene built per generation launch by launch,
    bit for bit. Solvers that cache what the arrays give (L-BFGS's lagged Hessian) and topology parameters
    (XPBD point cloud) build a scene per generation, and say why."""
    import logging
    import re

    import pliant.fit._cmaes as cm
    from pliant.fit._reuse import BatchScenes

    p = _cmaes_problem(case)
    assert batchable(p)
    gens = 4
    trail: list[list[float]] = []
    real = cm.evaluate_batch

    def record(problem, cands, scenes=None):
        out = real(problem, cands, scenes)
        trail.append(out)
        return out

    monkeypatch.setattr(cm, "evaluate_batch", record)
    held: list[BatchScenes] = []
    init = BatchScenes.__init__

    def keep(self, *args, **kwargs):
        held.append(self)
        init(self, *args, **kwargs)

    monkeypatch.setattr(BatchScenes, "__init__", keep)
    stores = _spy(monkeypatch, sim_graph.FrameGraphs)
    with caplog.at_level(logging.INFO, logger="pliant.fit"):
        reused = cm.cmaes(p, generations=gens, rtol=0.0)
    assert len(trail) == gens and len({len(t) for t in trail}) == 1
    (scenes,) = held
    assert [r.getMessage() for r in caplog.records if "CMA-ES" in r.getMessage()] == [
        caplog.records[-1].getMessage()
    ]  # one line for the run
    assert re.search(CMAES[case], caplog.text), caplog.text
    captures = sum(s.captures for s in stores)
    solver = p.build(p.nominal).solver
    # A frame that is one fused launch (FastMassSpring on the CPU) runs directly: nothing to capture.
    graphs = solver.graph_blocker() is None and not solver.frame_is_one_launch()
    if CMAES[case] == "reused across generations":
        assert (scenes.built, scenes.reused) == (1, gens - 1)
        if graphs:
            assert captures == 2, [(s.captures, s.replays) for s in stores]
            # every frame of a later generation is a replay
            assert max(s.replays for s in stores) >= gens * (p.n_train - 1) - 3
        else:  # a host minimiser or a fused frame: launch by launch, the scene still built once
            assert captures == 0
    else:
        # a scene per generation: a capture each, and one for the start (none where the step reads the host)
        assert (scenes.built, scenes.reused) == (gens, 0) and captures == (1 + gens if graphs else 0)
    with_reuse = np.array(trail)
    trail.clear()
    monkeypatch.setenv("PLIANT_GRAPH", "0")
    rebuilt = cm.cmaes(p, generations=gens, rtol=0.0, reuse=False)
    assert held[-1].built == gens
    assert np.array(trail).tobytes() == with_reuse.tobytes()
    assert np.array(rebuilt.history).tobytes() == np.array(reused.history).tobytes()
    assert any(len(set(t)) > 1 for t in with_reuse)  # the candidates differ: the written values act


def test_xpbd_takes_spring_stiffness_written_in_place():
    """XPBD converts spring k to compliances when it binds its constraints: after a new k is written into the
    model, ``refresh_parameters`` binds them again into the same arrays, and the restarted Simulator
    replays its captured graph (no new capture) to the trajectory of a scene built with that k, bit for
    bit."""
    text = FIT_ROPE.replace('kind = "rope"', 'kind = "rope"\nmodel = "pbd"').replace(
        'integrator = "SymplecticEuler"', 'kind = "xpbd"\niterations = 4'
    )
    cfg = pl.scene.parse_scene(text)
    held = pl.scene.build_scene(cfg)
    sim = pl.Simulator(held.model, held.solver, **held.sim_kwargs)
    before = sim.run(6, progress=False).x
    k = held.model.spring_stiffness.numpy()
    assert np.all(k == 50.0)
    held.model.spring_stiffness.assign(np.full_like(k, 7.0))
    assert held.solver.refresh_parameters() is None
    sim.restart()
    after = sim.run(6, progress=False).x
    cfg.objects[0].material.stiffness = 7.0
    fresh = pl.scene.build_scene(cfg)
    direct = pl.Simulator(fresh.model, fresh.solver, graph=False, **fresh.sim_kwargs).run(6, progress=False).x
    assert after.tobytes() == direct.tobytes()
    assert not np.array_equal(after, before)  # the new k acts
    assert sim._graphs is not None and sim._graphs.captures == 1


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


@pytest.mark.parametrize("case", ["bend_springs", "Et"])
def test_values_written_in_place_are_the_rebuilt_scenes(case):
    """The second generation's values written into the held model give its parameter arrays exactly as a
    scene built for them (a rope with bend springs: stiffness sets the structural springs only, damping
    all); a value the scene derives (a cloth's Et → structural and shear k) is not written: rebuilt."""
    from pliant.fit._reuse import BatchScenes, build_batch

    if case == "Et":
        text, params = CLOTH_ET, ["Et", "damping"]
    else:
        text, params = FIT_ROPE.replace("stiffness = 50.0", "stiffness = 50.0\nbend_stiffness = 5.0"), None
    cfg = pl.scene.parse_scene(text)
    names = params or ["stiffness", "damping"]
    p = Problem(cfg, observe(pl.scene.build_scene(cfg), tracks=4, seed=3), params=names)
    gen1 = [{names[0]: 30.0 + w, "damping": 0.01 + 0.001 * w} for w in range(3)]
    gen2 = [{names[0]: 70.0 - w, "damping": 0.02 - 0.001 * w} for w in range(3)]
    scenes = BatchScenes()
    first, _ = scenes.get(p, gen1)
    second, sim = scenes.get(p, gen2)
    rebuilt = build_batch(p, gen2)
    if case == "Et":
        assert scenes.reason == "the scene derives spring_stiffness from Et (no element holds the value)"
        assert second is not first and sim is None and (scenes.built, scenes.reused) == (2, 0)
        return
    assert scenes.reason is None and second is first and sim is not None and scenes.reused == 1
    k = second.model.spring_stiffness.numpy()
    assert np.count_nonzero(k == 5.0) > 0 and np.count_nonzero(k == 5.0) < k.size  # bend springs kept
    for name in ("spring_stiffness", "spring_damping", "spring_rest_length", "particle_mass"):
        assert getattr(second.model, name).numpy().tobytes() == getattr(rebuilt.model, name).numpy().tobytes()
