"""The fixtures made each engine's own way (issue 38, item 5; tests/data/foreign/*_own, made by
benchmarks/peers/observe_own.py): MuJoCo's even flexcomp masses and default soft contact, Newton's own
particle masses and default penalty ground. Each loads, says what it is, starts as a free fall, has the
mass distribution its sidecar names, and its scene is pliant's defaults (not the engine's masses).

These check the data, not how well pliant fits it (benchmarks/fit_own_fixtures.py measures that).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import pliant.io
import pliant.scene

DATA = Path(__file__).resolve().parent / "data" / "foreign"
G = 9.81

#: name -> (engine prefix, fitted material key of the scene, substeps per frame the engine ran)
OWN = {
    "mujoco_cloth_own": ("mujoco 4.0", "Et", 20),
    "mujoco_cube_own": ("mujoco 4.0", "E", 20),  # dropped from rest (issue 38's cube)
    "mujoco_cube_own_thrown": ("mujoco 4.0", "E", 20),  # thrown as mujoco_cube
    "newton_cloth_own": ("newton 1.8", "Et", 200),
    "newton_box_own": ("newton 1.8", "E", 100),
}
SOLIDS = ("mujoco_cube_own", "mujoco_cube_own_thrown", "newton_box_own")


def _meta(name: str) -> dict:
    return json.loads((DATA / f"{name}.json").read_text())


def _truth(name: str) -> np.ndarray:
    return pliant.io.Observations.load(DATA / _meta(name)["truth"]).points


def _scene(name: str):
    cfg = pliant.scene.load_scene(DATA / _meta(name)["scene"])
    return cfg, pliant.scene.build_scene(cfg, device="cpu")


@pytest.mark.parametrize("name", sorted(OWN))
def test_own_fixture_loads_with_its_shapes_and_provenance(name):
    engine, key, _ = OWN[name]
    meta = _meta(name)
    obs = pliant.io.Observations.load(DATA / f"{name}.npz")
    truth = pliant.io.Observations.load(DATA / meta["truth"])
    cfg, scene = _scene(name)
    n = scene.model.particle_count
    assert meta["engine"].startswith(engine) and meta["data"].startswith("SYNTHETIC")
    assert meta["made_the_engines_own_way"] is True
    assert obs.points.shape == (61, meta["tracks"], 3) == (meta["frames"], 40, 3)
    assert truth.points.shape == (61, n, 3) and truth.visible.all()
    np.testing.assert_allclose(obs.t, np.arange(61) / meta["fps"], atol=1e-12)
    obs.check_times(cfg.scene.frame_dt, "the fixture's scene")
    # The noise is the sidecar's, around the true vertices the tracks follow.
    res = obs.points - truth.points[:, meta["track_vertex"]]
    assert abs(np.std(res[obs.visible]) / meta["noise_std_m"] - 1.0) < 0.05
    # The truth is recorded, and the scene starts from it made too soft by the recorded factor.
    nominal = meta["material_pliant_nominal"]
    assert getattr(cfg.objects[0].material, key) == pytest.approx(nominal[key])
    assert meta["truth_values"][key if key == "E" else "Et"] == meta["material_pliant_converted"][key]
    assert meta["material_pliant_converted"][key] / nominal[key] == pytest.approx(
        nominal["factor_too_soft"], rel=0.01
    )
    # Every engine vertex sits on one of pliant's particles at frame 0 (within 1 mm), one to one.
    x0 = scene.model.particle_q_np
    d = np.linalg.norm(truth.points[0][:, None] - x0[None], axis=2)
    assert d.min(axis=1).max() < 1e-3 and np.unique(d.argmin(axis=1)).size == n


@pytest.mark.parametrize("name", sorted(OWN))
def test_own_fixture_has_the_engines_even_masses_not_pliants(name):
    """The sidecar's mass distribution is "even": every free vertex weighs the same in the engine, which
    pliant's default lumping (by area or volume) does not, and the scene keeps pliant's default."""
    meta = _meta(name)
    md = meta["mass_distribution"]
    assert md["kind"] == "even"
    m = np.asarray(md["vertex_mass_kg"])
    free = m > 0
    assert free.sum() >= 100 and m[free].max() / m[free].min() == pytest.approx(1.0, abs=1e-6)
    assert md["free_mass_spread"] == pytest.approx(1.0, abs=1e-6)
    assert m[free].sum() == pytest.approx(meta["free_mass_kg"], rel=1e-6)
    lumped = np.asarray(md["pliant_default_vertex_mass_kg"])
    assert lumped[free].max() / lumped[free].min() > 1.9  # corners against inner vertices
    # pliant's scene lumps as pliant does: its particles carry the lumped masses, not the engine's.
    _, scene = _scene(name)
    x0 = scene.model.particle_q_np
    nearest = np.linalg.norm(_truth(name)[0][:, None] - x0[None], axis=2).argmin(axis=1)
    pm = scene.model.particle_mass_np[nearest]
    np.testing.assert_allclose(pm[free] / pm[free].sum(), lumped[free] / lumped[free].sum(), rtol=1e-6)


@pytest.mark.parametrize("name", sorted(OWN))
def test_own_fixture_starts_as_a_free_fall(name):
    """Replays the first frames of the truth: before any strain or contact every free vertex moves as one
    rigid body under g (the generator's check on the engine's masses, gravity and inertia: a vertex whose
    gravity and inertia disagreed would fall at another rate)."""
    _, _, substeps = OWN[name]
    meta = _meta(name)
    x = _truth(name)
    dt = 1.0 / meta["fps"]
    still = np.abs(x - x[:1]).max(axis=(0, 2)) < 1e-6
    if still.any():  # cloths: far from the pins for one frame (their pull has not reached there)
        gap = np.linalg.norm(x[0][:, None] - x[0][still][None], axis=2).min(axis=1)
        use, frames = gap > 0.3 * float(np.ptp(x[0], axis=0).max()), 1
        v0 = np.zeros(3)
    else:  # dropped or thrown solids: every vertex, while the lowest stays 10 cm above the ground
        use = np.ones(len(x[0]), bool)
        frames = int(np.argmax(x[:, :, 1].min(axis=1) < 0.1)) - 1
        v0 = np.asarray(pliant.scene.load_scene(DATA / meta["scene"]).objects[0].velocity)
    assert use.sum() >= 10 and frames >= 1
    for f in range(1, frames + 1):
        t = f * dt
        # The engines step in substeps h: the exact drop of their Euler steps is g h² k (k + 1) / 2 at
        # k = t / h, the free fall's g t² / 2 plus g h t / 2.
        h = dt / substeps
        want = x[0, use] + v0 * t + np.array([0.0, -0.5 * G * t * (t + h), 0.0])
        err = np.abs(x[f, use] - want).max()
        assert err < 0.02 * 0.5 * G * t * t + 2e-5, f"{name} frame {f}: {err * 1e3:.3f} mm off a free fall"


@pytest.mark.parametrize("name", SOLIDS)
def test_own_solid_sinks_into_the_engines_soft_ground(name):
    """The engines' soft contact lets the vertices sink well below a contact radius: more than 5 mm of
    penetration, recorded in the sidecar, with the contact parameters the engine used."""
    meta = _meta(name)
    x = _truth(name)
    radius = meta["material_engine"]["contact_radius_m"]
    low = float(x[..., 1].min())
    assert meta["max_penetration_m"] == pytest.approx(radius - low, abs=1e-6)  # float32 truth
    assert meta["max_penetration_m"] > 5e-3 and low < 0.0
    assert x[0, :, 1].min() > 0.1  # it starts in the air
    # It comes to rest on the ground: the lowest vertex ends within a contact radius of it.
    assert abs(x[-1, :, 1].min()) < radius
    cfg, _ = _scene(name)
    assert cfg.ground is not None and cfg.ground.stiffness is None  # pliant's default ground
    assert cfg.objects[0].particle_radius is None  # pliant's default radius
    assert cfg.ground.friction == meta["material_engine"]["friction"]


def test_mujoco_cube_own_has_mujocos_default_contact():
    c = _meta("mujoco_cube_own")["contact"]
    assert c["solref"] == [0.02, 1.0] == c["solref_ground_geom"]
    assert c["solimp"] == pytest.approx([0.9, 0.95, 0.001, 0.5, 2.0])
    assert c["friction"][0] == 1.0 and c["flex_radius_m"] == 0.005 and c["condim"] == 3


def test_newton_box_own_has_newtons_default_contact_and_grid_masses():
    meta = _meta("newton_box_own")
    c = meta["contact"]
    for k in ("ke", "kd", "mu"):
        assert c[f"effective_{k}"] == pytest.approx(0.5 * (c["model_soft_contact"][k] + c["ground_shape"][k]))
    # add_soft_grid puts one cell's mass on each of the (n+1)³ particles: (5/4)³ × ρV for 4 cells a side.
    assert meta["total_mass_over_rho_V"] == pytest.approx((5 / 4) ** 3)
