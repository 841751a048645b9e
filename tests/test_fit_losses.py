"""Fitting losses (Warp kernels) against values computed by hand, in float32 and float64, and their tape
gradients against the closed form."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from pliant.fit import acceleration_loss, chamfer_loss, track_errors, track_loss

wp.init()

TYPES = {"float32": (wp.float32, wp.vec3), "float64": (wp.float64, wp.vec3d)}


def _arr(a, t, rg=False):
    return wp.array(np.asarray(a), dtype=t, device="cpu", requires_grad=rg)


@pytest.mark.parametrize("dtype", TYPES)
def test_track_loss_by_hand(dtype):
    """Two frames, two particles, two tracks; β = 0.1 m. Residuals per coordinate (sim − obs):
    frame 0, track 0 → particle 1: (0.05, 0, −0.3): ½·0.05²/0.1 + 0 + (0.3 − 0.05) = 0.0125 + 0.25 = 0.2625;
    frame 0, track 1 → particle 0: hidden; frame 1, track 1 → particle 0: (0, 0.2, 0): 0.2 − 0.05 = 0.15;
    frame 1, track 0: (0, 0, 0.02): ½·0.02²/0.1 = 0.002. Sum 0.4145 over 3 visible × 3 coordinates."""
    s, v = TYPES[dtype]
    x = _arr([[0, 0, 0], [1, 0, 0], [0, 0.2, 0], [1, 0, 0.02]], v)  # frames 0 and 1, 2 particles each
    obs = _arr([[0.95, 0, 0.3], [9, 9, 9], [1, 0, 0], [0, 0, 0]], v)  # frame-major: (frame, track)
    vis = _arr([1, 0, 1, 1], wp.int32)
    out = _arr([0.0], s)
    track_loss(x, _arr([1, 0], wp.int32), obs, vis, out, frames=2, beta=0.1, weight=2.0)
    assert out.numpy()[0] == pytest.approx(2.0 * 0.4145 / 9.0, rel=1e-6)


@pytest.mark.parametrize("dtype", TYPES)
def test_chamfer_loss_by_hand(dtype):
    """Observed points (0.1, 0, 0) and (2, 1, 0) against particles (0,0,0), (2,0,0): nearest squared
    distances 0.01 and 1.0; a padded third point is ignored. Frame 2 has one point, (0, 0, 3): 9. Mean over
    the 3 valid points."""
    s, v = TYPES[dtype]
    x = _arr([[0, 0, 0], [2, 0, 0], [0, 0, 0], [2, 0, 0]], v)
    cloud = _arr([[0.1, 0, 0], [2, 1, 0], [50, 50, 50], [0, 0, 3], [7, 7, 7], [7, 7, 7]], v)
    count = _arr([2, 1], wp.int32)
    out = _arr([0.0], s)
    chamfer_loss(x, cloud, count, out, frames=2)
    assert out.numpy()[0] == pytest.approx((0.01 + 1.0 + 9.0) / 3.0, rel=1e-6)


@pytest.mark.parametrize("dtype", TYPES)
def test_acceleration_loss_by_hand(dtype):
    """One particle at x = 0, 0, 1, 4 (accelerations 1 then 2 per frame²: change 1 in x) and one at rest;
    β = 0.5: smooth_l1(1) = 1 − 0.25 = 0.75; mean over 2 particles × 3 coordinates, weight 0.01."""
    s, v = TYPES[dtype]
    xs = [_arr([[a, 0, 0], [5, 5, 5]], v) for a in (0.0, 0.0, 1.0, 4.0)]
    out = _arr([0.0], s)
    acceleration_loss(*xs, out, beta=0.5, weight=0.01)
    assert out.numpy()[0] == pytest.approx(0.01 * 0.75 / 6.0, rel=1e-6)


def test_track_loss_gradient_on_the_tape():
    """d/dx of the track loss: (x − obs)/β in the quadratic zone, sign(x − obs) beyond, / normaliser."""
    x = _arr([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], wp.vec3d, rg=True)
    obs = _arr([[0.02, 0.0, -0.5], [0.0, 0.0, 0.0]], wp.vec3d)
    out = _arr([0.0], wp.float64, rg=True)
    tape = wp.Tape()
    with tape:
        track_loss(x, _arr([0, 1], wp.int32), obs, _arr([1, 0], wp.int32), out, beta=0.1)
    tape.backward(out)
    np.testing.assert_allclose(x.grad.numpy(), [[-0.2 / 3, 0.0, 1.0 / 3], [0.0, 0.0, 0.0]], rtol=1e-12)


def test_chamfer_gradient_moves_the_nearest_particle_only():
    x = _arr([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]], wp.vec3d, rg=True)
    out = _arr([0.0], wp.float64, rg=True)
    tape = wp.Tape()
    with tape:
        chamfer_loss(x, _arr([[0.1, 0.0, 0.0]], wp.vec3d), _arr([1], wp.int32), out)
    tape.backward(out)
    np.testing.assert_allclose(x.grad.numpy(), [[-0.2, 0.0, 0.0], [0.0, 0.0, 0.0]], rtol=1e-12)


def test_track_errors_are_mean_distances():
    x = np.zeros((2, 2, 3))
    pts = np.array([[[3.0, 4, 0], [np.nan] * 3], [[0, 0, 1.0], [0, 2.0, 0]]])
    vis = np.array([[True, False], [True, True]])
    np.testing.assert_allclose(track_errors(x, np.array([0, 1]), pts, vis), [5.0, 1.5])
