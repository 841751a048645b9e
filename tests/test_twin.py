"""``pliant twin`` end to end on pictures pliant renders of a cantilever (issue 37): the volume carved, the
clamp found, no ground invented, the fit run, the twin written as a scene that runs and renders, and every
bad input refused in one line naming the array. The cross-engine figures (MuJoCo's beam) are the slow test
in tests/test_twin_slow.py."""

from __future__ import annotations

import json

import numpy as np
import pytest

import pliant as pl
from pliant.twin import TwinError, TwinOptions, build_twin

FRAMES = 16


@pytest.fixture(scope="module")
def footage():
    """A 0.6 m FEM cantilever (the built-in scene, backward Euler: another model and integrator than the
    twin's) filmed by 4 cameras at 96 × 72 with masks and depth."""
    cfg = pl.scene.load_scene("cantilever", [f"scene.frames={FRAMES}"])
    return pl.fit.observe_images(
        pl.scene.build_scene(cfg), cameras=4, image_size=(96, 72), masks=True, depth=True, uint8=True
    )


@pytest.fixture(scope="module")
def twin(footage, tmp_path_factory):
    out = tmp_path_factory.mktemp("twin")
    opts = TwinOptions(generations=2, splat_iterations=20, max_particles=800, progress=False)
    return out, build_twin(footage, out, opts)


def test_the_twin_is_written_and_runs(twin):
    out, rep = twin
    for name in rep["files"]:
        assert (out / name).is_file(), name
    assert json.loads((out / "twin.json").read_text())["particles"] == rep["particles"]
    cfg = pl.scene.load_scene(out / "twin.toml")
    assert cfg.solver.integrator == "ImplicitMidpoint"  # no numerical damping
    x = pl.scene.build_scene(cfg).simulator().run(3, progress=False).x
    assert np.all(np.isfinite(x))
    assert [s["step"] for s in rep["steps"]] == [
        "reconstruct",
        "splats",
        "model",
        "observe",
        "ground",
        "fixed",
        "fit",
        "evaluate",
    ]


def test_the_volume_and_the_clamp_are_found(twin):
    out, rep = twin
    x0 = np.load(out / "twin_rollout.npz")["x"][0]
    lo, hi = x0.min(axis=0), x0.max(axis=0)
    # The true beam: 0.6 × 0.1 × 0.1 m centred at (0, 0.6, 0); carved to within two voxels on every side.
    s = rep["spacing_m"]
    assert np.all(np.abs(lo - [-0.3, 0.55, -0.05]) <= 2 * s) and np.all(
        np.abs(hi - [0.3, 0.65, 0.05]) <= 2 * s
    )
    fixed = rep["fixed"]
    assert fixed["fixed_particles"] > 0 and len(fixed["boxes"]) == 1, fixed["reason"]
    assert fixed["boxes"][0]["center"][0] < -0.2  # at the clamped end
    assert rep["ground"]["height"] is None, rep["ground"]["reason"]


def test_the_twin_predicts_better_than_standing_still(twin):
    _, rep = twin
    m = rep["metrics"]
    assert m["chamfer_mm"]["test"] < m["chamfer_still_mm"]["test"]
    assert m["iou"]["train"] > 0.6


def test_the_model_is_chosen_by_validation(footage, tmp_path):
    opts = TwinOptions(
        generations=1, splat_iterations=10, max_particles=400, models=("fem", "springs"), progress=False
    )
    rep = build_twin(footage, tmp_path, opts)
    losses = {m: r["validation_loss"] for m, r in rep["models"].items()}
    assert set(losses) == {"fem", "springs"} and rep["model"] == min(losses, key=losses.__getitem__)
    cfg = pl.scene.load_scene(tmp_path / "twin.toml")
    assert cfg.objects[0].kind == ("points" if rep["model"] == "springs" else "mesh")


def test_masks_are_required(footage, tmp_path):
    obs = pl.io.Observations.from_arrays(
        t=footage.t, images=footage.images, K=footage.K, world_to_camera=footage.world_to_camera
    )
    with pytest.raises(TwinError, match=r"masks: pliant twin needs"):
        build_twin(obs, tmp_path, TwinOptions(progress=False))


