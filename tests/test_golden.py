"""Every built-in scene reproduces its golden trajectory (tests/golden.py) bit for bit on the CPU.

The fixture was written before the scene-layer refactor (issue 10) and the differentiable-step work
(issue 12): a forward run with gradients off must not change by a single bit. A change that is meant to
alter the motion regenerates the fixture (`python -m tests.golden NAME`) and says why in its commit.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.golden import GOLDEN_DIR, scene_names, simulate

NAMES = sorted(p.stem for p in GOLDEN_DIR.glob("*.npz"))


def test_every_builtin_scene_has_a_golden_trajectory():
    assert NAMES, "no golden trajectories found"
    assert set(scene_names()) <= set(NAMES)


@pytest.mark.parametrize("name", NAMES)
def test_golden_trajectory(name: str):
    with np.load(GOLDEN_DIR / f"{name}.npz", allow_pickle=False) as f:
        expected = f["x"]
    x = simulate(name, frames=expected.shape[0] - 1)
    assert x.shape == expected.shape
    assert x.dtype == expected.dtype
    np.testing.assert_array_equal(x, expected)
