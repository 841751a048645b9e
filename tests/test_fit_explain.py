"""A photometric fit says when the images cannot be explained (pliant/fit/_explain.py): the appearance stage
runs before the physics for a scene without ``[gaussians]`` and is written into ``fitted.toml``; a fit to
images no splats can draw warns; a value at a bound warns; the nominal printed is the scene's value."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import pliant as pl
from pliant.fit import observe_images
from pliant.fit._explain import FitWarning, after_physics
from pliant.fit._params import apply_globals
from pliant.gaussians._scene import scene_gaussians
from pliant.io import Observations
from tests.test_fit_photometric import CLOTH

#: The truth's appearance: another palette on a grey background (a section the fitted scene does not have).
SECTION = (
    '\n[gaussians]\ngenerate = "mesh"\nchecker = 0.1\ncolor = [0.1, 0.2, 0.9]\n'
    "color2 = [0.95, 0.85, 0.1]\nbackground = [0.7, 0.7, 0.7]\n"
)


@pytest.fixture(scope="module")
def truth():
    """The tiny cloth's videos from 2 cameras at 24×18 px, drawn with the SECTION's appearance."""
    cfg = pl.scene.parse_scene(CLOTH + SECTION)
    return observe_images(pl.scene.build_scene(cfg), cameras=2, image_size=(24, 18))


def test_appearance_stage_runs_first_and_is_written_to_fitted_toml(truth, tmp_path):
    cfg = pl.scene.parse_scene(CLOTH)
    with warnings.catch_warnings():
        warnings.simplefilter("error", FitWarning)  # the footage is explained: no warning
        report = pl.fit.fit(
            apply_globals(cfg, {"stiffness": 80.0}),
            truth,
            tmp_path,
            params=["stiffness"],
            generations=2,
            epochs=0,
            progress=False,
            video=False,
        )
    a = report["appearance"]
    assert a["psnr_before_db"] < 10.0 and a["psnr_after_db"] > 25.0, a
    np.testing.assert_allclose(a["background"], [0.7, 0.7, 0.7], atol=0.02)
    assert report["psnr_initial_state_db"] == pytest.approx(a["psnr_after_db"], abs=1e-6)
    assert report["psnr_nominal_train_db"] is not None and report["warnings"] == []
    # held-out frames: the fitted motion (stiffness from 80 towards 50 N/m) draws them better than the nominal
    assert report["psnr_fitted_test_db"] > report["psnr_nominal_test_db"] > 10.0
    # fitted.toml draws the fitted appearance: the same background and the same image at frame 0
    fitted = pl.scene.load_scene(tmp_path / "fitted.toml")
    assert fitted.gaussians is not None and fitted.gaussians.ply.endswith("appearance.ply")
    scene = pl.scene.build_scene(fitted)
    splats = scene_gaussians(scene)
    assert splats.background == pytest.approx(tuple(a["background"]))
    from pliant.gaussians import Camera

    cam = Camera(truth.K[0], truth.world_to_camera[0], 24, 18)
    img = splats.image(scene.model.particle_q_np, cam)
    mse = float(np.mean((img - truth.image(0, 0)) ** 2))
    assert -10 * np.log10(mse) > 25.0


def test_images_that_cannot_be_explained_warn(truth, tmp_path):
    noise = np.random.default_rng(0).random(truth.images.shape)
    obs = Observations.from_arrays(t=truth.t, images=noise, K=truth.K, world_to_camera=truth.world_to_camera)
    cfg = pl.scene.parse_scene(CLOTH)
    with pytest.warns(FitWarning, match=r"do not explain the images at the observed initial state \(PSNR"):
        report = pl.fit.fit(
            cfg, obs, tmp_path, params=["stiffness"], generations=1, epochs=0, progress=False, video=False
        )
    assert report["psnr_initial_state_db"] < 20.0
    assert any("do not explain" in w for w in report["warnings"])


def test_a_value_at_a_bound_warns_and_the_nominal_is_the_scene_value(truth, tmp_path):
    cfg = pl.scene.parse_scene(CLOTH.replace("damping_rate = 0.5", "damping_rate = 0.0"))
    report = pl.fit.fit(
        cfg,
        truth,
        tmp_path,
        params=["stiffness", "damping_rate"],
        generations=1,
        epochs=0,
        progress=False,
        video=False,
    )
    p = report["params"]["damping_rate"]
    lo, hi = p["bounds"]
    assert p["nominal"] == 0.0  # the scene's value, not the search's start √(lo · hi)
    assert p["start"] == pytest.approx(np.sqrt(lo * hi))
    from pliant.fit import PhotometricProblem

    problem = PhotometricProblem(cfg, truth, params=["stiffness", "damping_rate"])
    with pytest.warns(FitWarning, match=rf"damping_rate ended at its upper bound \({hi:g};"):
        after = after_physics(problem, {"stiffness": 50.0, "damping_rate": hi})
    assert len(after["warnings"]) == 1


def test_cli_prints_the_appearance_and_psnr_lines(truth, tmp_path, capsys):
    from pliant.cli import main

    (tmp_path / "s.toml").write_text(CLOTH.replace("stiffness = 50.0", "stiffness = 80.0"))
    truth.save(tmp_path / "obs.npz")
    args = ["fit", str(tmp_path / "s.toml"), str(tmp_path / "obs.npz"), "--out", str(tmp_path / "fit")]
    assert main([*args, "--params", "stiffness", "--iterations", "1", "--no-video", "-q"]) == 0
    out = capsys.readouterr().out
    assert "appearance (frame 0): PSNR " in out and " -> " in out
    assert "PSNR at the start of the physics fit: " in out
    assert "PSNR on the held-out frames: " in out and "(nominal motion " in out


def test_a_scene_with_its_own_section_is_refitted_only_when_asked(truth, tmp_path):
    cfg = pl.scene.parse_scene(CLOTH + SECTION.replace("[0.7, 0.7, 0.7]", "[0.2, 0.2, 0.2]"))
    kw = dict(params=["stiffness"], generations=1, epochs=0, progress=False, video=False)
    with pytest.warns(FitWarning, match="the scene's \\[gaussians\\] section does not describe the footage"):
        rep = pl.fit.fit(cfg, truth, tmp_path / "kept", **kw)  # its section is kept: a wrong background
    assert "appearance" not in rep
    rep = pl.fit.fit(cfg, truth, tmp_path / "refit", appearance=True, **kw)
    np.testing.assert_allclose(rep["appearance"]["background"], [0.7, 0.7, 0.7], atol=0.02)
    g = pl.scene.load_scene(tmp_path / "refit" / "fitted.toml").gaussians
    assert g.ply.endswith("appearance.ply") and g.generate is None and g.bind == "triangles"
    assert g.background == pytest.approx(tuple(rep["appearance"]["background"])) and len(g.light) == 5
