"""Carved voxels as a tetrahedral mesh (issue 37's model step): the two meshes of a voxel set, their
coarsening for the fit's coarse stage, and the largest piece."""

from __future__ import annotations

import numpy as np
import pytest

import pliant.geometry as g


def _grid(n: tuple[int, int, int], h: float, origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    i, j, k = np.meshgrid(*(np.arange(m) for m in n), indexing="ij")
    return (np.stack([i.ravel(), j.ravel(), k.ravel()], axis=1) + 0.5) * h + np.asarray(origin)


def _volume(m) -> float:
    p = np.asarray(m.points)[np.asarray(m.tets)]
    return float(
        np.sum(np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0])) / 6
    )


@pytest.mark.parametrize("dual", [False, True])
def test_a_full_block_of_voxels_is_box_tets(dual):
    h = 0.1
    c = _grid((4, 3, 2), h)
    m = g.voxel_tets(c, h, dual=dual)
    n, lo = ((3, 2, 1), c.min(axis=0)) if dual else ((4, 3, 2), c.min(axis=0) - h / 2)
    b = g.box_tets(*n, size=tuple(h * np.asarray(n)), origin=lo)
    assert np.abs(m.points - b.points).max() < 1e-12  # the same vertices in the same order ...
    assert sorted(map(tuple, m.tets.tolist())) == sorted(map(tuple, b.tets.tolist()))  # ... and tets
    assert _volume(m) == pytest.approx(np.prod(n) * h**3, rel=1e-12)  # every tet positive, no overlap


def test_dual_nodes_are_the_voxel_centres():
    h = 0.05
    c = _grid((5, 4, 3), h, origin=(0.3, -0.2, 1.0))
    m = g.voxel_tets(c, h, dual=True)
    assert len(m.points) == len(c)
    assert _farthest(m.points, c) < 1e-12


def _farthest(a: np.ndarray, b: np.ndarray) -> float:
    """The largest distance from a point of ``a`` to the nearest of ``b``."""
    from scipy.spatial import cKDTree

    return float(cKDTree(b).query(a)[0].max())


def test_coarsening_keeps_cells_that_are_mostly_full():
    h = 0.01
    c = _grid((4, 4, 2), h)
    full = g.coarsen_voxels(c, h)
    assert len(full) == 4 and np.allclose(np.sort(full[:, 0]), [0.01, 0.01, 0.03, 0.03])
    half = g.coarsen_voxels(c[c[:, 2] < h], h)  # one layer: each coarse cell half full
    assert len(half) == 4 and len(g.coarsen_voxels(c[c[:, 2] < h], h, min_fill=0.75)) == 0


def test_the_largest_piece_drops_a_stray_fragment():
    h = 0.1
    body = _grid((5, 2, 2), h)
    stray = _grid((2, 2, 2), h, origin=(2.0, 0.0, 0.0))
    m = g.largest_piece(g.voxel_tets(np.vstack([body, stray]), h, dual=True))
    assert m.points[:, 0].max() < 1.0 and len(m.tets) == 6 * 4
    assert m.tets.max() == len(m.points) - 1  # renumbered, no unused vertex
