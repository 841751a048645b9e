"""The XPBD colouring rows of the drape benchmark run over-relaxed at half the substeps (issue 42 item 3):
the faster setting follows the former one (100 substeps, ω = 1) and the converged reference, and it is not
at the edge of its stability (ω ± 0.1 stay within the 2 % budget)."""

from __future__ import annotations

import numpy as np
import pytest

from pliant.bench._drape_motion import reference_curve, solver_curve, trajectory_error
from pliant.bench._xpbd import SETTINGS, _drape_solver

#: The former 64² colouring setting (substeps, ω), the side of the side-by-side comparison.
FORMER = (100, 1.0)
BUDGET = 0.02


def _curve(n: int, substeps: int, omega: float, dtype: str) -> np.ndarray:
    model, solver = _drape_solver(n, "coloring", 1, "cpu", dtype, 0.0, omega)
    return solver_curve(model, solver, substeps=substeps, frames=30)


def test_relaxed_colouring_follows_the_former_setting_in_float64():
    """float64, 64²: the over-relaxed half-substep curve stays within 2 % of the final sag of the former
    setting's curve at every frame, and is at least as close to the converged reference."""
    substeps, iterations, omega = SETTINGS[(64, "coloring")]
    assert iterations == 1 and substeps < FORMER[0]
    ref = reference_curve(64)
    fast = _curve(64, substeps, omega, "float64")
    former = _curve(64, *FORMER, "float64")
    assert np.all(np.isfinite(fast))
    assert np.max(np.abs(fast - former)) / abs(ref[-1]) < BUDGET
    assert trajectory_error(fast, ref) <= min(trajectory_error(former, ref), BUDGET)


@pytest.mark.parametrize("shift", [-0.1, 0.1])
def test_relaxation_has_a_margin(shift):
    """float32 (the rows' dtype): ω moved by 0.1 either way still meets the budget at the rows' substeps
    (at 40 substeps ω = 1.8 is 7.9 % off, at 30 substeps 1.7 diverges: the setting keeps away from that)."""
    substeps, _, omega = SETTINGS[(64, "coloring")]
    curve = _curve(64, substeps, omega + shift, "float32")
    assert trajectory_error(curve, reference_curve(64)) <= BUDGET
