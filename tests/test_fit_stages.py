"""Each fitting stage recovers a known parameter of a tiny scene from pliant's own synthetic observations
(pliant → pliant, known truth), and bad set-ups fail with one clear line."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import FIT_ROPE

import pliant as pl
from pliant.fit import FitError, Problem, cmaes, gradient_stage, observe
from pliant.fit._params import apply_globals

ROPE = FIT_ROPE

CLOTH_XPBD = """
[scene]
name = "tiny_cloth"
frame_dt = 0.04
substeps = 4
frames = 16
dtype = "float64"
device = "cpu"
[[objects]]
kind = "cloth"
model = "pbd"
nx = 4
ny = 4
size = 0.4
origin = [-0.2, 0.5, -0.2]
plane = "xz"
mass = 0.05
pin = "top-corners"
[objects.material]
compliance = 1e-2
[solver]
kind = "xpbd"
iterations = 4
"""


def _truth(text: str, tracks: int):
    cfg = pl.scene.parse_scene(text)
    return cfg, observe(pl.scene.build_scene(cfg), tracks=tracks)


def test_cmaes_recovers_rope_stiffness_and_damping():
    """Start at 2× the stiffness and 0.4× the damping rate; CMA-ES finds the stiffness within 3 % (the damping
    rate barely acts over 0.3 s of training frames: within 10 % here; the slow study checks 2 %)."""
    cfg, obs = _truth(ROPE, tracks=7)
    wrong = apply_globals(cfg, {"stiffness": 100.0, "damping_rate": 0.2})
    p = Problem(wrong, obs, params=["stiffness", "damping_rate"])
    r = cmaes(p, generations=20, seed=1)
    assert r.values["stiffness"] == pytest.approx(50.0, rel=0.03)
    assert r.values["damping_rate"] == pytest.approx(0.5, rel=0.1)
    assert r.history[-1] <= r.history[0] and r.loss < 1e-2 * p.loss(p.simulate(p.build(p.nominal), p.n_train))


def test_gradient_stage_recovers_rope_stiffness():
    """Mass-spring (ForceSolver + symplectic Euler) tape gradients, one-frame horizon, Adam on a shared log
    factor: from 2× the stiffness back to within 1 %."""
    cfg, obs = _truth(ROPE, tracks=7)
    p = Problem(apply_globals(cfg, {"stiffness": 100.0}), obs, params=[], per_element="stiffness")
    r = gradient_stage(p, p.nominal, iterations=12, lr=0.1, shared=True)
    k = r.per_element["model.spring_stiffness"]
    assert np.allclose(k, k[0]) and k[0] == pytest.approx(50.0, rel=0.01)
    assert r.history[-1] < 1e-2 * r.history[0]


def test_gradient_stage_recovers_xpbd_compliance():
    """XPBD (differentiable Jacobi sweeps): compliance from 3× back to within 1 % on a 4×4 cloth."""
    cfg, obs = _truth(CLOTH_XPBD, tracks=25)
    p = Problem(apply_globals(cfg, {"compliance": 3e-2}), obs, params=[], per_element="compliance")
    r = gradient_stage(p, p.nominal, iterations=12, lr=0.1, shared=True)
    (alpha,) = r.per_element.values()
    assert alpha[0] == pytest.approx(1e-2, rel=0.01)


def test_a_gradient_that_is_exactly_zero_is_an_error():
    """Every particle pinned: no parameter moves the tracks, and the stage says so instead of 'converging'."""
    cfg = pl.scene.parse_scene(ROPE.replace('pin = "first"', "pin = [0, 1, 2, 3, 4, 5, 6]"))
    obs = observe(pl.scene.build_scene(cfg), tracks=7)
    obs.points[1:] += 0.01  # observed motion the pinned rope cannot follow: a non-zero loss
    p = Problem(cfg, obs, params=[], per_element="stiffness")
    with pytest.raises(FitError, match="exactly zero gradient for 'stiffness'"):
        gradient_stage(p, p.nominal, iterations=1)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"params": ["stifness"]}, r"--params: unknown parameter 'stifness'; the global parameters are"),
        (
            {"params": ["E"]},
            r"--params: 'E' .* does not exist in this scene; it has stiffness, damping_rate, damping",
        ),
        ({"params": []}, r"nothing to fit"),
        ({"params": [], "per_element": "volume"}, r"--per-element: unknown parameter 'volume'"),
        ({"params": [], "per_element": "E"}, r"--per-element: this scene's model has no tetrahedra"),
        ({"train_fraction": 1.5}, r"--train-fraction"),
    ],
)
def test_bad_setups_are_one_line_errors(kwargs, match):
    cfg, obs = _truth(ROPE, tracks=3)
    with pytest.raises(FitError, match=match):
        Problem(cfg, obs, **kwargs)


def test_observation_times_must_match_the_scene():
    cfg, obs = _truth(ROPE, tracks=3)
    obs.t = obs.t * 0.5
    with pytest.raises(pl.io.ObservationError, match=r"t\[1\] = 0\.02 s but frame 1 of the scene"):
        Problem(cfg, obs)


HANDLED = (
    ROPE.replace('pin = "first"', 'pin = "none"')
    + """
