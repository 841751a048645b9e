"""The benchmarks' motion measure (``trajectory_error``: the drape's sag over its fall against a converged
float64 reference) separates converged runs from runs that damp the motion away, and the stored reference
reproduces."""

from __future__ import annotations

import numpy as np
import pytest

from pliant.bench._drape_motion import compute_reference, reference_curve, sag_curve, trajectory_error


def test_converged_symplectic_run_follows_the_reference():
    ref = reference_curve(16)
    curve = sag_curve(16, "symplectic", substeps=20)  # float32, the stable setting, undamped
    assert trajectory_error(curve, ref) < 0.005
    assert ref[0] == 0.0 and 0.9 < ref[-1] < 1.0  # starts flat, has fallen to about its length at 0.5 s


def test_damping_and_truncated_iterations_are_caught():
    """The measure can fail: the benchmarks' former extra damping (1/s) and a Baraff–Witkin step with 5 CG
    iterations both slow the fall far beyond 2 %, though both would look fine at rest."""
    ref = reference_curve(16)
    damped = sag_curve(16, "symplectic", substeps=20, damping_rate=1.0)
    truncated = sag_curve(16, "implicit", substeps=1, cg_iterations=5)
    assert trajectory_error(damped, ref) > 0.05
    assert trajectory_error(truncated, ref) > 0.2
    assert trajectory_error(np.full_like(ref, np.nan), ref) == float("inf")


@pytest.mark.slow
def test_stored_reference_reproduces():
    np.testing.assert_allclose(compute_reference(16), reference_curve(16), rtol=1e-9, atol=1e-12)
