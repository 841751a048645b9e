"""Issue 38, items 1 and 4: the global stage is gated by validation (a fit is never worse than the scene as
given on the frames it held back without saying so), and the report says which parameters the data
constrain and which trade against each other."""

from __future__ import annotations

import math

import numpy as np
import pytest
import tomllib
from helpers import FIT_ROPE

import pliant as pl
from pliant.cli._fit import _gate_lines
from pliant.fit import observe
from pliant.fit._gate import TIE, fit_window
from pliant.fit._identify import CONSTRAINED, hessian, identify, stencil, summarise
from pliant.fit._params import resolve_globals

#: The tiny rope over 20 steps (21 observed frames): 15 training frames, of which 12-14 validate.
ROPE = FIT_ROPE.replace("frames = 10", "frames = 20")
KW = dict(per_element=None, generations=12, progress=False, video=False)


def _observed(text: str, **values: float):
    cfg = pl.scene.parse_scene(text)
    return observe(pl.scene.build_scene(pl.fit.apply_globals(cfg, values)), tracks=7)


def _fitted(out) -> dict:
    return tomllib.loads((out / "fitted.toml").read_text())


def test_the_fitted_values_are_dropped_when_they_predict_the_validation_frames_worse(tmp_path):
    """A recording whose rope is stiffer (80 N/m) over the first 12 frames and then moves as the scene says
    (50 N/m): CMA-ES, trained on frames 1-11, fits the stiff start, which predicts the validation frames
    12-14 worse than the scene's own value (which predicts them exactly). The gate keeps 50 N/m and says
    why, in fit.json and in the CLI's summary."""
    cfg = pl.scene.parse_scene(ROPE)
    stiff, own = _observed(ROPE, stiffness=80.0), _observed(ROPE)
    n_fit = fit_window(round(0.7 * stiff.frames), 0.2)
    assert n_fit == 12
    stiff.points[n_fit:] = own.points[n_fit:]  # the object changes after the frames the search sees
    rep = pl.fit.fit(cfg, stiff, tmp_path, params=["stiffness"], **KW)
    gv = rep["global_validation"]
    assert gv["frames"] == [12, 15]
    assert gv["fitted_values"]["stiffness"] > 65.0  # the search did fit the stiff start ...
    assert gv["fitted"] > gv["nominal"]  # ... which predicts the validation frames worse
    assert gv["kept"] is False and "no better than the scene's own" in gv["why"]
    assert _fitted(tmp_path)["objects"][0]["material"]["stiffness"] == 50.0
    assert rep["params"]["stiffness"]["value"] == 50.0
    assert rep["error"] == rep["error_nominal"]  # the scene as given: its errors, train and test
    lines = _gate_lines(rep)
    assert lines[0].startswith("global stage: KEPT THE SCENE'S VALUES: the fitted values predict")


def test_a_fit_that_predicts_better_is_kept_and_a_parameter_without_effect_is_reset(tmp_path):
    """The rope observed at 50 N/m, fitted from 80 N/m with the ground's restitution, which never acts (the
    ground is 5 m below): the stiffness is constrained (a band of a few per cent around 50 N/m), the
    restitution is flagged as not constrained (its band is the whole box) and, a tie on the training and
    validation frames, put back to the scene's 0 (the simpler explanation: no bounce); the fitted stiffness
    predicts the validation frames better and is kept."""
    text = ROPE + "[ground]\nheight = -5.0\nrestitution = 0.0\n"
    obs = _observed(text)
    cfg = pl.fit.apply_globals(pl.scene.parse_scene(text), {"stiffness": 80.0})
    rep = pl.fit.fit(cfg, obs, tmp_path, params=["stiffness", "ground_restitution"], **KW)
    gv, ident = rep["global_validation"], rep["identifiability"]
    assert gv["kept"] is True and gv["simplified"] < gv["nominal"]
    assert gv["simplified"] <= (1.0 + TIE) * gv["fitted"]
    k, e = ident["params"]["stiffness"], ident["params"]["ground_restitution"]
    assert k["constrained"] and k["sigma_unit"] < 0.2 * CONSTRAINED
    assert k["band"][0] < rep["params"]["stiffness"]["value"] < k["band"][1]
    assert 40.0 < k["band"][0] and k["band"][1] < 60.0
    assert not e["constrained"] and e["sigma_unit"] == pytest.approx(1.0, abs=1e-6)
    assert e["band"] == [0.0, 1.0] and ident["trade"] == []
    assert list(gv["reset"]) == ["ground_restitution"] and gv["reset"]["ground_restitution"] != 0.0
    assert _fitted(tmp_path)["ground"].get("restitution", 0.0) == 0.0
    assert rep["params"]["stiffness"]["value"] == pytest.approx(50.0, rel=0.03)
    assert rep["error"]["test"] < 0.5 * rep["error_nominal"]["test"]
    lines = "\n".join(_gate_lines(rep))
    assert "ground_restitution: NOT constrained by the data" in lines
    assert "stiffness: constrained by the data" in lines and "back to the scene's value" in lines


