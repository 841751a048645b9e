"""The total-variation prior of the gradient stage (pl.fit.Smoothness) and the cloth membrane parameter Et:
hand-computed values, a finite-difference gradient, the neighbour pairs of a known mesh."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import FIT_ROPE

import pliant as pl
from pliant.fit import FitError, Smoothness
from pliant.fit._params import per_element_incidence, resolve_globals


def test_pairs_are_elements_that_share_a_particle():
    # A chain 0-1-2-3 of three springs and a detached spring 4-5: pairs (0,1) and (1,2) only.
    s = Smoothness(np.array([[0, 1], [1, 2], [2, 3], [4, 5]]), weight=1.0)
    assert sorted(zip(s.a.tolist(), s.b.tolist(), strict=True)) == [(0, 1), (1, 2)]


def test_value_and_gradient_by_hand_and_by_finite_differences():
    s = Smoothness(np.array([[0, 1], [1, 2], [2, 3]]), weight=3.0, eps=0.01)
    theta = np.array([0.0, 0.3, -0.2])
    r = lambda d: np.sqrt(d * d + 1e-4) - 0.01  # noqa: E731
    value, grad = s.value_grad(theta)
    assert value == pytest.approx(3.0 / 3 * (r(-0.3) + r(0.5)), rel=1e-12)
    h = 1e-6
    fd = [(s.value_grad(theta + h * e)[0] - s.value_grad(theta - h * e)[0]) / (2 * h) for e in np.eye(3)]
    np.testing.assert_allclose(grad, fd, rtol=1e-6, atol=1e-9)
    # Equal values cost nothing, whatever the weight.
    assert s.value_grad(np.full(3, 0.7)) == (0.0, pytest.approx(np.zeros(3)))


CLOTH = """
[scene]
name = "c"
frame_dt = 0.04
substeps = 4
frames = 4
dtype = "float64"
device = "cpu"
[[objects]]
kind = "cloth"
nx = 2
ny = 2
size = 0.2
origin = [0.0, 0.5, 0.0]
plane = "xz"
mass = 0.05
pin = "top-corners"
[objects.material]
Et = 50.0
"""


def test_incidence_of_springs_and_the_cloth_membrane_parameter():
    cfg = pl.scene.parse_scene(CLOTH)
    scene = pl.scene.build_scene(cfg)
    inc = per_element_incidence(scene, "stiffness")
    np.testing.assert_array_equal(inc, scene.model.spring_indices.numpy().reshape(-1, 2))
    (b,) = resolve_globals(cfg, ["Et"])
    assert b.nominal == 50.0 and b.lo == pytest.approx(5.0) and b.hi == pytest.approx(500.0)
    # Et is set on the material, and the springs follow it (k from E·t and ν).
    k = pl.scene.build_scene(pl.fit.apply_globals(cfg, {"Et": 100.0})).model.spring_stiffness.numpy()
    np.testing.assert_allclose(k, 2.0 * scene.model.spring_stiffness.numpy())
    cfg.objects[0].material.stiffness = 10.0  # given springs: Et is then unused, so not a parameter
    with pytest.raises(FitError, match="'Et'"):
        resolve_globals(cfg, ["Et"])


def test_negative_smoothness_is_refused():
    cfg = pl.scene.parse_scene(CLOTH.replace("Et = 50.0", "stiffness = 50.0"))
    obs = pl.fit.observe(pl.scene.build_scene(cfg), tracks=4)
    p = pl.fit.Problem(cfg, obs, params=[], per_element="stiffness")
    with pytest.raises(FitError, match="smoothness"):
        pl.fit.gradient_stage(p, {}, iterations=1, smoothness=-1.0)


ROPE = FIT_ROPE


def test_validation_frames_decide_whether_the_gradient_stage_is_kept(tmp_path):
    """11 frames: 8 train (frames 1-7), of which the last 20 % (frame 7) validates the per-spring values; a
    stiffness 2× off is a fault the per-spring values do fix, so they are kept and predict frame 7 better."""
    cfg = pl.scene.parse_scene(ROPE)
    obs = pl.fit.observe(pl.scene.build_scene(cfg), tracks=7)
    wrong = pl.fit.apply_globals(cfg, {"stiffness": 100.0})
    rep = pl.fit.fit(
        wrong,
        obs,
        tmp_path,
        params=[],
        per_element="stiffness",
        epochs=6,
        lr=0.1,
        progress=False,
        video=False,
    )
    v = rep["gradient_validation"]
    assert v["frames"] == [7, 8]
    assert rep["gradient_stage_kept"] == (v["after"] < 0.9 * v["before"]) and rep["gradient_stage_kept"]
    assert rep["error"]["test"] < rep["error_nominal"]["test"]
