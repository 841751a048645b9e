"""Issue 25's figures on motion pliant did not make: the default ``pliant fit`` (no ``--params``) on the
cross-engine fixtures in tests/data/foreign/ (made by benchmarks/peers/observe_{mujoco,newton}.py: tracks
with noise and occlusion, a scene deliberately 5× too soft). The held-out track error must fall to the
issue's bound of the nominal scene's: 0.25× on cloth, 0.3× on a soft solid with ground contact.

MuJoCo's rope (0.80×) is not here: the fit finds its converted material, and the converted material
itself explains the motion no better (benchmarks/peers/README.md), so what is left is the difference
between a discrete elastic rod with inextensible edges and pliant's springs, not the search. MuJoCo's cloth
is (0.21×) since its generator calls mj_setConst after setting the lumped masses: before, MuJoCo's
vertices fell at 0.4 g to 1.6 g (tests/test_foreign_fixtures.py checks the first frame is a free fall)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import pliant as pl

DATA = Path(os.environ.get("PLIANT_FOREIGN_DATA", Path(__file__).parent / "data" / "foreign"))

CASES = [
    ("newton_cloth", 0.25),  # Newton 1.8 triangle-FEM membrane + dihedral bending
    ("mujoco_cloth", 0.25),  # MuJoCo 4.0 2D flex: StVK triangles + hinge bending, implicit
    ("newton_box", 0.30),  # Newton 1.8 Smith tets thrown on a penalty ground
    ("mujoco_cube", 0.30),  # MuJoCo 4.0 StVK flex cube thrown on the ground
]


@pytest.mark.slow
@pytest.mark.parametrize("name, bound", CASES, ids=[c[0] for c in CASES])
def test_default_fit_on_foreign_tracks(name, bound, tmp_path):
    if not (DATA / f"{name}.npz").exists():
        pytest.skip(f"the fixture {name} is absent")
    cfg = pl.scene.load_scene(DATA / f"{name}.toml")
    obs = pl.io.Observations.load(DATA / f"{name}.npz")
    rep = pl.fit.fit(cfg, obs, tmp_path, per_element="auto", progress=False, video=False)  # as the CLI
    fitted, nominal = rep["error"]["test"], rep["error_nominal"]["test"]
    assert fitted <= bound * nominal, (
        f"{name}: held-out {fitted * 1e3:.1f} mm vs nominal {nominal * 1e3:.1f} mm"
    )
