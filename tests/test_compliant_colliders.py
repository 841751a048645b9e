"""Compliant colliders (issue 38 item 3): a collider's ``stiffness`` κ [1/s²] and ``damping_ratio`` ζ make
its contact the ground's spring–damper max(κ d − b v_n, 0) per unit mass (b = 2ζ√κ), solved by backward
Euler after the step in every solver family. Closed forms as tests/test_compliant_contact.py's for the
ground: a resting particle sits g/κ deep, and released at the surface it rebounds as the damped oscillator
of ω = √κ and ratio ζ; a moving compliant plate still carries a particle resting on it."""

from __future__ import annotations

import math

import numpy as np
import pytest

import pliant as pl

G = 9.81
KAPPA = 2500.0
FAMILIES = ("force_explicit", "force_implicit", "fast_mass_spring", "fast_mass_spring_implicit", "xpbd")


def _solver(family: str, model: pl.Model, collisions: list):
    gravity = [pl.energies.Gravity()]
    if family == "force_explicit":
        integ = pl.integrators.SymplecticEuler()
        return pl.solvers.ForceSolver(model, gravity, integ, collisions=collisions)
    if family == "force_implicit":
        integ = pl.integrators.BackwardEuler(newton_tol=1e-12)
        return pl.solvers.ForceSolver(model, gravity, integ, collisions=collisions)
    if family == "fast_mass_spring":
        return pl.solvers.FastMassSpring(model, collisions=collisions)
    if family == "fast_mass_spring_implicit":
        return pl.solvers.FastMassSpring(model, method="implicit", collisions=collisions)
    return pl.solvers.XPBD(model, iterations=4, collisions=collisions)


def _depths(family: str, kind: str, zeta: float, dt: float, steps: int) -> np.ndarray:
    """Depth −φ(x) [m] of a particle (radius 0) released at rest on top of a compliant sphere or box."""
    colliders = pl.collision.Colliders()
    if kind == "sphere":
        colliders.add_sphere((0.0, -0.5, 0.0), 0.5, stiffness=KAPPA, damping_ratio=zeta)
    else:
        colliders.add_box((0.0, -0.1, 0.0), (1.0, 0.1, 1.0), stiffness=KAPPA, damping_ratio=zeta)
    b = pl.ModelBuilder(gravity=(0.0, -G, 0.0))
    b.add_particles([[0.0, 0.0, 0.0]], 0.3, radius=0.0)
    model = b.finalize(device="cpu", dtype="float64")
    solver = _solver(family, model, [colliders])
    s0, s1 = model.state(), model.state()
    out = np.empty(steps)
    for k in range(steps):
        solver.step(s0, s1, None, dt)
        s0, s1 = s1, s0
        out[k] = -colliders.query(model, s0.particle_q)[0][0]
    return out


@pytest.mark.parametrize("kind", ["sphere", "box"])
@pytest.mark.parametrize("family", FAMILIES)
def test_a_resting_particle_sinks_g_over_kappa_into_a_collider(family: str, kind: str):
    """Critically damped (ζ = 1, κ = 2500 1/s²), a particle comes to rest g/κ = 3.92 mm deep (1e-6)."""
    d = _depths(family, kind, 1.0, 1e-3, 600)
    assert d[-1] == pytest.approx(G / KAPPA, rel=1e-6)


@pytest.mark.parametrize("family", ["force_explicit", "xpbd"])
def test_a_release_on_a_compliant_collider_rebounds_as_the_damped_oscillator(family: str):
    """ζ = 0.2, Δt = 0.1 ms, on a box: the first overshoot past g/κ is e^(−ζπ/√(1−ζ²)) of it (3 %), at
    π/ω_d (1 %), as on the compliant ground."""
    zeta, dt = 0.2, 1e-4
    wd = math.sqrt(KAPPA) * math.sqrt(1 - zeta**2)
    d = _depths(family, "box", zeta, dt, int(1.5 * math.pi / wd / dt))
    first = int(np.argmax(d))
    overshoot = d[first] / (G / KAPPA) - 1.0
    assert overshoot == pytest.approx(math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2)), rel=0.03)
    assert (first + 1) * dt == pytest.approx(math.pi / wd, rel=0.01)
    assert d.min() > 0.0  # in contact throughout: the force never pulls nor lets go below the surface


def test_hard_and_compliant_colliders_validate_their_parameters():
    """κ must be > 0 (None: hard), ζ >= 0: one-line errors naming the field, before any work."""
    c = pl.collision.Colliders()
    with pytest.raises(ValueError, match="stiffness κ must be > 0"):
        c.add_sphere((0, 0, 0), 1.0, stiffness=0.0)
    with pytest.raises(ValueError, match="damping_ratio ζ must be >= 0"):
        c.add_box((0, 0, 0), (1, 1, 1), stiffness=100.0, damping_ratio=-1.0)
    with pytest.raises(ValueError, match="velocity must be 3 finite numbers"):
        c.add_capsule((0, 0, 0), (1, 0, 0), 0.1, velocity=(1.0, 2.0))
    assert len(c) == 0
