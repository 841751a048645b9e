"""Visual correction (pl.gaussians.VisualCorrector): a simulation with wrong stiffness pulled back toward a
"real" twin seen by three cameras."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from pliant.bench._gaussians import _beam_sim, _cloth_sim, _cloth_sim_implicit, visual_correction_drift
from pliant.gaussians import Camera, Gaussians, VisualCorrector, bind, render


def _blob_scene():
    g1 = np.linspace(-0.3, 0.3, 4)
    rng = np.random.default_rng(2)
    # jittered, and cameras off the lattice axes: equal depths would make the sort order (and so the image)
    # jump under tiny motions
    X = np.stack(np.meshgrid(g1, g1, g1, indexing="ij"), -1).reshape(-1, 3) + rng.normal(0, 0.01, (64, 3))
    g = Gaussians.from_values(X, scales=0.07, opacities=0.8, colors=rng.uniform(0, 1, X.shape), device="cpu")
    b = bind(g, X, method="lbs", k=4, neighbours=8)
    cams = [
        Camera.look_at([2.5 * np.sin(a), 0.8, 2.5 * np.cos(a)], [0, 0, 0], width=64, height=48)
        for a in (0.3, 2.4, 4.5)
    ]
    return X, b, cams


def test_state_estimate_recovers_a_shift_seen_by_three_cameras():
    X, b, cams = _blob_scene()
    shift = np.array([0.03, -0.02, 0.01])
    observed = [render(b.deform(wp.array(X + shift, dtype=wp.vec3)), c).colour.numpy() for c in cams]
    vc = VisualCorrector(b, cams, iterations=15)
    est = vc.estimate(wp.array(X, dtype=wp.vec3), observed)
    # the mean displacement is recovered to a tenth of its length
    assert np.linalg.norm((est - X).mean(axis=0) - shift) < 0.1 * np.linalg.norm(shift)
    # fixed particles stay; the trust region bounds every coordinate's change
    fixed = np.zeros(len(X), bool)
    fixed[:5] = True
    vc = VisualCorrector(b, cams, iterations=15, max_step=0.01)
    est = vc.estimate(wp.array(X, dtype=wp.vec3), observed, fixed=fixed)
    np.testing.assert_allclose(est[:5], X[:5], atol=1e-7)
    assert np.abs(est - X).max() <= 0.01 + 1e-7


def test_visual_correction_rejects_bad_settings():
    X, b, cams = _blob_scene()
    with pytest.raises(ValueError, match="unknown visual correction method"):
        VisualCorrector(b, cams, method="magic")
    with pytest.raises(ValueError, match="position_gain must lie in"):
        VisualCorrector(b, cams, position_gain=1.5)
    with pytest.raises(ValueError, match="max_step must be a positive"):
        VisualCorrector(b, cams, max_step=0.0)


def test_correction_halves_the_drift_of_a_too_soft_xpbd_shape_matching_beam():
    # 10 frames of a clamped beam under XPBD shape matching, k_S = 0.1 simulated against 0.3 "real"
    r = visual_correction_drift(_beam_sim, 0.3, 0.1, 10)
    assert r["mean_drift_reduction"] >= 0.5, r
    assert r["final_drift_reduction"] >= 0.5, r


def test_correction_reduces_the_drift_of_a_too_soft_cloth_force_solver():
    # 8 frames of the pinned cloth (ForceSolver), k = 100 N/m simulated against 300 N/m "real"
    r = visual_correction_drift(_cloth_sim, 300.0, 100.0, 8)
    assert r["mean_drift_reduction"] >= 0.4, r
    assert r["final_drift_corrected_m"] < r["final_drift_uncorrected_m"], r


@pytest.mark.slow
@pytest.mark.parametrize(
    "make,k_true,k_sim",
    [(_cloth_sim, 300.0, 100.0), (_cloth_sim_implicit, 300.0, 100.0), (_beam_sim, 0.3, 0.1)],
    ids=["cloth", "cloth_backward_euler", "xpbd_beam"],
)
def test_visual_correction_figure(make, k_true, k_sim):
    # the figure: 3x wrong stiffness, 3 cameras, >= 50 % less mean drift over 30 frames (1 s),
    # and less final drift too
    r = visual_correction_drift(make, k_true, k_sim, 30)
    assert r["mean_drift_reduction"] >= 0.5, r
    assert r["final_drift_reduction"] >= 0.5, r


def test_embodied_gaussians_forces_stay_available():
    X, b, cams = _blob_scene()
    shift = np.array([0.03, -0.02, 0.01])
    observed = [render(b.deform(wp.array(X + shift, dtype=wp.vec3)), c).colour.numpy() for c in cams]
    sim = _Sim(X)
    vc = VisualCorrector(b, cams, method="forces")
    vc.correct(sim, observed)
    once = sim.control.particle_f.numpy().copy()
    assert np.dot(once.sum(axis=0), shift) > 0.8 * np.linalg.norm(once.sum(axis=0)) * np.linalg.norm(shift)
    # a second call replaces the corrector's own contribution instead of adding to it
    vc.correct(sim, observed)
    np.testing.assert_allclose(sim.control.particle_f.numpy(), once, rtol=1e-5, atol=1e-9)


class _Sim:
    """The few Simulator attributes the corrector reads (free particles of mass 1 g)."""

    def __init__(self, X: np.ndarray) -> None:
        from pliant.model import ModelBuilder

        b = ModelBuilder()
        b.add_particles(X, 1e-3)
        self.model = b.finalize(device="cpu", dtype="float32")
        self.state_0 = self.model.state()
        self.control = self.model.control()
        self.frame_dt = 1 / 30
