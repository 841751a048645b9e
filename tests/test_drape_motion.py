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


# ----------------------------------------------------------------------- CG stopped by its tolerance
def _implicit_drape(tol: float, every: int | None = None, cap: int = 400):
    from pliant.bench._mass_spring import FRAME_DT, cloth_drape_model
    from pliant.solvers import FastMassSpring

    model = cloth_drape_model(12, device="cpu", dtype="float64")
    solver = FastMassSpring(
        model, method="implicit", cg_iterations=cap, cg_tol=tol, cg_check_every=every, damping_rate=0.0
    )
    s0, s1 = model.state(), model.state()
    control = model.control()
    used = []
    for _ in range(5):
        solver.step(s0, s1, control, FRAME_DT / 4)
        s0, s1 = s1, s0
        used.append(solver.last_cg_iterations)
    return s0.particle_q.numpy(), used, solver


def test_cg_stops_at_its_tolerance_and_the_early_stop_changes_nothing():
    """CG stops well before its cap once the residual reaches cg_tol; stopping the launches early gives the
    same positions, bit for bit, as launching every iteration with the update frozen on the device."""
    x_checked, used, solver = _implicit_drape(1e-6, every=4)
    x_all, used_all, _ = _implicit_drape(1e-6, every=0)
    assert all(0 < u < 400 for u in used), used
    assert used == used_all
    np.testing.assert_array_equal(x_checked, x_all)
    assert solver.cg_steps == 5 and solver.cg_iterations_total == sum(used)


def test_tighter_cg_tolerance_takes_more_iterations_and_lands_closer():
    exact, _, _ = _implicit_drape(1e-12)
    errors, iterations = [], []
    for tol in (1e-2, 1e-4, 1e-6, 1e-8):
        x, used, _ = _implicit_drape(tol)
        errors.append(float(np.abs(x - exact).max()))
        iterations.append(sum(used))
    assert iterations == sorted(iterations) and iterations[0] < iterations[-1]
    assert all(a > b for a, b in zip(errors, errors[1:], strict=False)), errors
    assert errors[-1] < 1e-9


def test_cg_options_are_checked():
    from pliant.bench._mass_spring import cloth_drape_model
    from pliant.solvers import FastMassSpring

    model = cloth_drape_model(4, device="cpu")
    with pytest.raises(ValueError, match="cg_tol"):
        FastMassSpring(model, method="implicit", cg_tol=0.0)
    with pytest.raises(ValueError, match="cg_check_every"):
        FastMassSpring(model, method="implicit", cg_check_every=-1)