[[handles]]
kind = "points"
points = [[0.0, 0.5, 0.0]]
radius = 0.01
stiffness = 200.0
"""
)


def test_observed_controls_drive_the_spring_handles():
    """`controls` replace the handles' own motion: the held end follows the observed control point."""
    cfg = pl.scene.parse_scene(HANDLED)
    obs = observe(pl.scene.build_scene(cfg), tracks=7)
    obs.controls = np.zeros((obs.frames, 1, 3)) + [0.0, 0.5, 0.0]
    obs.controls[:, 0, 0] = np.linspace(0.0, 0.1, obs.frames)  # the hand moves 10 cm along x
    p = Problem(cfg, obs, params=["stiffness"])
    x = p.simulate(p.build(p.nominal), p.frames)
    end = int(np.argmin(np.linalg.norm(x[0] - [0.0, 0.5, 0.0], axis=1)))
    assert x[-1, end, 0] == pytest.approx(0.1, abs=0.02)
    obs.controls = np.zeros((obs.frames, 2, 3))
    with pytest.raises(
        pl.io.ObservationError, match=r"controls: 2 control points but the scene's spring handles"
    ):
        Problem(cfg, obs, params=["stiffness"])


def test_ctrl_c_keeps_the_best_values_in_the_output_folder(tmp_path, monkeypatch):
    """An interrupt in the middle of CMA-ES still writes fitted.toml / fit.json with the best so far."""
    import pliant.fit._cmaes as cm

    cfg, obs = _truth(ROPE, tracks=5)
    calls = {"n": 0}
    real = cm.evaluate

    def interrupted(problem, values):
        calls["n"] += 1
        if calls["n"] == 8:
            raise KeyboardInterrupt
        return real(problem, values)

    monkeypatch.setattr(cm, "evaluate", interrupted)
    # A batched generation is interrupted the same way: route it through the candidates one by one.
    monkeypatch.setattr(
        cm, "evaluate_batch", lambda problem, cands, *_: [cm.evaluate(problem, v) for v in cands]
    )
    with pytest.raises(KeyboardInterrupt):
        pl.fit.fit(
            apply_globals(cfg, {"stiffness": 80.0}),
            obs,
            tmp_path,
            params=["stiffness"],
            progress=False,
            video=False,
        )
    import json

    rep = json.loads((tmp_path / "fit.json").read_text())
    assert rep["interrupted"] is True and (tmp_path / "fitted.toml").exists()
    assert (
        abs(rep["params"]["stiffness"]["value"] - 50.0) <= 30.0
    )  # the best so far, never worse than the start


POINTS = """
[scene]
name = "blob"
frame_dt = 0.04
substeps = 10
frames = 4
device = "cpu"
[[objects]]
kind = "points"
shape = "box"
size = [0.12, 0.12, 0.12]
spacing = 0.04
origin = [0.0, 0.3, 0.0]
[objects.material]
stiffness = 100.0
"""


