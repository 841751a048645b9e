"""Defaults that work on motion pliant did not make (issue 25 item 1): the parameters each model searches by
default, their physically scaled bounds, the ground's coefficients when the tracks reach it, the printed plan
and fit.json's record; and (slow) the default fit of Newton's cloth meets the issue's held-out ratio."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import FIT_ROPE
from test_fit_slow import FEM_BOX as FEM
from test_fit_stages import CLOTH_XPBD

import pliant as pl
from pliant.fit import Problem, observe
from pliant.fit._params import default_params, ground_contact

CLOTH_ET = (
    FIT_ROPE.replace(
        'kind = "rope"\nn_segments = 6\nlength = 0.3\norigin = [0.0, 0.5, 0.0]\ndirection = [1.0, 0.0, 0.0]',
        'kind = "cloth"\nnx = 3\nny = 3\nsize = 0.3\norigin = [-0.15, 0.5, -0.15]\nplane = "xz"',
    )
    .replace('pin = "first"', 'pin = "top-corners"')
    .replace("stiffness = 50.0", "Et = 40.0")
)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (FIT_ROPE, ["stiffness", "damping_rate", "damping"]),
        (
            FIT_ROPE.replace("stiffness = 50.0", "stiffness = 50.0\nbend_stiffness = 5.0"),
            ["stiffness", "bend_stiffness", "damping_rate", "damping"],
        ),
        (CLOTH_ET, ["Et", "damping_rate", "damping"]),
        (FEM, ["E", "nu", "damping_rate"]),
        (CLOTH_XPBD, ["compliance", "damping_rate"]),
    ],
)
def test_default_parameters_per_model(text, expected):
    """Mass-spring: stiffness (or E·t), the bend springs' stiffness where it has them, velocity damping rate,
    dashpot γ; FEM: E, ν, damping rate; XPBD: compliance and damping rate."""
    assert default_params(pl.scene.parse_scene(text)) == expected


def test_ground_coefficients_join_when_the_tracks_reach_the_ground():
    """The rope falls onto a ground at 0.46 m (its lowest track ends on it): friction and restitution are
    searched too; the same rope with the ground far below is not in contact."""
    low = pl.scene.parse_scene(
        FIT_ROPE.replace('pin = "first"', 'pin = "none"') + "[ground]\nheight = 0.46\n"
    )
    obs = observe(pl.scene.build_scene(low), tracks=7)
    gap = ground_contact(low, obs)
    assert gap is not None and gap <= 0.05 * np.ptp(obs.points[obs.visible], axis=0).max()
    assert default_params(low, obs)[-2:] == ["ground_friction", "ground_restitution"]
    far = pl.scene.parse_scene(FIT_ROPE + "[ground]\nheight = -5.0\n")
    assert default_params(far, observe(pl.scene.build_scene(far), tracks=7))[-1] == "damping"


def test_dashpot_bounds_scale_with_the_critical_damping():
    """A placeholder γ = 0 is searched over 10⁻⁴ … 1 × 2√(k m) of the rope's springs (not a box around
    10⁻⁵ N s/m), and a damping rate of 0 over the registry's 10⁻³ … 30 1/s; the scene's own values and
    the reasons are kept for the report."""
    cfg = pl.scene.parse_scene(FIT_ROPE.replace("damping_rate = 0.5", "damping_rate = 0.0"))
    obs = observe(pl.scene.build_scene(cfg), tracks=7)
    p = Problem(cfg, obs)
    b = {x.name: x for x in p.globals}
    m = p.build({}).model
    gc = 2.0 * math.sqrt(50.0 * float(np.median(m.particle_mass.numpy()[m.particle_inv_mass.numpy() > 0])))
    assert b["damping"].hi == pytest.approx(gc, rel=1e-12) and b["damping"].lo == pytest.approx(1e-4 * gc)
    assert b["damping"].scene_value == 0.0 and b["damping"].nominal == pytest.approx(1e-2 * gc)
    assert (b["damping_rate"].lo, b["damping_rate"].hi) == (1e-3, 30.0)
    assert "dissipation" in b["damping_rate"].why and "dashpot" in b["damping"].why


def test_fit_prints_and_records_what_it_searches(tmp_path, capsys):
    """The plan (bounds, scale, the scene's value, why, stages) is printed before the fit and recorded in
    fit.json."""
    cfg = pl.scene.parse_scene(FIT_ROPE)
    obs = observe(pl.scene.build_scene(cfg), tracks=7)
    pl.fit.fit(cfg, obs, tmp_path, generations=1, epochs=0, progress=True, video=False)
    out = capsys.readouterr().out
    assert "fit: searching" in out and "damping_rate: [0.05, 5] 1/s (log), scene 0.5" in out
    rep = json.loads((tmp_path / "fit.json").read_text())
    assert list(rep["params"]) == ["stiffness", "damping_rate", "damping"]
    assert (
        rep["params"]["damping_rate"]["nominal"] == 0.5
        and "dissipation" in rep["params"]["damping_rate"]["why"]
    )
    assert rep["params"]["stiffness"]["stages"] == ["cmaes"]


@pytest.mark.slow
def test_default_fit_of_newton_cloth_meets_the_issue_ratio(tmp_path):
    """Newton 1.8's cloth (benchmarks/peers/data), scene 5× too soft, the default command: held-out track
    error ≤ 0.25× nominal (issue 25). The wall time is printed (the issue's goal: ≤ 2 min on one core)."""
    data = Path(__file__).resolve().parent.parent / "benchmarks" / "peers" / "data"
    text = (data / "newton_cloth.toml").read_text(encoding="utf-8")
    assert "Et = 106.7" in text  # the converted material, made 5× too soft here
    cfg = pl.scene.parse_scene(text.replace("Et = 106.7", "Et = 21.34"))
    obs = pl.io.Observations.load(data / "newton_cloth.npz")
    t0 = time.perf_counter()
    rep = pl.fit.fit(cfg, obs, tmp_path, device="cpu", progress=False, video=False)
    ratio = rep["error"]["test"] / rep["error_nominal"]["test"]
    print(f"newton cloth default fit: {ratio:.3f} x nominal in {time.perf_counter() - t0:.0f} s")
    assert ratio <= 0.25, rep["params"]


LONG_ROPE = FIT_ROPE.replace("frames = 10", "frames = 50")


def test_multiple_shooting_starts_each_window_from_the_observed_state():
    """shooting=W: a training run is the open-loop run up to frame W, then continues from the observed
    state (every particle tracked here: the truth's own state), so at the true parameters the forced run
    follows the observations, and from wrong ones each window's error starts again near zero."""
    cfg = pl.scene.parse_scene(LONG_ROPE)
    obs = observe(pl.scene.build_scene(cfg), tracks=7)
    wrong = pl.fit.apply_globals(cfg, {"stiffness": 20.0})
    p = Problem(wrong, obs, params=["stiffness"], shooting=5)
    free_run = p.simulate(p.build(p.nominal), p.n_train, forced=False)
    forced = p.simulate(p.build(p.nominal), p.n_train)
    np.testing.assert_array_equal(forced[:6], free_run[:6])  # frames 0 … 5: the first window, open loop
    err = p.errors(forced)[1 : p.n_train]
    assert err[5] < 0.75 * err[4]  # frame 5 is simulated, frame 6 starts from the observed state at frame 5
    assert p.loss(forced) < p.loss(free_run)
    truth = Problem(cfg, obs, params=["stiffness"], shooting=5)
    at_truth = truth.loss(truth.simulate(truth.build(truth.nominal), truth.n_train))
    # Not 0: the forced velocities are central differences of the frames (O(Δt²)), not the true ones.
    assert at_truth < 0.1 * p.loss(forced)


def test_multiple_shooting_is_the_default_for_long_densely_tracked_motion():
    """Every free particle tracked and ≥ 30 training frames: windows of SHOOTING_WINDOW frames; sparse
    tracks or a short motion: open loop; a bad window is refused."""
    from pliant.fit._problem import SHOOTING_WINDOW

    cfg = pl.scene.parse_scene(LONG_ROPE)
    dense = observe(pl.scene.build_scene(cfg), tracks=7)
    sparse = observe(pl.scene.build_scene(cfg), tracks=3)
    assert Problem(cfg, dense, params=["stiffness"]).shooting == SHOOTING_WINDOW
    assert Problem(cfg, sparse, params=["stiffness"]).shooting == 0
    short = pl.scene.parse_scene(FIT_ROPE)
    assert Problem(short, observe(pl.scene.build_scene(short), tracks=7), params=["stiffness"]).shooting == 0
    with pytest.raises(pl.fit.FitError, match="--shooting"):
        Problem(cfg, dense, params=["stiffness"], shooting=-1)


def test_models_are_compared_side_by_side(tmp_path, capsys):
    """`pliant fit --models mass_spring,fem` on a FEM box's own motion: both candidates are fitted (the
    mass-spring one starting from springs k = E·h), fem predicts the held-out frames better, and the table
    and models.json say so; an unknown model is refused before any fit."""
    from pliant.cli import main
    from pliant.fit._models import candidate

    cfg = pl.scene.parse_scene(FEM)
    obs = observe(pl.scene.build_scene(cfg), tracks=8)
    ms = candidate(cfg, "mass_spring")
    assert ms.objects[0].model == "mass_spring" and ms.objects[0].material.stiffness == pytest.approx(
        2e4 * 0.2
    )
    scene, npz = tmp_path / "box.toml", tmp_path / "obs.npz"
    pl.fit.scene_toml(cfg, scene)
    obs.save(npz)
    args = ["fit", str(scene), str(npz), "--out", str(tmp_path / "m"), "--models", "mass_spring,fem"]
    assert main([*args, "--iterations", "2", "--no-video", "-q"]) == 0
    table = capsys.readouterr().out
    rep = json.loads((tmp_path / "m" / "models.json").read_text())
    assert rep["best"] == "fem", rep
    assert rep["models"]["fem"]["test"] < rep["models"]["mass_spring"]["test"]
    assert "fem" in table and "<- best" in table and (tmp_path / "m" / "fem" / "fit.json").exists()
    with pytest.raises(pl.fit.FitError, match="unknown model 'springs'"):
        pl.fit.compare_models(cfg, obs, ["fem", "springs"], tmp_path / "x")


def test_auto_per_element_runs_the_models_own_and_validates_it(tmp_path):
    """per_element="auto": per-spring k for mass-spring (E per tet for FEM, α for XPBD, none from images);
    the stage runs and fit.json says whether validation kept it."""
    from pliant.fit._params import auto_per_element

    assert auto_per_element(pl.scene.parse_scene(FIT_ROPE), None) == "stiffness"
    assert auto_per_element(pl.scene.parse_scene(FEM), None) == "E"
    assert auto_per_element(pl.scene.parse_scene(CLOTH_XPBD), None) == "compliance"
    cfg = pl.scene.parse_scene(FIT_ROPE)
    obs = observe(pl.scene.build_scene(cfg), tracks=7)
    wrong = pl.fit.apply_globals(cfg, {"stiffness": 80.0})
    rep = pl.fit.fit(
        wrong, obs, tmp_path, per_element="auto", generations=2, epochs=2, progress=False, video=False
    )
    assert rep["gradient_stage_kept"] in (True, False) and rep["gradient_validation"] is not None


def test_observed_velocity_is_fourth_order_where_five_frames_are_seen():
    """Teacher forcing's start velocities: the five-point stencil converges as Δt⁴, the central difference
    (its fallback where a neighbour frame is unseen) as Δt²; both on x = sin(ωt)."""
    from pliant.fit._problem import observed_velocity

    w, t0 = 7.0, 0.3
    errs = {}
    for dt in (0.02, 0.01):
        t = t0 + dt * np.arange(-3, 4)
        pts = np.zeros((7, 2, 3))
        pts[:, :, 0] = np.sin(w * t)[:, None]
        vis = np.ones((7, 2), bool)
        vis[1, 1] = False  # track 1 misses frame f - 2: central difference
        v, ok = observed_velocity(pts, vis, 3, dt)
        assert ok.all()
        errs[dt] = np.abs(v[:, 0] - w * np.cos(w * t0))
    order = np.log2(errs[0.02] / errs[0.01])
    assert order[0] == pytest.approx(4.0, abs=0.1) and order[1] == pytest.approx(2.0, abs=0.1)
    v, ok = observed_velocity(pts, np.array([[True, True]] * 3 + [[True, False]] * 4), 3, 0.01)
    assert ok.tolist() == [True, False]  # no velocity for a track unseen at f


def test_multiple_shooting_is_followed_by_an_open_loop_search(tmp_path):
    """After CMA-ES over forced windows, CMA-ES again open loop from its values (what the held-out frames
    measure): fit.json has both stages, the result's loss is the open-loop one, and the open-loop stage runs
    only with multiple shooting."""
    cfg = pl.scene.parse_scene(FIT_ROPE.replace("frames = 10", "frames = 50"))
    obs = observe(pl.scene.build_scene(cfg), tracks=6, noise=1e-3, seed=1)
    wrong = pl.fit.apply_globals(cfg, {"stiffness": 120.0})
    rep = pl.fit.fit(wrong, obs, tmp_path, params=["stiffness"], generations=8, progress=False, video=False)
    assert rep["shooting"] == 10 and set(rep["loss_history"]) >= {"cmaes", "cmaes_open_loop"}
    p = Problem(wrong, obs, params=["stiffness"], shooting=0)
    fitted = p.loss(p.simulate(p.build({"stiffness": rep["params"]["stiffness"]["value"]}), p.n_train))
    # validated on the held-back frames, the search ran again on all the training frames (pliant.fit._global)
    refit = rep["global_validation"]["refit"]
    assert refit[:2] == ["cmaes_all_frames", "cmaes_open_loop_all_frames"]
    last = rep["loss_history"]["cmaes_open_loop_all_frames"][-1]
    # the better on all the training frames of the search again's values and the held-back search's
    # (then refined open loop on all of them from there: it starts there, so it cannot end worse)
    both = rep["global_validation"]["all_frames"]
    assert both["search_again"] == pytest.approx(last, rel=1e-9)  # open loop
    if both["search_again"] <= both["held_back_search"]:
        assert refit == ["cmaes_all_frames", "cmaes_open_loop_all_frames"]
        assert fitted == pytest.approx(last, rel=1e-9)
    else:
        assert refit[2:] == ["cmaes_refined_all_frames"]
        refined = rep["loss_history"]["cmaes_refined_all_frames"]
        assert fitted == pytest.approx(min(refined), rel=1e-9) and fitted <= both["held_back_search"]
    assert fitted < 0.1 * p.loss(p.simulate(p.build(p.nominal), p.n_train))
    assert rep["params"]["stiffness"]["value"] == pytest.approx(50.0, rel=0.05)
    rep0 = pl.fit.fit(
        wrong,
        obs,
        tmp_path / "open",
        params=["stiffness"],
        shooting=0,
        generations=4,
        progress=False,
        video=False,
    )
    assert "cmaes_open_loop" not in rep0["loss_history"]
