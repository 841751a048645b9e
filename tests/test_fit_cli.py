"""``pliant observe`` and ``pliant fit``: the four outputs, a runnable fitted.toml (with per-element values in
the NPZ it names), and one-line errors with exit code 1 for bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

import pliant as pl
from pliant.cli import main
from tests.test_fit_stages import CLOTH_XPBD, ROPE


@pytest.fixture()
def rope(tmp_path):
    path = tmp_path / "rope.toml"
    path.write_text(ROPE.replace("stiffness = 50.0", "stiffness = 80.0"))  # the scene to fit: k off by 60 %
    truth = tmp_path / "truth.toml"
    truth.write_text(ROPE)
    assert main(["observe", str(truth), "--out", str(tmp_path / "obs.npz"), "--tracks", "5", "-q"]) == 0
    return path, tmp_path / "obs.npz"


def test_fit_writes_the_four_outputs_and_the_fitted_scene_runs(rope, tmp_path, capsys):
    scene, obs = rope
    out = tmp_path / "fit"
    code = main(
        ["fit", str(scene), str(obs), "--out", str(out), "--params", "stiffness", "--iterations", "6", "-q"]
    )
    assert code == 0, capsys.readouterr().err
    for name in ("fitted.toml", "fit.json", "fit.png", "fit.mp4"):
        assert (out / name).stat().st_size > 0, name
    rep = json.loads((out / "fit.json").read_text())
    k = rep["params"]["stiffness"]["value"]
    assert abs(k - 50.0) < abs(80.0 - 50.0) / 2  # closer to the truth than to the start
    assert rep["error"]["train"] < rep["error_nominal"]["train"]
    assert len(rep["error_per_frame"]) == 11 and rep["wall_time"] > 0 and rep["loss_history"]["cmaes"]
    cfg = pl.scene.load_scene(out / "fitted.toml")
    assert cfg.objects[0].material.stiffness == pytest.approx(k)
    assert main(["run", str(out / "fitted.toml"), "--out", str(tmp_path / "run"), "--no-video", "-q"]) == 0


def test_per_element_values_live_in_the_npz_the_toml_names(tmp_path, capsys):
    truth = tmp_path / "truth.toml"
    truth.write_text(CLOTH_XPBD)
    scene = tmp_path / "cloth.toml"
    scene.write_text(CLOTH_XPBD.replace("compliance = 1e-2", "compliance = 2e-2"))
    obs, out = tmp_path / "obs.npz", tmp_path / "fit"
    assert main(["observe", str(truth), "--out", str(obs), "--tracks", "16", "--frames", "6", "-q"]) == 0
    args = ["fit", str(scene), str(obs), "--out", str(out), "--params", "none", "--per-element", "compliance"]
    assert main([*args, "--iterations", "2", "--no-video", "-q"]) == 0, capsys.readouterr().err
    cfg = pl.scene.load_scene(out / "fitted.toml")
    assert cfg.scene.parameters == "fitted_params.npz"
    with np.load(out / "fitted_params.npz") as z:
        fitted = z["constraints.0.compliance_array"]
    assert not np.allclose(fitted, 2e-2)  # the stage moved them
    built = pl.scene.build_scene(cfg)
    np.testing.assert_array_equal(built.solver.constraints[0].compliance_array.numpy(), fitted)
    assert main(["run", str(out / "fitted.toml"), "--out", str(tmp_path / "run"), "--no-video", "-q"]) == 0


def _err(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_bad_inputs_exit_1_with_one_line(rope, tmp_path, capsys):
    scene, obs = rope
    out = str(tmp_path / "f")
    assert main(["fit", str(scene), str(obs), "--out", out, "--params", "stifness", "-q"]) == 1
    assert "--params: unknown parameter 'stifness'" in _err(capsys)
    assert main(["fit", str(scene), str(obs), "--out", out, "--params", "none", "-q"]) == 1
    assert "nothing to fit" in _err(capsys)
    assert main(["fit", str(scene), str(obs), "--out", out, "--smoothness", "-1", "-q"]) == 1
    assert "--smoothness: expected a weight >= 0, got -1.0" in _err(capsys)
    assert main(["fit", str(scene), str(obs), "--out", out, "--validation", "1.5", "-q"]) == 1
    assert "--validation: expected a fraction in [0, 1), got 1.5" in _err(capsys)
    z = dict(np.load(obs))
    np.savez(tmp_path / "slow.npz", **{**z, "t": z["t"] * 2})
    assert main(["fit", str(scene), str(tmp_path / "slow.npz"), "--out", out, "-q"]) == 1
    assert "slow.npz: t: t[1] = 0.08 s but frame 1" in _err(capsys)
    np.savez(tmp_path / "hidden.npz", **{**z, "visible": np.zeros_like(z["visible"])})
    assert main(["fit", str(scene), str(tmp_path / "hidden.npz"), "--out", out, "-q"]) == 1
    assert "hidden.npz: visible: every track is invisible" in _err(capsys)
    assert main(["fit", str(scene), str(tmp_path / "none.npz"), "--out", out, "-q"]) == 1
    assert "observation file not found" in _err(capsys)
    assert main(["observe", str(scene), "--out", out + ".npz", "--dropout", "1.5", "-q"]) == 1
    assert "--dropout" in _err(capsys)


def test_set_overrides_the_scene_for_observe_and_fit(tmp_path, capsys):
    """`--set` works on `observe` and `fit` as on `run`: the observed truth and the fitted start differ only
    by the override, and the fit moves the stiffness from the override toward the truth."""
    truth = tmp_path / "rope.toml"
    truth.write_text(ROPE)
    obs = tmp_path / "obs.npz"
    assert main(["observe", str(truth), "--out", str(obs), "--tracks", "5", "-q"]) == 0
    out = tmp_path / "fit"
    args = [
        "fit",
        str(truth),
        str(obs),
        "--out",
        str(out),
        "--params",
        "stiffness",
        "--iterations",
        "6",
        "-q",
    ]
    assert main([*args, "--set", "objects[0].material.stiffness=80.0"]) == 0, capsys.readouterr().err
    rep = json.loads((out / "fit.json").read_text())
    assert rep["params"]["stiffness"]["nominal"] == pytest.approx(80.0)
    assert abs(rep["params"]["stiffness"]["value"] - 50.0) < 15.0
    assert main([*args, "--set", "objects[0].material.stifness=80.0"]) == 1
    assert "stifness" in capsys.readouterr().err


def test_shooting_flag_reaches_the_fit_and_is_recorded(rope, tmp_path, capsys):
    scene, obs = rope
    out = tmp_path / "fit"
    argv = ["fit", str(scene), str(obs), "--out", str(out), "--params", "stiffness", "--iterations", "2"]
    assert main([*argv, "--shooting", "4", "--no-video", "-q"]) == 0, capsys.readouterr().err
    assert json.loads((out / "fit.json").read_text())["shooting"] == 4
    with pytest.raises(SystemExit):  # argparse: a negative window is refused before any work
        main([*argv, "--shooting", "-1", "-q"])
    assert "expected a number >= 0" in capsys.readouterr().err
