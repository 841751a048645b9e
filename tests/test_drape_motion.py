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


# ----------------------------------------------------------------------- θ: backward Euler ↔ midpoint
def _vertical_oscillator(theta: float, steps: int, t_end: float = 1.0):
    """A particle hanging from a pinned one by a spring along y (a linear oscillator about its equilibrium):
    returns (y(t_end) − exact, the total energy's relative change)."""
    import pliant as pl

    k, m, rest, g = 40.0, 0.1, 0.5, 9.81
    b = pl.ModelBuilder(gravity=(0.0, -g, 0.0))
    b.add_particles([[0.0, 1.0, 0.0], [0.0, 1.0 - rest - 0.05, 0.0]], [m, m])
    b.pin([0])
    b.add_springs([[0, 1]], stiffness=k, rest_length=rest)
    model = b.finalize(device="cpu", dtype="float64")
    solver = pl.solvers.FastMassSpring(model, method="implicit", theta=theta, cg_tol=1e-14, cg_iterations=10)
    s0, s1 = model.state(), model.state()
    h = t_end / steps

    def energy(s):
        y, v = s.particle_q.numpy()[1, 1], s.particle_qd.numpy()[1, 1]
        return 0.5 * m * v * v + m * g * y + 0.5 * k * (1.0 - y - rest) ** 2

    e0 = energy(s0)
    for _ in range(steps):
        solver.step(s0, s1, model.control(), h)
        s0, s1 = s1, s0
    omega = (k / m) ** 0.5
    y_eq = 1.0 - rest - m * g / k
    exact = y_eq + (1.0 - rest - 0.05 - y_eq) * np.cos(omega * t_end)
    return s0.particle_q.numpy()[1, 1] - exact, (energy(s0) - e0) / abs(e0)


def test_theta_half_is_second_order_and_keeps_the_energy():
    """θ = ½ (linearised implicit midpoint) is exact for a linear oscillator's energy and converges at second
    order; θ = 1 (backward Euler) loses energy and converges at first order."""
    err_h, drift_half = _vertical_oscillator(0.5, 50)
    err_h2, _ = _vertical_oscillator(0.5, 100)
    assert abs(drift_half) < 1e-10
    assert 3.6 < abs(err_h / err_h2) < 4.4  # second order
    _, drift_be = _vertical_oscillator(1.0, 50)
    assert drift_be < -0.01  # backward Euler dissipates
    be_h, _ = _vertical_oscillator(1.0, 1600)  # first order (asymptotic once ω²h·t ≪ 1: 1600 steps)
    be_h2, _ = _vertical_oscillator(1.0, 3200)
    assert 1.8 < abs(be_h / be_h2) < 2.2


def test_theta_is_checked():
    from pliant.bench._mass_spring import cloth_drape_model
    from pliant.solvers import FastMassSpring

    with pytest.raises(ValueError, match="theta"):
        FastMassSpring(cloth_drape_model(4, device="cpu"), method="implicit", theta=0.3)
    grad_model = cloth_drape_model(4, device="cpu", dtype="float64")
    grad_model.requires_grad = True
    with pytest.raises(ValueError, match="no adjoint"):
        FastMassSpring(grad_model, method="implicit", theta=0.5)
