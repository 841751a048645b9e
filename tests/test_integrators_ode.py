"""Integrators on the ODE path (NumPy, float64): orders, energy behaviour, identities, adaptivity."""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl
from tests.helpers import ALL_INTEGRATORS, check_ode_order, fresh, integrator_id

I = pl.integrators


@pytest.mark.parametrize("integ", ALL_INTEGRATORS, ids=integrator_id)
def test_order_ode(integ):
    """The global error at T = 8 on the oscillator shrinks like dt**order (±0.15, last 4 refinements)."""
    check_ode_order(fresh(integ))


def _energy_ratios(integ, m=2.0, k=3.0, dt=0.1, steps=50):
    p = I.lecture_oscillator(m=m, k=k)
    sol = integ.solve(p, np.array([0.3, 1.0]), steps * dt, dt)
    e = np.array([p.energy(y) for y in sol.y])
    return e[1:] / e[:-1], 1.0 + k / m * dt * dt


def test_forward_euler_multiplies_energy():
    """Forward Euler multiplies the undamped oscillator's energy by exactly 1 + ω²h² each step (1e-12)."""
    ratio, factor = _energy_ratios(I.ForwardEuler())
    np.testing.assert_allclose(ratio, factor, rtol=1e-12, atol=0)


def test_backward_euler_divides_energy():
    """Backward Euler divides the undamped oscillator's energy by exactly 1 + ω²h² each step (1e-12)."""
    ratio, factor = _energy_ratios(I.BackwardEuler())
    np.testing.assert_allclose(ratio, 1.0 / factor, rtol=1e-12, atol=0)


def test_implicit_midpoint_conserves_linear_energy():
    """Implicit midpoint (half backward Euler + extrapolation) keeps the oscillator energy to 1e-12, any h."""
    for dt in (0.1, 1.0, 10.0):
        ratio, _ = _energy_ratios(I.ImplicitMidpoint(), dt=dt, steps=200)
        np.testing.assert_allclose(np.cumprod(ratio), 1.0, rtol=1e-12, atol=0)


@pytest.mark.parametrize("integ", [I.SymplecticEuler(), I.VelocityVerlet()], ids=lambda i: i.name)
def test_symplectic_energy_bounded_without_drift(integ):
    """Over 1e5 steps the energy stays within h·E0 of its start and its mean does not drift."""
    h, steps = 0.01, 100_000
    osc = I.harmonic_oscillator()
    sol = integ.solve(osc, (1.0, 0.0), steps * h, h)
    e = 0.5 * sol.v[:, 0] ** 2 + 0.5 * sol.x[:, 0] ** 2
    e0 = e[0]
    dev = np.max(np.abs(e - e0))
    assert dev <= h * e0, f"{integ.name}: max energy deviation {dev:.3g} > h·E0 = {h * e0:.3g}"
    # Means over the first and last 10%, trimmed to whole periods of the energy oscillation (the numerical
    # rotation angle per step is θ = arccos(1 − h²ω²/2) for both methods; E oscillates with angle 2θ).
    period = np.pi / np.arccos(1.0 - 0.5 * h * h)
    window = int(round(np.floor(0.1 * steps / period) * period))
    first, last = e[:window].mean(), e[-window:].mean()
    assert abs(last - first) <= 1e-3 * dev, f"{integ.name}: mean energy drifted {first:.12g} -> {last:.12g}"


def test_rk2_heun_identical_ode():
    """RK2(alpha=0.5, beta=0.5, a=0, b=1) reproduces Heun bit for bit on the ODE path."""
    p = I.harmonic_oscillator(gamma=0.3)
    a = I.RK2(alpha=0.5, beta=0.5, a=0.0, b=1.0).solve(p, (1.0, 0.2), 5.0, 0.05)
    b = I.Heun().solve(p, (1.0, 0.2), 5.0, 0.05)
    assert np.array_equal(a.y, b.y)


def test_bdf2_first_step_is_backward_euler_and_reset():
    """BDF2 starts with a backward-Euler step, and reset() forgets the history."""
    p = I.harmonic_oscillator()
    y0 = np.array([0.0, 1.0])
    bdf, be = I.BDF2(), I.BackwardEuler()
    y1 = bdf.step_ode(p, 0.0, 0.1, y0)
    assert np.array_equal(y1, be.step_ode(p, 0.0, 0.1, y0))
    y2 = bdf.step_ode(p, 0.1, 0.1, y1)
    assert not np.allclose(y2, be.step_ode(p, 0.1, 0.1, y1), rtol=1e-6, atol=0)
    bdf.reset()
    assert np.array_equal(bdf.step_ode(p, 0.1, 0.1, y1), be.step_ode(p, 0.1, 0.1, y1))


