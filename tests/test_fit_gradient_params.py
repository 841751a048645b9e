"""The image-gradient stage reaches every global parameter that drives a registry parameter (issue 30 item 3):
its gradient w.r.t. stiffness, Et, the dashpot damping and the damping rate equals central differences of
the image loss; the others are named as CMA-ES's; the gradient stages stop on a relative improvement."""

from __future__ import annotations

import numpy as np
import pytest
from test_fit_photometric import CLOTH

import pliant as pl
from pliant.fit import FitError, PhotometricProblem, observe_images
from pliant.fit._gradient import Convergence
from pliant.fit._params import GLOBAL, Bound, apply_globals
from pliant.fit._photometric import _GlobalGradient, gradient_capable, refine_globals
from pliant.fit._run import search_plan, stages_of


def test_every_magnitude_that_drives_the_registry_is_gradient_capable():
    """The capable set is read from the declarations, and every parameter it drives is differentiable."""
    capable = {n for n, p in GLOBAL.items() if gradient_capable(p)}
    assert capable == {"stiffness", "Et", "damping", "damping_rate", "E", "compliance"}
    for n in capable:
        assert GLOBAL[n].drives and all(d in pl.diff.PARAMETERS for d in GLOBAL[n].drives), n


@pytest.mark.parametrize(
    ("material", "names"),
    [
        ("stiffness = 50.0\ndamping = 0.01", ["stiffness", "damping", "damping_rate"]),
        ("Et = 50.0", ["Et"]),
    ],
)
def test_image_gradient_of_each_global_equals_central_differences(material, names):
    """∂L/∂log p through render → particles → rollout for each p, against scenes rebuilt at p(1 ± ε)."""
    cfg = pl.scene.parse_scene(CLOTH.replace("stiffness = 50.0", material))
    obs = observe_images(pl.scene.build_scene(cfg), cameras=2, image_size=(24, 18))
    wrong = apply_globals(cfg, {n: 1.5 * v for n, v in {"stiffness": 50.0, "Et": 50.0}.items() if n in names})
    p = PhotometricProblem(wrong, obs, params=names)
    gg = _GlobalGradient(p, p.nominal, names)
    loss, grad = gg.evaluate(np.zeros(len(names)))
    assert loss == pytest.approx(p.loss(p.simulate(p.build(p.nominal), p.n_train)), rel=1e-12)
    eps = 1e-5
    for i, n in enumerate(names):
        v = p.nominal[n]

        def at(x: float, n=n) -> float:
            return p.loss(p.simulate(p.build({**p.nominal, n: x}), p.n_train))

        fd = (at(v * (1 + eps)) - at(v * (1 - eps))) / (2 * eps)
        assert abs(fd) > 1e-9, n
        assert abs(grad[i] - fd) <= 2e-4 * abs(fd), (n, grad[i], fd)


def test_parameters_without_an_image_gradient_are_named():
    """ν is CMA-ES's alone: the plan says so, and refining it alone is refused with the capable names."""
    cfg = pl.scene.parse_scene(CLOTH)
    obs = observe_images(pl.scene.build_scene(cfg), cameras=1, image_size=(12, 9))
    p = PhotometricProblem(cfg, obs, params=["stiffness", "damping_rate"])
    assert [stages_of(p, b) for b in p.globals] == [["cmaes", "image-gradient"]] * 2
    plan = search_plan(p)
    assert "damping_rate: [0.05, 5] 1/s (log), scene 0.5, start 0.5" in plan[1]
    p.globals = [Bound(GLOBAL["nu"], 0.3, 0.0, 0.49, 0.3)]
    assert stages_of(p, p.globals[0]) == ["cmaes"]
    with pytest.raises(FitError, match=r"refines stiffness, Et, E, compliance, damping_rate, damping; none"):
        refine_globals(p, {"nu": 0.3})


def test_convergence_stops_on_relative_improvement():
    """Three iterations in a row that improve the best loss by less than tol stop the stage; tol 0 never
    stops early."""
    stop = Convergence(1e-3, patience=3)
    losses = [10.0, 5.0, 4.0, 3.9999, 3.9998, 3.99975, 1.0]
    assert [stop(v) for v in losses[:6]] == [False, False, False, False, False, True]
    never = Convergence(0.0)
    assert not any(never(v) for v in [1.0] * 10)
    with pytest.raises(FitError, match="tol"):
        Convergence(-1.0)
