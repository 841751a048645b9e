"""Issue 41, item 2: an image fit's memory (targets, the rasteriser's per-view buffers, the gradient tape) is
estimated before it starts, printed in the fit's plan, and refused above the available memory with advice
unless ``--force``."""

from __future__ import annotations

import pytest
from test_fit_photometric import CLOTH  # the same 4×4 cloth the photometric fit tests use

import pliant as pl
from pliant.cli import main
from pliant.fit import PhotometricProblem, observe_images
from pliant.fit._memory import TILES_PER_GAUSSIAN, image_fit_memory, problem_memory


def test_the_formula_on_a_small_case():
    """C = 2 cameras, T = 5 frames of 6 × 8 px with masks, float64, G = 10 Gaussians, N = 25 particles,
    F = 3 training frames of S = 10 substeps: each term as the module's docstring states it."""
    s, P, G = 8, 6 * 8, 10
    kw = dict(cameras=2, frames=5, height=6, width=8, masks=True, scalar_bytes=s, gaussians=G, particles=25)
    mem = image_fit_memory(**kw, train_frames=3, substeps=10, gradient=True)
    assert mem.targets == 2 * 5 * P * 4 * s == 15360
    view = P * (9 * s + 4) + G * (10 * s + 20 + 24 * TILES_PER_GAUSSIAN)
    assert mem.per_view == view
    assert mem.tape == 2 * 3 * (view + P * 5 * s + G * 10 * s) + 3 * 10 * 25 * 18 * s
    assert mem.total == mem.targets + mem.per_view + mem.tape
    no_grad = image_fit_memory(**kw, train_frames=3, substeps=10, gradient=False)
    assert no_grad.tape == 0 and no_grad.total == mem.targets + view
    assert "gradient tape" in mem.describe() and "gradient tape" not in no_grad.describe()


def test_the_targets_term_is_what_the_fit_allocates():
    """The targets term equals the bytes of the device images and masks the fit's losses read over all
    frames (measured on the Warp arrays), and the per-view term covers one render's outputs."""
    cfg = pl.scene.parse_scene(CLOTH)
    obs = observe_images(pl.scene.build_scene(cfg), cameras=2, image_size=(24, 18), masks=True)
    problem = PhotometricProblem(cfg, obs, params=["stiffness"])
    mem = problem_memory(problem, gradient=True)
    assert mem is not None
    x = problem.simulate(problem.build(problem.nominal), problem.frames)
    problem.frame_losses(x, 0)
    held = sum(a.capacity for pair in problem._targets.values() for a in pair if a is not None)
    assert len(problem._targets) == 2 * obs.frames and mem.targets == held
    colour, alpha, depth = problem.render(problem.build(problem.nominal).model.particle_q, 0)
    outputs = sum(a.capacity for a in (colour, alpha, depth))  # 5 scalars per pixel
    assert outputs < mem.per_view < 4 * outputs + problem.gaussians.count * 400
    # The tape keeps C·F views: at least the renders' outputs of every training view.
    assert mem.tape > 2 * (problem.n_train - 1) * outputs


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("memfit")
    (d / "truth.toml").write_text(CLOTH)
    (d / "cloth.toml").write_text(CLOTH.replace("stiffness = 50.0", "stiffness = 40.0"))
    args = ["observe", str(d / "truth.toml"), "--out", str(d / "obs.npz"), "--cameras", "2"]
    assert main([*args, "--image-size", "24x18", "-q"]) == 0
    return d


def test_an_image_fit_above_the_memory_is_refused_with_advice(files, capsys, monkeypatch):
    """With 1 kB available (device_memory faked), `pliant fit` exits 1 with one line: the estimate, the memory
    available and the advice (fewer frames, a lower resolution, --force), before any rendering; --force runs
    it, printing the estimate in the plan."""
    import pliant.fit._run as run

    monkeypatch.setattr(run, "device_memory", lambda device: 1e3)
    out = files / "fit"
    args = [
        "fit",
        str(files / "cloth.toml"),
        str(files / "obs.npz"),
        "--out",
        str(out),
        "--params",
        "stiffness",
    ]
    args += ["--iterations", "1", "--no-video"]
    capsys.readouterr()
    assert main([*args, "-q"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "this image fit needs about" in err[0] and "1 kB is available" in err[0], err
    assert "fewer frames" in err[0] and "lower image resolution" in err[0] and "--force" in err[0], err
    assert not (out / "fitted.toml").exists() and not (out / "appearance.ply").exists()
    assert main([*args, "--force"]) == 0
    printed = capsys.readouterr().out
    line = next(ln for ln in printed.splitlines() if ln.startswith("  memory: about"))
    assert "targets" in line and "per view" in line and "gradient tape" in line and "1 kB available" in line
    assert (out / "fitted.toml").exists()
