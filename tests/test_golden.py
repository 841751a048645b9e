"""Every built-in scene reproduces its golden trajectory (tests/golden.py) bit for bit on the CPU.

Except where a step does host linear algebra: L-BFGS (``options.minimizer.method = "lbfgs"``, or "auto" on
the CPU) takes dot
products and triangular solves in NumPy/SciPy, whose OpenBLAS picks its kernels by CPU (AVX2 or AVX-512),
so the last bit of a dot product, and then an iteration count, can differ between machines. Those scenes
agree to :data:`HOST_LINALG_ATOL` (measured: `cantilever` 2.5e-5 m off on an AMD EPYC against the
fixture's machine; with ``OPENBLAS_CORETYPE=SkylakeX`` the same box reproduces it bit for bit).

The fixture was written before the scene-layer refactor (issue 10) and the differentiable-step work
(issue 12): a forward run with gradients off must not change by a single bit. A change that is meant to
alter the motion regenerates the fixture (`python -m tests.golden NAME`) and says why in its commit.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.golden import GOLDEN_DIR, scene_names, simulate

NAMES = sorted(p.stem for p in GOLDEN_DIR.glob("*.npz"))
#: [m] over the fixture's frames, for scenes whose steps use host BLAS (L-BFGS); they move 1e-3 m or more.
HOST_LINALG_ATOL = 1e-4


def _host_linalg(name: str) -> bool:
    import pliant as pl

    # "auto" is L-BFGS on the CPU, where the goldens run
    return pl.scene.load_scene(name).solver.options.get("minimizer", {}).get("method") in ("lbfgs", "auto")


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
    if _host_linalg(name):
        assert np.abs(expected[-1] - expected[0]).max() > 10 * HOST_LINALG_ATOL  # the check is not vacuous
        np.testing.assert_allclose(x, expected, rtol=0, atol=HOST_LINALG_ATOL)
    else:
        np.testing.assert_array_equal(x, expected)