def test_the_hessian_stencil_recovers_a_quadratic_exactly():
    """Central differences are exact on a quadratic (plus an odd cubic term, which they cancel), also
    beside a bound, where the stencil's centre moves inside the box."""
    A = np.array([[2.0, 0.5, 0.1], [0.5, 1.0, -0.3], [0.1, -0.3, 3.0]])
    g = np.array([0.1, -0.2, 0.3])
    pts, c = stencil(np.array([0.5, 0.3, 1.0]), 0.02)
    assert pts.shape == (19, 3) and c[2] == pytest.approx(0.98)
    dx = pts - c
    f = dx @ g + 0.5 * np.einsum("pi,ij,pj->p", dx, A, dx) + dx[:, 0] ** 3
    assert np.allclose(hessian(f, 3, 0.02), A, atol=1e-9)


def test_two_parameters_that_enter_only_as_a_product_trade_against_each_other():
    """Two log-scaled parameters whose product alone sets the loss (a stiffness and a mass), same box: in the
    unit box L depends on u₁ + u₂ only, H = a [[1, 1], [1, 1]]. The direction u₁ − u₂ is flat (the whole
    box), the other gets 2ΔL / 2a, so each parameter's band is √((1 + ΔL/a) / 2) of the box, not
    constrained, and their correlation is −(1 − ΔL/a) / (1 + ΔL/a). A well-determined diagonal H gives
    √(2ΔL / H_ii), constrained, uncorrelated."""
    cfg = pl.scene.parse_scene(FIT_ROPE)
    bounds = resolve_globals(cfg, ["stiffness", "damping_rate"])
    values = {"stiffness": 50.0, "damping_rate": 0.5}
    loss, a = 2.0, 1e3
    dl = 0.1 * loss
    rep = summarise(a * np.ones((2, 2)), loss, bounds, values)
    s = math.sqrt(0.5 * (1.0 + dl / a))
    for p in rep["params"].values():
        assert p["sigma_unit"] == pytest.approx(s, rel=1e-9) and not p["constrained"]
    (pair,) = rep["trade"]
    assert pair["params"] == ["stiffness", "damping_rate"]
    assert pair["correlation"] == pytest.approx(-(1 - dl / a) / (1 + dl / a), rel=1e-9)
    rep = summarise(np.diag([4e3, 1e4]), loss, bounds, values)
    k = rep["params"]["stiffness"]
    assert k["sigma_unit"] == pytest.approx(math.sqrt(2 * dl / 4e3), rel=1e-9) and k["constrained"]
    b = bounds[0]
    factor = math.exp(k["sigma_unit"] * math.log(b.hi / b.lo))
    assert k["band"] == pytest.approx([50.0 / factor, 50.0 * factor], rel=1e-12)
    assert k["relative"] == pytest.approx(factor - 1.0, rel=1e-12)
    assert rep["trade"] == [] and abs(rep["correlation"][0][1]) < 1e-12


def test_no_band_is_read_where_the_loss_is_no_minimum():
    """A Hessian with a direction along which a unit of the box lowers the loss by more than ΔL, and more
    steeply than a tenth of its strongest upward curvature (a rugged loss, or a search stopped early):
    nothing is said about the parameters (constrained None, no pairs), and the CLI says why; weaker negative
    curvature (|λ| < 2ΔL, or < 10 % of the largest eigenvalue) is noise, and flat."""
    cfg = pl.scene.parse_scene(FIT_ROPE)
    bounds = resolve_globals(cfg, ["stiffness", "damping_rate"])
    values = {"stiffness": 50.0, "damping_rate": 0.5}
    loss = 2.0  # ΔL = 0.2
    rep = summarise(np.array([[1.0, 0.0], [0.0, -0.5]]), loss, bounds, values)
    assert rep["minimum"] is False and rep["trade"] == []
    assert all(p["constrained"] is None for p in rep["params"].values())
    assert "not measured" in _gate_lines({"identifiability": rep})[0]
    for neg in (-0.3, -50.0):  # beyond 2ΔL but 5 % of the largest: noise
        rep = summarise(np.array([[1e3, 0.0], [0.0, neg]]), loss, bounds, values)
        assert rep["minimum"] is True and rep["params"]["damping_rate"]["sigma_unit"] == pytest.approx(1.0)
        assert rep["params"]["stiffness"]["constrained"] and not rep["params"]["damping_rate"]["constrained"]