def test_bdf2_variable_step_keeps_order():
    """With the step alternating between h and h/2, BDF2's global error still shrinks like h²."""
    osc = I.harmonic_oscillator()
    errs, hs = [], []
    for k in range(4, 9):
        h = 2.0**-k
        bdf = I.BDF2()
        y, t = np.array([0.0, 1.0]), 0.0
        steps = [h, 0.5 * h] * int(round(2.0 / (1.5 * h)))
        for dt in steps:
            y = bdf.step_ode(osc, t, dt, y)
            t += dt
        errs.append(abs(y[1] - np.cos(t)))
        hs.append(h)
    slope = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert abs(slope - 2.0) <= 0.15, f"variable-step BDF2 order {slope:.3f}"


def test_dopri_adaptive_meets_tolerance():
    """DOPRI5(4) with rtol 1e-8 ends within 1e-6 of cos(10), and a looser rtol takes fewer steps."""
    osc = I.harmonic_oscillator()
    dp = I.DormandPrince()
    tight = dp.solve_adaptive(osc, (1.0, 0.0), 10.0, rtol=1e-8, atol=1e-10)
    loose = dp.solve_adaptive(osc, (1.0, 0.0), 10.0, rtol=1e-4, atol=1e-6)
    assert tight.t[-1] == 10.0
    assert abs(tight.x[-1, 0] - np.cos(10.0)) < 1e-6
    assert loose.t.size < tight.t.size
    assert tight.stats["accepted"] == tight.t.size - 1


def test_dopri_adaptive_follows_fast_transients():
    """On a stiff-ish decay plus oscillation, adaptive steps are small early and large late."""
    p = I.ODEProblem(f=lambda t, y: np.array([-50.0 * (y[0] - np.cos(t))]))
    sol = I.DormandPrince().solve_adaptive(p, np.array([0.0]), 3.0, rtol=1e-6, atol=1e-9)
    dts = np.diff(sol.t)
    assert dts[:3].max() < dts[-3:].min()
    exact_late = (2500 * np.cos(3.0) + 50 * np.sin(3.0)) / 2501  # transient has decayed
    assert abs(sol.y[-1, 0] - exact_late) < 1e-5


def test_dopri_has_no_physical_path():
    """DormandPrince.step_system raises NotImplementedError that points to RK4."""
    with pytest.raises(NotImplementedError, match="RK4"):
        I.DormandPrince().step_system(None, 0.0, 0.1, None, None, None, None)


def test_integrator_flags():
    """Every integrator declares order, explicit and symplectic consistently with its kind."""
    flags = {i.name: (i.order, i.explicit, i.symplectic) for i in ALL_INTEGRATORS}
    assert flags["BackwardEuler"] == (1, False, False)
    assert flags["ImplicitMidpoint"] == (2, False, True)
    assert flags["BDF2"] == (2, False, False)
    assert flags["VelocityVerlet"] == (2, True, True)
    assert flags["DormandPrince"] == (5, True, False)
    assert I.Leapfrog is I.VelocityVerlet


@pytest.mark.parametrize(
    ("cls", "expected", "tol"),
    [
        (I.ForwardEuler, 0.0, 0.0),
        (I.Heun, 0.0, 0.0),
        (I.SymplecticEuler, 2.0, 0.01),
        (I.VelocityVerlet, 2.0, 0.01),
        (I.RK4, 2.0 * np.sqrt(2.0), 0.005),
        (I.DormandPrince, 0.997, 0.01),
        (I.BackwardEuler, np.inf, 0.0),
        (I.ImplicitMidpoint, np.inf, 0.0),
    ],
    ids=lambda v: v.__name__ if isinstance(v, type) else str(v),
)
def test_stability_limits(cls, expected, tol):
    """The bisection on energy growth finds each method's |R(iωΔt)| = 1 crossing on the oscillator."""
    from pliant.studies import oscillator_stability_limit

    lim = oscillator_stability_limit(cls(), steps=1000, iterations=25)
    if np.isinf(expected) or expected == 0.0:
        assert lim == expected, f"{cls.__name__}: {lim}"
    else:
        assert abs(lim - expected) <= tol, (
            f"{cls.__name__}: largest stable ωΔt {lim:.4f}, expected {expected:.4f}"
        )
