"""The independent intersection test (tests/intersections.py, by ipctk) on meshes whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("ipctk")

from intersections import Part, grid_triangles, intersecting_frames, sphere_mesh  # noqa: E402


def _sheet(n: int, size: float, height: float) -> np.ndarray:
    """(n+1)² vertices [m] of a square sheet in the plane y = height, centred on the y axis."""
    u = np.linspace(-size / 2, size / 2, n + 1)
    x, z = np.meshgrid(u, u, indexing="xy")
    return np.stack([x.ravel(), np.full(x.size, height), z.ravel()], 1)


def test_two_sheets_apart_and_crossing():
    tri = grid_triangles(4, 4)
    low = _sheet(4, 1.0, 0.0)
    # Frame 0: 1 mm apart (parallel); frame 1: the upper sheet tilted through the lower one.
    high0 = _sheet(4, 1.0, 1e-3)
    high1 = high0.copy()
    high1[:, 1] = 0.3 * high1[:, 0]
    parts = [Part(tri, np.stack([low, low])), Part(tri, np.stack([high0, high1]))]
    assert intersecting_frames(parts) == [1]


def test_a_sheet_folded_through_itself():
    # A strip folded over: columns 0–8 lie on y = 0 (x from 0 to 1), columns 9–16 come back 2 mm above
    # (x from 1 to 1/8; the hinge panel is vertical). Then the far end dips 4 mm below the near half.
    tri = grid_triangles(16, 2)
    k, z = np.meshgrid(np.arange(17), np.linspace(0, 0.5, 3), indexing="xy")
    k, z = k.ravel(), z.ravel()
    upper = k >= 9
    x = np.where(upper, (17 - k) / 8, k / 8)
    fold = np.stack([x, np.where(upper, 2e-3, 0.0), z], 1)
    through = fold.copy()
    through[:, 1] = np.where(upper, 2e-3 - 6e-3 * (1 - x), 0.0)  # +2 mm at the hinge, −3.25 mm at x = 1/8
    assert intersecting_frames([Part(tri, np.stack([fold, through]))]) == [1]


def test_a_cloth_around_a_sphere():
    v, f = sphere_mesh((0.0, 0.0, 0.0), 0.1, 2)
    assert np.allclose(np.linalg.norm(v, axis=1), 0.1)
    assert len(f) == 20 * 4**2
    # Euler's formula for a closed genus-0 surface: V − E + F = 2.
    edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    assert len(v) - len(edges) + len(f) == 2
    tri = grid_triangles(6, 6)
    above = _sheet(6, 0.5, 0.1 + 1e-3)
    cutting = _sheet(6, 0.5, 0.05)
    ball = Part(f, v)
    assert intersecting_frames([ball, Part(tri, np.stack([above, cutting, above]))]) == [1]


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="triangles index past"):
        Part([[0, 1, 5]], np.zeros((3, 3)))
    with pytest.raises(ValueError, match="frame counts"):
        intersecting_frames([Part([[0, 1, 2]], np.zeros((2, 3, 3))), Part([[0, 1, 2]], np.zeros((3, 3, 3)))])