class _Quadratic:
    """A stand-in Problem whose open-loop loss on frames [lo, hi) is a closed form of the values: ``a``
    only acts before frame 10 (the frames the search trains on), ``b`` only on the last frames, ``k`` on
    all of them. ``build`` and ``simulate`` pass the values through; the loss reads them."""

    n_train = 15

    def __init__(self):
        cfg = pl.scene.parse_scene(FIT_ROPE)
        self.globals = resolve_globals(cfg, ["stiffness", "damping_rate", "damping"])
        for b, scene in zip(self.globals, (50.0, 0.0, 0.0), strict=True):
            b.scene_value = scene

    def build(self, values):
        return dict(values)

    def build_given(self):
        return self.build({"stiffness": 50.0, "damping_rate": 0.0, "damping": 0.0})

    def simulate(self, scene, frames, forced=False):
        return scene

    def loss(self, v, lo, hi):
        early, late = max(0, min(hi, 10) - lo), max(0, hi - max(lo, 10))
        common = (early + late) * (1.0 + (v["stiffness"] - 60.0) ** 2)
        return common + early * 0.5 * (v["damping_rate"] - 0.5) ** 2 + 0.1 * late * (1.0 - v["damping"])

    def unseed(self):
        pass


def test_a_loose_parameter_the_training_frames_use_is_not_put_back(monkeypatch):
    """Two parameters the identifiability calls not constrained, both a tie on the validation frames when
    put back to the scene's 0: ``damping`` (no effect on the frames 1-9 the search trained on) is put back;
    ``damping_rate`` is not: back at 0 it raises the loss on frames 1-9 from 9 to 9 + 9 · 0.5 · 0.5² (12.5 %,
    beyond the 2 % tie), the data use it where the search looked."""
    import pliant.fit._gate as gate_mod

    problem = _Quadratic()
    loose = {"sigma_unit": 1.0, "constrained": False}
    report = {"params": {"stiffness": {"sigma_unit": 0.01, "constrained": True}}}
    report["params"].update(damping_rate=dict(loose), damping=dict(loose, sigma_unit=0.9))
    monkeypatch.setattr(gate_mod, "identify", lambda *a, **k: report)
    fitted = {"stiffness": 60.0, "damping_rate": 0.5, "damping": 0.001}
    values, gv, _ = gate_mod.gate(problem, fitted, 10)
    train = problem.loss(fitted, 1, 10)
    assert train == pytest.approx(9.0)
    assert problem.loss({**fitted, "damping_rate": 0.0}, 1, 10) > (1.0 + TIE) * train
    assert problem.loss({**fitted, "damping_rate": 0.0}, 10, 15) == problem.loss(fitted, 10, 15)
    assert list(gv["reset"]) == ["damping"] and gv["kept"] is True
    assert values == {"stiffness": 60.0, "damping_rate": 0.5, "damping": 0.0}
    assert "tie on the training and validation frames" in gv["why"]


class _Box:
    """A stand-in Problem for :func:`identify` with a closed-form loss (``_unit_loss``) in the unit box."""

    def __init__(self):
        self.globals = resolve_globals(
            pl.scene.parse_scene(FIT_ROPE), ["stiffness", "damping_rate", "damping"]
        )

    def unit(self, cands: list[dict]) -> np.ndarray:
        """The candidates' points [n, 3] in the unit box."""
        return np.array([[b.param.to_unit(c[b.name], b.lo, b.hi) for b in self.globals] for c in cands])

    def values(self, u) -> dict[str, float]:
        return {b.name: b.param.from_unit(x, b.lo, b.hi) for b, x in zip(self.globals, u, strict=True)}


