"""Issue 37's figures on another engine's footage (slow: the whole ``pliant twin`` command, minutes on one
core): MuJoCo's clamped soft beam, four cameras at 200 × 150 px with masks and depth, judged against MuJoCo's
own vertices (``tests/twin_truth.py``). ``benchmarks/twin_beam.py`` prints the same figures with the
masks-only variant, the held-out camera and the wall time."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from twin_truth import score_twin

from pliant.cli import main

VIDEO = Path(__file__).resolve().parent / "data" / "foreign" / "mujoco_beam_video.npz"
HELDOUT = VIDEO.with_name("mujoco_beam_heldout.npz")


@pytest.mark.slow
def test_a_twin_of_mujocos_beam_from_its_pictures(tmp_path):
    out = tmp_path / "twin"
    assert main(["twin", str(VIDEO), "--out", str(out), "-q"]) == 0
    rep = json.loads((out / "twin.json").read_text())
    s = score_twin(out)
    assert s["chamfer_mm"] <= 6.0, s  # a 1 cm grid inside the true solid scores 4.8 mm, a 3 cm one 14 mm
    assert s["motion_ratio"] <= 0.6, s  # a copy of the truth one frame late scores 0.39, standing still 1
    assert rep["fixed"]["fixed_particles"] > 0 and rep["ground"]["height"] is None
    assert rep["metrics"]["chamfer_mm"]["test"] < rep["metrics"]["chamfer_still_mm"]["test"]
    # A camera the twin never saw: its splats against MuJoCo's rendering of that view.
    assert (
        main(["run", str(out / "twin.toml"), "--cameras", str(HELDOUT), "--out", str(out / "heldout"), "-q"])
        == 0
    )
