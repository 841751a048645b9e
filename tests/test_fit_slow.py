"""Known-truth recovery figures (pliant → pliant, synthetic data; ``-m slow``, a few minutes on one core):
the fit_rope scene's stiffness within 1 % and damping rate within 2 % from clean tracks, both within 5 % with
1 mm noise and 30 % of the tracks hidden at each frame."""

from __future__ import annotations

import pytest

import pliant as pl

TRUTH = {"stiffness": 300.0, "damping_rate": 0.5}


@pytest.mark.slow
@pytest.mark.parametrize(("noise", "dropout", "tol"), [(0.0, 0.0, (0.01, 0.02)), (0.001, 0.3, (0.05, 0.05))])
def test_cmaes_recovers_the_rope_from_its_own_observations(noise, dropout, tol):
    cfg = pl.scene.load_scene("fit_rope")
    cfg.scene.dtype = "float64"
    obs = pl.fit.observe(
        pl.scene.build_scene(cfg, device="cpu"), tracks=13, noise=noise, dropout=dropout, seed=3
    )
    wrong = pl.fit.apply_globals(cfg, {"stiffness": 480.0, "damping_rate": 0.25})
    p = pl.fit.Problem(wrong, obs, params=list(TRUTH), device="cpu")
    r = pl.fit.cmaes(p, generations=40)
    assert abs(r.values["stiffness"] - 300.0) / 300.0 <= tol[0], r.values
    assert abs(r.values["damping_rate"] - 0.5) / 0.5 <= tol[1], r.values


FEM_BOX = """
[scene]
name = "fem_cube"
frame_dt = 0.04
substeps = 20
frames = 8
dtype = "float64"
device = "cpu"
[[objects]]
kind = "soft_box"
model = "fem"
cells = [1, 1, 1]
size = [0.2, 0.2, 0.2]
origin = [0.0, 0.12, 0.0]
density = 500.0
velocity = [0.5, -1.0, 0.0]
[objects.material]
E = 2e4
nu = 0.35
[ground]
height = 0.0
friction = 0.5
[solver]
integrator = "SymplecticEuler"
"""


@pytest.mark.slow
def test_gradient_stage_recovers_fem_youngs_modulus():
    """A cube of tets dropped on the ground (explicit FEM, tape gradients through μ and λ together): E from
    2× back to within 2 %."""
    cfg = pl.scene.parse_scene(FEM_BOX)
    obs = pl.fit.observe(pl.scene.build_scene(cfg), tracks=8)
    p = pl.fit.Problem(pl.fit.apply_globals(cfg, {"E": 4e4}), obs, params=[], per_element="E")
    r = pl.fit.gradient_stage(p, p.nominal, iterations=20, lr=0.1, shared=True)
    mu = r.per_element["model.tet_mu"]
    assert mu[0] == pytest.approx(2e4 / (2 * 1.35), rel=0.02)