def test_topology_parameters_rebuild_the_springs():
    """radius and neighbours of a point-cloud object are scene values: a candidate rebuilds its springs."""
    cfg = pl.scene.parse_scene(POINTS)
    obs = observe(pl.scene.build_scene(cfg), tracks=8)
    p = Problem(cfg, obs, params=["radius", "neighbours"])
    radius, neighbours = p.globals
    assert radius.param.topology and neighbours.param.integer
    assert radius.nominal == pytest.approx(1.8 * 0.04) and neighbours.nominal == 12
    few = p.build({"radius": 0.045, "neighbours": 3.0}).model.spring_count
    many = p.build({"radius": 0.1, "neighbours": 20.0}).model.spring_count
    assert 0 < few < many
    assert neighbours.param.from_unit(0.37, neighbours.lo, neighbours.hi) == round(1 + 0.37 * 23)


def test_observe_records_the_handles_and_replaying_them_reproduces_the_motion():
    """A scene driven by a moving spring handle: observe() writes its control points as `controls`, and a
    fit problem driven by them (instead of the scene's own handle motion) reproduces the tracks exactly."""
    cfg = pl.scene.parse_scene(HANDLED + "velocity = [0.2, 0.0, 0.0]\n")
    obs = observe(pl.scene.build_scene(cfg), tracks=7)
    assert obs.controls.shape == (obs.frames, 1, 3)
    np.testing.assert_allclose(obs.controls[:, 0, 0], 0.2 * obs.t, atol=1e-12)
    p = Problem(cfg, obs, params=["stiffness"])
    assert p.loss(p.simulate(p.build(p.nominal), p.frames), 1, p.frames) < 1e-20


def test_lbfgs_on_the_whole_rollout_recovers_rope_stiffness():
    """SciPy L-BFGS-B on the whole training rollout (one tape) from 2× the stiffness, within 1 %."""
    cfg, obs = _truth(ROPE, tracks=7)
    p = Problem(apply_globals(cfg, {"stiffness": 100.0}), obs, params=[], per_element="stiffness")
    r = gradient_stage(p, p.nominal, iterations=10, optimizer="lbfgs", shared=True)
    assert r.per_element["model.spring_stiffness"][0] == pytest.approx(50.0, rel=0.01)


def test_gradient_stage_restarts_each_shooting_window_from_the_observations(monkeypatch):
    """With multiple shooting the gradient stage's horizons restart from the observed state at every window
    start (teacher forcing, as the CMA-ES stage's runs), and a horizon never spans a window start; the
    forced loss from a wrong stiffness is below open loop's (the error stops accumulating), and at the
    truth both nearly vanish."""
    cfg, obs = _truth(ROPE, tracks=6)  # every free particle tracked
    wrong = apply_globals(cfg, {"stiffness": 150.0})
    restarts: list[int] = []
    force_state = Problem.force_state

    def spy(self, model, f, q, qd):
        restarts.append(f)
        before = q.copy()
        force_state(self, model, f, q, qd)
        seen = obs.visible[f]
        np.testing.assert_allclose(q[obs.particle[seen]], obs.points[f][seen], atol=1e-12)
        assert not np.allclose(before, q)  # the simulated state had drifted from the observed one

    monkeypatch.setattr(Problem, "force_state", spy)

    def first_epoch(scene_cfg, shooting: int, horizon: int = 1):
        restarts.clear()
        p = Problem(scene_cfg, obs, params=[], per_element="stiffness", shooting=shooting)
        r = gradient_stage(p, p.nominal, iterations=1, lr=1e-12, shared=True, horizon=horizon)
        return r.history[0], list(restarts), r.evaluations

    open_loop, none, _ = first_epoch(wrong, 0)
    forced, at, n = first_epoch(wrong, 2)
    assert none == [] and at == [2, 4, 6] and n == 7  # training frames 1-7, one-frame horizons
    assert forced < open_loop
    assert first_epoch(wrong, 2, horizon=5)[1:] == ([2, 4, 6], 4)  # horizons cut at 2, 4 and 6
    monkeypatch.setattr(Problem, "force_state", force_state)
    # At the truth open loop is exact; forcing restarts from five-point velocities of 25 fps tracks, close.
    assert first_epoch(cfg, 0)[0] < 1e-6 * open_loop and first_epoch(cfg, 2)[0] < 0.02 * open_loop