@pytest.mark.parametrize("edge", [1.0, 0.0])
def test_a_parameter_the_data_push_past_its_bound_is_held_there_and_the_others_measured(edge):
    """L = 1 + ½ xᵀ A x + (xᵀ b − s·σ) t − ½ q t² (x: stiffness and damping_rate about m; t: damping's
    distance from its bound, σ = +1 at the upper, −1 at the lower): the loss falls towards the bound at
    slope ∂L/∂u = −σ s and is concave across it, so the whole Hessian has λ = −q, and the report said
    nothing ("no minimum"). Now damping is at its bound with that slope, and the reduced Hessian at the bound
    is A: bands √(2ΔL (A⁻¹)ᵢᵢ) with ΔL = 0.1 (the loss there is 1), correlation −ρ (they trade). With A
    indefinite the free ones are "not measured", the bound one still reported."""
    box, m, s, q = _Box(), np.array([0.4, 0.6]), 5.0, 200.0
    b = np.array([3.0, -2.0])
    side = 1.0 if edge else -1.0

    def losses(A):
        def run(cands):
            u = box.unit(cands)
            x, t = u[:, :2] - m, side * (u[:, 2] - edge)  # t ≤ 0 inside the box
            quad = 0.5 * np.einsum("pi,ij,pj->p", x, A, x)
            return list(1.0 + quad + (x @ b - s * side * side) * t - 0.5 * q * t * t)

        return run

    a, rho = 400.0, 0.95
    A = a * np.array([[1.0, rho], [rho, 1.0]])
    values = box.values([*m, edge])
    rep = identify(box, values, 10, losses(A))
    assert summarise(np.array(rep["hessian"]), 1.0, box.globals, values)["minimum"] is False  # before
    d = rep["params"]["damping"]
    assert rep["at_bound"] == ["damping"] and rep["free"] == ["stiffness", "damping_rate"]
    assert d["at_bound"] == ("upper" if edge else "lower") and d["constrained"] is None
    assert d["slope_unit"] == pytest.approx(-side * s, rel=1e-6)  # upper: falls upwards; lower: downwards
    assert d["value"] == (box.globals[2].hi if edge else box.globals[2].lo)
    assert rep["minimum"] is True and rep["loss"] == pytest.approx(1.0, rel=1e-12)
    cov = 2.0 * 0.1 * np.linalg.inv(A)
    for k, name in enumerate(("stiffness", "damping_rate")):
        p = rep["params"][name]
        assert p["sigma_unit"] == pytest.approx(math.sqrt(cov[k, k]), rel=0.05)
        assert p["constrained"] == (math.sqrt(cov[k, k]) < CONSTRAINED)  # 0.072 of the box: constrained
    (pair,) = rep["trade"]
    assert pair["params"] == ["stiffness", "damping_rate"]
    assert pair["correlation"] == pytest.approx(-rho, rel=0.05) and abs(pair["correlation"]) > 0.9
    assert rep["evaluations"] == 19 + 9  # the whole stencil, then the free ones' with damping at its bound
    lines = "\n".join(_gate_lines({"identifiability": rep}))
    assert f"damping: at its {d['at_bound']} bound" in lines and "push it beyond the search box" in lines
    assert "stiffness: constrained by the data" in lines and "trade against each other" in lines
    rep = identify(box, values, 10, losses(np.array([[1.0, 0.0], [0.0, -300.0]])))
    assert rep["minimum"] is False and rep["params"]["damping"]["at_bound"] and rep["trade"] == []
    lines = _gate_lines({"identifiability": rep})
    assert lines[1].startswith("  damping: at its") and len(lines) == 3
    assert lines[2].startswith("  stiffness, damping_rate: not measured: with damping at the bound")


def test_the_report_is_unchanged_when_no_parameter_is_pushed_against_a_bound():
    """An interior minimum beside the upper bound of damping (within a step: the loss rises towards the
    bound at slope 0.4), then damping_rate's minimum 0.002 of the box below its lower bound (the loss falls
    towards it at 0.06 per unit of the box: less than ΔL = 0.2, flat there): the report is the plain
    stencil's, as before bounds were handled (the same dict, no line about a bound)."""
    box = _Box()
    A = np.array([[50.0, 10.0, 0.0], [10.0, 30.0, 5.0], [0.0, 5.0, 80.0]])
    for opt, u0 in (([0.5, 0.3, 0.995], [0.5, 0.3, 0.995]), ([0.5, -0.002, 0.995], [0.5, 0.0, 0.995])):

        def run(cands, opt=np.array(opt)):
            x = box.unit(cands) - opt
            return list(2.0 + 0.5 * np.einsum("pi,ij,pj->p", x, A, x))

        values = box.values(u0)
        pts, c = stencil(box.unit([values])[0])  # identify's own point: the values' round trip
        f = np.array(run([box.values(u) for u in pts]))
        want = summarise(hessian(f, 3), float(f[0]), box.globals, values)
        moved = {b.name: b.param.from_unit(c[k], b.lo, b.hi) for k, b in enumerate(box.globals)}
        method = "central finite differences of the open-loop training loss, step 0.02 of the unit box"
        want.update(
            method=method, frames=[1, 10], evaluations=19, left_out=[], hessian=hessian(f, 3).tolist()
        )
        want["centre"] = moved
        rep = identify(box, values, 10, run)
        assert rep == want and "at_bound" not in rep
        assert not any("bound" in line for line in _gate_lines({"identifiability": rep}))
