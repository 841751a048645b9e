"""Issue 38's figures on the fixtures made each engine's own way (tests/data/foreign/*_own, made by
benchmarks/peers/observe_own.py: MuJoCo's even flexcomp masses and default soft contact, Newton's own
particle masses and default penalty ground; scenes with pliant's defaults). The default ``pliant fit``
must never predict the held-out frames worse than the nominal scene, and must reach the issue's bound:
0.25× nominal on cloth, 0.3× on soft solids with ground contact.

MuJoCo's cloth reached 0.345× before issue 38's stages, 0.266× after them, and 0.16× once the validation
gate stopped putting back the spring dashpot that the frames it trained on use (benchmarks/peers/README.md).
Its held-out error is chaotic in the fitted values (the cloth folds): ±0.5 % on them moves it by ±5 mm.
"""

from __future__ import annotations

from pathlib import Path

import pytest

import pliant as pl

DATA = Path(__file__).resolve().parent / "data" / "foreign"

CASES = [
    pytest.param("mujoco_cloth_own", 0.25),
    pytest.param("mujoco_cube_own", 0.30),
    pytest.param("mujoco_cube_own_thrown", 0.30),
    pytest.param("newton_cloth_own", 0.25),
    pytest.param("newton_box_own", 0.30),
]


@pytest.mark.slow
@pytest.mark.parametrize("name, bound", CASES)
def test_default_fit_on_the_engines_own_fixtures(name, bound, tmp_path):
    cfg = pl.scene.load_scene(DATA / f"{name}.toml")
    obs = pl.io.Observations.load(DATA / f"{name}.npz")
    rep = pl.fit.fit(cfg, obs, tmp_path, per_element="auto", progress=False, video=False)  # as the CLI
    fitted, nominal = rep["error"]["test"], rep["error_nominal"]["test"]
    assert fitted <= nominal, f"{name}: worse than nominal ({fitted * 1e3:.1f} vs {nominal * 1e3:.1f} mm)"
    assert fitted <= bound * nominal, (
        f"{name}: held-out {fitted * 1e3:.1f} mm vs nominal {nominal * 1e3:.1f} mm"
    )