def test_ray_without_ray_is_refused_before_any_work(footage, tmp_path, monkeypatch):
    """``ray=True`` (``pliant twin --ray``) where Ray cannot be imported: one line naming the pip command,
    before the output folder is made (not after the carving and the splats)."""
    import sys

    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(TwinError, match=r"^--ray needs Ray, an optional extra: pip install"):
        build_twin(footage, tmp_path / "out", TwinOptions(ray=True, progress=False))
    assert not (tmp_path / "out").exists()


def test_a_camera_that_disagrees_with_the_masks_is_named(footage, tmp_path):
    w2c = footage.world_to_camera.copy()
    w2c[2, :3, 3] += [0.5, 0.0, 0.0]  # camera 2 half a metre off
    obs = pl.io.Observations.from_arrays(
        t=footage.t, images=footage.images, K=footage.K, world_to_camera=w2c, masks=footage.masks
    )
    with pytest.raises(TwinError, match=r"camera 2") as e:
        build_twin(obs, tmp_path, TwinOptions(progress=False, spacing=0.02))
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("metres", [1e30, 3e38])
def test_depth_in_absurd_units_is_named(footage, tmp_path, metres):
    """Found by tests/test_fuzz_observations.py: depth readings of 1e30 m left no reading after the outlier
    filter, and NumPy's 'zero-size array' escaped (3e38 m: the filter's radius overflows)."""
    import warnings

    depth = np.where(np.stack([footage.depth[c] for c in range(footage.cameras)]) > 0, metres, 0.0)
    obs = pl.io.Observations.from_arrays(
        t=footage.t,
        images=footage.images,
        K=footage.K,
        world_to_camera=footage.world_to_camera,
        masks=footage.masks,
        depth=depth,
        source="beam.npz",
    )
    with warnings.catch_warnings(), pytest.raises(TwinError) as e:
        warnings.simplefilter("error")
        build_twin(obs, tmp_path, TwinOptions(progress=False))
    assert str(e.value).startswith("beam.npz: depth: fewer than 8 readings inside the masks at frame 0 lie")
    assert not list(tmp_path.iterdir())


def test_the_twin_runs_live_with_its_splats_and_can_be_dragged(twin):
    from pliant.gaussians._scene import scene_splats
    from pliant.live import LiveSession

    out, _ = twin
    scene = pl.scene.build_scene(pl.scene.load_scene(out / "twin.toml"), device="cpu")
    session = LiveSession(scene)
    # The twin predicts with the implicit midpoint rule; hands on it get backward Euler (MuJoCo's beam twin
    # diverged under a drag with the midpoint rule: its stiff modes ring on at full amplitude).
    assert type(session.sim.solver.integrator).__name__ == "BackwardEuler" and "BackwardEuler" in session.note
    splats = scene_splats(scene.config, scene)  # what `pliant view` draws, bound to the particles
    placed = splats.place(session.x)
    assert placed.count > 0 and np.all(np.isfinite(placed.means.numpy()))
    tip = int(np.argmax(session.x[:, 0]))  # the free end, far from the clamp
    target = session.x[tip] + [0.0, 0.2, 0.0]
    session.grab(tip, target)
    for _ in range(10):
        session.step(1)
    assert session.x[tip, 1] > target[1] - 0.2 + 0.05  # lifted toward the cursor, not left to sag
    session.release()
    assert session.control.drag_index == -1
    session.step(30)  # let go: it swings back and settles without blowing up
    assert np.all(np.isfinite(session.x)) and np.abs(session.x).max() < 2.0


def test_no_clamp_is_invented_on_pictures_of_a_free_fall():
    cfg = pl.scene.load_scene("cantilever", ["scene.frames=10", "handles=[]", "ground.height=-10.0"])
    obs = pl.fit.observe_images(pl.scene.build_scene(cfg), cameras=4, image_size=(96, 72), masks=True)
    h = 0.02
    clouds, counts = pl.geometry.frame_clouds(obs.K, obs.world_to_camera, obs.masks, spacing=h)
    found = pl.twin.detect_fixed(clouds[0, : counts[0]], clouds, counts, tol=0.5 * h, spacing=h)
    assert found.fixed.sum() == 0 and found.boxes == [], found.reason
