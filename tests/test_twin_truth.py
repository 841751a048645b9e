"""The twin yardstick (tests/twin_truth.py, issue 37) against closed forms on the MuJoCo beam's truth: the
distance to the solid, uniform volume samples, the Chamfer distance of particle grids, and the motion ratio
of the truth itself and of the truth one frame late."""

from __future__ import annotations

import numpy as np
import pytest
import twin_truth as tt

#: Mean distance from a uniform point of the unit cube to its centre (half the mean distance from a corner of
#: the unit cube to a uniform point in it, 0.9605919564…).
CUBE_CENTRE_MEAN = 0.4802959782


@pytest.fixture(scope="module")
def truth():
    return tt.load_beam_truth()


def _box(truth):
    x0 = truth["x"][0]
    return x0.min(axis=0), x0.max(axis=0)


def _grid(lo, hi, h):
    """Particles at the centres of cells of side ``h`` [m] from ``lo``, those inside ``hi``."""
    axes = [np.arange(lo[d] + 0.5 * h, hi[d], h) for d in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def test_distance_to_the_solid_is_the_boxs(truth):
    # At frame 0 the beam is a box: the distance to it is |max(0, lo - q, q - hi)|, 0 inside.
    lo, hi = _box(truth)
    q = lo + (hi - lo) * np.random.default_rng(1).uniform(-0.5, 1.5, size=(400, 3))
    d = tt.distance_to_solid(q, truth["x"][0], truth["tets"])
    exact = np.linalg.norm(np.maximum(0.0, np.maximum(lo - q, q - hi)), axis=1)
    np.testing.assert_allclose(d, exact, atol=1e-12)
    assert (d == 0).mean() > 0.05  # some points were inside


def test_volume_samples_are_uniform_in_the_solid(truth):
    lo, hi = _box(truth)
    x0, tets = truth["x"][0], truth["tets"]
    s = tt.volume_samples(x0, tets, 20_000, seed=2)
    assert np.all(tt.distance_to_solid(s, x0, tets) == 0.0)
    np.testing.assert_allclose(tt.tet_volumes(x0, tets).sum(), np.prod(hi - lo), rtol=1e-12)
    # A uniform box: mean at the centre, per-axis variance L^2 / 12 (to a few standard errors).
    L = hi - lo
    assert np.all(np.abs(s.mean(axis=0) - 0.5 * (lo + hi)) < 4 * L / np.sqrt(12 * 20_000))
    np.testing.assert_allclose(s.var(axis=0), L**2 / 12, rtol=0.04)


def test_embedding_reproduces_inside_points_and_clamps_outside_ones(truth):
    x0, tets = truth["x"][0], truth["tets"]
    lo, hi = _box(truth)
    p = lo + (hi - lo) * np.random.default_rng(3).uniform(-0.2, 1.2, size=(500, 3))
    e, b, inside = tt.embed(p, x0, tets)
    inside_box = np.all((p >= lo) & (p <= hi), axis=1)
    np.testing.assert_array_equal(inside, inside_box)
    assert np.all(b >= 0) and np.allclose(b.sum(axis=1), 1.0)
    back = np.einsum("nk,nkd->nd", b, x0[tets[e]])
    np.testing.assert_allclose(back[inside], p[inside], atol=1e-12)
    # Outside, the clamped coordinates put the point on its tet: inside the solid.
    assert np.all(tt.distance_to_solid(back, x0, tets) < 1e-12)


def test_chamfer_of_particle_grids_is_calibrated(truth):
    # Cell-centred grids filling the beam: every particle inside (first term 0), every volume sample within
    # its own cell, at 0.4803 h from the particle on average: 4.8 mm at 1 cm. A 3 cm grid cannot pass 6 mm.
    x0, tets = truth["x"][0], truth["tets"]
    lo, hi = _box(truth)
    one = tt.chamfer_to_volume(_grid(lo, hi, 0.01), x0, tets)
    assert one == pytest.approx(CUBE_CENTRE_MEAN * 0.01, rel=0.01)
    two = tt.chamfer_to_volume(_grid(lo, hi, 0.02), x0, tets)
    assert two == pytest.approx(CUBE_CENTRE_MEAN * 0.02, rel=0.01)
    three = tt.chamfer_to_volume(_grid(lo, hi, 0.03), x0, tets)
    assert three > 0.012
    # Particles outside pay their distance: the 1 cm grid moved 1 cm up fails 6 mm; the truth's own vertices
    # (on the surface and inside) score 0.48 of their 2 cm spacing or less.
    assert tt.chamfer_to_volume(_grid(lo, hi, 0.01) + [0.0, 0.01, 0.0], x0, tets) > 0.006
    assert tt.chamfer_to_volume(x0, x0, tets) < CUBE_CENTRE_MEAN * 0.02


def test_motion_ratio_of_the_truth_and_of_a_one_frame_lag(truth):
    x, tets, t = truth["x"], truth["tets"], truth["t"]
    frames = tt.heldout_frames(len(t))
    assert frames[0] == len(t) - int(np.ceil(0.3 * len(t))) and frames[-1] == len(t) - 1
    p0 = tt.volume_samples(x[0], tets, 3000, seed=4)
    m = tt.material_points(p0, x, tets)
    np.testing.assert_allclose(m[0], p0, atol=1e-12)
    assert tt.material_error(m, x, tets, frames) < 1e-12
    assert tt.motion_ratio(m, x, tets, frames) < 1e-9
    # The static shape held at the material points' mean is the baseline itself: ratio 1.
    still = np.repeat(m[frames].mean(axis=0)[None], len(t), axis=0)
    still[0] = p0
    assert tt.motion_ratio(still, x, tets, frames) == pytest.approx(1.0, rel=1e-9)
    # One frame late: for a swing A sin(2 pi t / P) the lag error over the static one is 2 sin(pi dt / P)
    # (mean |A sin(a) - A sin(a - w dt)| over mean |A sin(a)|), with P the tip's period on those frames.
    lag = np.concatenate([m[:1], m[:-1]])
    ratio = tt.motion_ratio(lag, x, tets, frames)
    tip = np.abs(x[0, :, 0] - x[0, :, 0].max()) < 1e-9
    y = x[frames][:, tip, 1].mean(axis=1)
    cross = np.flatnonzero(np.diff(np.sign(y - y.mean())) != 0)  # every half period
    period = 2 * np.mean(np.diff(t[frames][cross]))
    dt = t[1] - t[0]
    assert ratio == pytest.approx(2 * np.sin(np.pi * dt / period), rel=0.1)
    assert 0.3 < ratio < 0.5 < tt.motion_ratio(np.concatenate([m[:2], m[:-2]]), x, tets, frames)


def test_bad_input_names_the_array(truth):
    x, tets = truth["x"], truth["tets"]
    with pytest.raises(ValueError, match="particles_x: need"):
        tt.material_error(x[:5], x, tets, [1])
    with pytest.raises(ValueError, match="frames: need"):
        tt.material_error(x, x, tets, [len(x)])
    with pytest.raises(ValueError, match="tets: need"):
        tt.volume_samples(x[0], tets[:, :3], 10)
    with pytest.raises(ValueError, match="particles: need"):
        tt.chamfer_to_volume(np.zeros((0, 3)), x[0], tets)
