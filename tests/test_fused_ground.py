"""FastMassSpring's fused CPU frame with ground contact and kinematic targets: the response after each substep
(projection with smoothed or exact Coulomb friction and restitution, or compliant contact) and the targets,
inside the one launch, give the step-by-step frames bit for bit; the physics checked against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

import pliant as pl

G = 9.81


def _cloth(
    dtype: str, *, gravity=(0.0, -G, 0.0), y0: float = 0.0, pin: str = "none", height: float = 0.0, **ground
) -> pl.Model:
    """A 7×5 cloth lying flat at height ``y0``, over the ground y = ``height`` given by ``ground``."""
    b = pl.ModelBuilder(gravity=gravity)
    b.add_cloth_grid(nx=7, ny=5, size=0.5, mass=0.2, youngs_modulus_thickness=400.0, damping=0.02,
                     origin=(-0.25, y0, -0.25), plane="xz", pin=pin)  # fmt: skip
    b.add_ground(height, **ground)
    return b.finalize(device="cpu", dtype=dtype)


def _run(model, control, substeps: int, frames: int, dt: float = 1e-3, **options):
    """(x, v) per frame of the fused solver and of the step-by-step one, asserted bit for bit, and the
    fused solver."""
    out = []
    for fused in (None, False):
        solver = pl.solvers.FastMassSpring(model, fused_frame=fused, **options)
        frame = pl.solvers.FrameStep(solver, dt, substeps)
        s0, s1 = model.state(), model.state()
        xs, vs = [], []
        for _ in range(frames):
            s0, s1 = frame(s0, control, s1)
            xs.append(s0.particle_q.numpy().copy())  # CPU numpy() is a view
            vs.append(s0.particle_qd.numpy().copy())
        out.append((np.array(xs), np.array(vs), solver))
    (xf, vf, fused_solver), (xp, vp, _) = out
    assert fused_solver.fused_frame_blocker is None
    assert np.array_equal(xf, xp) and np.array_equal(vf, vp)
    return xf, vf, fused_solver


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("substeps", [6, 7])
def test_resting_on_the_ground(dtype, substeps):
    """Dropped from 2 cm with random velocities: it lands, and every particle ends on or above y = r."""
    model = _cloth(dtype, y0=0.02)
    model.particle_qd.assign(np.random.default_rng(5).normal(scale=0.3, size=(model.particle_count, 3)))
    x, v, _ = _run(model, None, substeps, frames=30)
    r = float(model.particle_radius.numpy()[0])
    tol = 1e-6 if dtype == "float32" else 1e-12
    assert x[-1][:, 1].min() >= r - tol
    assert np.sum(np.abs(x[-1][:, 1] - r) <= tol) > model.particle_count // 2  # in contact


@pytest.mark.parametrize("law", ["coulomb", "coulomb_exact"])
@pytest.mark.parametrize("mu", [0.2, 0.8])
def test_incline_stick_and_slip(law, mu):
    """Gravity tilted by 30° (tan = 0.577): μ = 0.8 sticks, μ = 0.2 slides at g (sin θ − μ cos θ)."""
    th = math.radians(30.0)
    model = _cloth("float64", gravity=(G * math.sin(th), -G * math.cos(th), 0.0), y0=0.005,
                   friction=mu, friction_law=law)  # fmt: skip
    substeps, frames, dt = 8, 25, 1e-3
    x, v, _ = _run(model, None, substeps, frames, dt)
    t = substeps * frames * dt
    vx = v[-1][:, 0].mean()
    if mu > math.tan(th):
        assert abs(vx) < (1e-4 if law == "coulomb" else 1e-12)  # a creep below ε_v = 1e-4 m/s; exact stick
    else:
        # Each substep gravity adds g sin θ Δt along the slope and friction takes μ g cos θ Δt back.
        a = G * (math.sin(th) - mu * math.cos(th))
        assert vx == pytest.approx(a * t, rel=1e-3)


def test_bounce_with_restitution():
    """Falling flat from 5 cm with e = 0.5: it leaves the ground at half its impact speed (springs stay at
    rest length: every particle moves alike)."""
    model = _cloth("float64", y0=0.05, restitution=0.5, friction=0.0)
    x, v, _ = _run(model, None, substeps=10, frames=15, dt=1e-3)
    vy = v[:, :, 1].mean(axis=1)
    k = int(np.argmax(vy > 0))  # the first frame after the bounce
    assert k > 0 and vy[k - 1] < 0
    impact = math.sqrt(2 * G * (0.05 - float(model.particle_radius.numpy()[0])))
    # Up at e·impact, then slowed by gravity for at most one frame (10 substeps of 1 ms).
    assert 0.5 * impact - G * 10e-3 - 0.02 < vy[k] <= 0.5 * impact + 0.02


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("zeta", [0.0, 1.0])
def test_compliant_ground(dtype, zeta):
    """κ = 1e4 /s², ζ = 0 and 1: bit for bit; with the damper it settles g/κ deep (1 %)."""
    kappa = 1.0e4
    model = _cloth(dtype, y0=0.005, stiffness=kappa, damping_ratio=zeta)
    x, v, _ = _run(model, None, substeps=8, frames=40)
    if zeta > 0:
        r = float(model.particle_radius.numpy()[0])
        depth = r - x[-1][:, 1].mean()
        assert depth == pytest.approx(G / kappa, rel=1e-2)


@pytest.mark.parametrize("substeps", [5, 6])
def test_kinematic_targets_on_the_ground(substeps):
    """Two kinematic corners moved each frame (as a scene's handle's control_fn does) over a cloth on the
    ground: the targets are reached with the velocity that got them there, bit for bit."""
    b = pl.ModelBuilder(gravity=(0.0, -G, 0.0))
    b.add_cloth_grid(nx=7, ny=5, size=0.5, mass=0.2, youngs_modulus_thickness=400.0, damping=0.0,
                     origin=(-0.25, 0.02, -0.25), plane="xz")  # fmt: skip
    b.add_kinematic([0, 7])
    b.add_ground(0.0, friction=0.4)
    model = b.finalize(device="cpu", dtype="float64")
    control = model.control()
    x0 = control.kinematic_targets.numpy().copy()
    out = []
    for fused in (None, False):
        solver = pl.solvers.FastMassSpring(model, fused_frame=fused)
        frame = pl.solvers.FrameStep(solver, 1e-3, substeps)
        s0, s1 = model.state(), model.state()
        for f in range(12):
            target = x0 + np.array([0.0, 0.01 * (f + 1), 0.0])
            control.set_kinematic_targets(target)
            s0, s1 = frame(s0, control, s1)
            xk = s0.particle_q.numpy()[[0, 7]]
            assert np.array_equal(xk, target)
        out.append((s0.particle_q.numpy().copy(), s0.particle_qd.numpy().copy(), solver))
    assert out[0][2].fused_frame_blocker is None
    assert np.array_equal(out[0][0], out[1][0]) and np.array_equal(out[0][1], out[1][1])
    # The target moves once per frame, in its first substep: later substeps start on it and stay (v = 0).
    assert np.array_equal(out[0][1][[0, 7]], np.zeros((2, 3)))


@pytest.mark.parametrize("graph", [True, False])
def test_simulator_frames_on_the_ground_fused_and_replayed(graph):
    """The Simulator's frames (captured as a CPU graph and replayed, or launched) with the ground fused:
    the step-by-step frames bit for bit."""
    xs = []
    for fused in (None, False):
        model = _cloth("float32", y0=0.01, pin="top-corners", restitution=0.3)
        sim = pl.Simulator(
            model, pl.solvers.FastMassSpring(model, fused_frame=fused), substeps=8, graph=graph
        )
        sim.run(6, progress=False)
        xs.append(sim.state_0.particle_q.numpy().copy())
    assert np.array_equal(xs[0], xs[1])
    assert np.abs(xs[0] - model.particle_q.numpy()).max() > 1e-3


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("stiffness", [None, 1.0e4])
def test_a_raised_ground_is_the_plane_kinds_arithmetic(dtype, stiffness):
    """On a ground at y = -0.0137 m (where y - h and h + r round differently from y and r) the fused frame
    lists exactly the particles the plane kind's test puts in contact and calls the same function: bit for
    bit with step by step, hard and compliant; every particle ends on or above the contact surface."""
    h = -0.0137
    ground = {} if stiffness is None else {"stiffness": stiffness, "damping_ratio": 1.0}
    model = _cloth(dtype, y0=h + 0.01, height=h, **ground)
    model.particle_qd.assign(np.random.default_rng(9).normal(scale=0.3, size=(model.particle_count, 3)))
    x, _, _ = _run(model, None, substeps=7, frames=30)
    r = float(model.particle_radius.numpy()[0])
    sink = 0.0 if stiffness is None else 3.0 * G / stiffness
    assert x[-1][:, 1].min() >= h + r - sink - (1e-6 if dtype == "float32" else 1e-12)
