"""What holds the twin and what it rests on, found from motion alone (issue 37, item 3): the clamp of a
cantilever, no clamp on a free fall, the ground under a dropped box and none under a hanging beam. The
clouds here are the simulated surface vertices of each frame (what depth would see); tests/test_twin.py
runs the same detectors on clouds made from pliant-rendered pictures."""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl
from pliant.twin import detect_fixed, detect_ground


def _surface_clouds(name: str, frames: int, overrides: tuple[str, ...] = ()) -> tuple[np.ndarray, np.ndarray]:
    """(positions [T, N, 3] of every particle, surface vertex indices) of a built-in scene's run."""
    scene = pl.scene.build_scene(pl.scene.load_scene(name, overrides))
    x = scene.simulator().run(frames, progress=False).x
    tets = scene.model.tet_indices.numpy()
    surf = np.unique(pl.geometry.surface_from_tets(tets))
    return x, surf


def _clouds(x: np.ndarray, surf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = x[:, surf]
    return c, np.full(len(x), len(surf))


@pytest.fixture(scope="module")
def cantilever():
    return _surface_clouds("cantilever", 30)


def test_the_clamp_of_a_cantilever_is_found(cantilever):
    x, surf = cantilever
    clouds, counts = _clouds(x, surf)
    found = detect_fixed(x[0], clouds, counts, tol=1e-4, spacing=0.0375)
    held = x[0, found.fixed]
    # The scene's clamp: the kinematic particles in a 1 cm box at x = -0.3 (the beam's left end face).
    assert found.fixed.sum() >= 9, found.reason
    assert held[:, 0].max() < -0.3 + 0.0375 * 1.01, "only the clamped end is held"
    assert len(found.boxes) == 1
    c, h = found.boxes[0]
    assert abs(c[0] - held[:, 0].mean()) < 0.04 and np.all(h > 0)
    # The tip moves: its particles are free.
    assert not found.fixed[np.argmax(x[0, :, 0])]


def test_no_clamp_on_a_free_fall():
    x, surf = _surface_clouds("cantilever", 12, ("handles=[]", "ground.height=-10.0"))
    clouds, counts = _clouds(x, surf)
    found = detect_fixed(x[0], clouds, counts, tol=1e-4, spacing=0.0375)
    assert found.fixed.sum() == 0 and found.boxes == []
    assert "free" in found.reason


def test_the_ground_under_a_dropped_box_is_found():
    x, surf = _surface_clouds("fem_drop", 40)
    clouds, counts = _clouds(x, surf)
    g = detect_ground(clouds, counts, spacing=0.0625)
    assert g.height is not None, g.reason
    assert abs(g.height - 0.0) < 0.02  # the scene's ground, less the contact's penetration


def test_no_ground_under_a_hanging_beam(cantilever):
    x, surf = cantilever
    clouds, counts = _clouds(x, surf)
    g = detect_ground(clouds, counts, spacing=0.0375)
    assert g.height is None, g.reason


def test_a_floor_seen_far_below_is_not_used(cantilever):
    x, surf = cantilever
    clouds, counts = _clouds(x, surf)
    rng = np.random.default_rng(0)
    floor = np.column_stack([rng.uniform(-1, 1, 2000), np.zeros(2000), rng.uniform(-1, 1, 2000)])
    g = detect_ground(clouds, counts, spacing=0.0375, background=floor)
    assert g.height is None and g.seen_height == pytest.approx(0.0, abs=1e-6), g.reason
    near = detect_ground(clouds, counts, spacing=0.0375, background=floor + [0, x[:, :, 1].min() - 0.01, 0])
    assert near.height == pytest.approx(x[:, :, 1].min() - 0.01, abs=1e-3), near.reason
