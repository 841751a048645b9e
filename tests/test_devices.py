"""The same scenes on every available device agree with the CPU (CUDA runs when a GPU is present)."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl
import pliant.constraints._base as constraint_base


def _cloth(device: str, dtype: str = "float64") -> pl.Model:
    b = pl.ModelBuilder()
    b.add_cloth_grid(
        nx=8,
        ny=8,
        size=0.5,
        mass=0.1,
        stiffness=200.0,
        damping=0.01,
        origin=(-0.25, 0.3, -0.25),
        pin="top-corners",
    )
    b.add_ground(friction=0.5)
    return b.finalize(device=device, dtype=dtype)


def _run(model: pl.Model, solver: pl.solvers.Solver, frames: int, substeps: int) -> np.ndarray:
    sim = pl.Simulator(model, solver, frame_dt=1 / 60, substeps=substeps)
    return sim.run(frames, progress=False).x


@pytest.mark.parametrize("integrator", ["SymplecticEuler", "RK4", "BackwardEuler"], ids=lambda n: n)
def test_mass_spring_matches_cpu(device: str, integrator: str) -> None:
    """A pinned cloth under each integrator gives the CPU's trajectory on this device (1e-8 m, float64)."""
    substeps = 4 if integrator == "BackwardEuler" else 20
    xs = {}
    for dev in {"cpu", device}:
        m = _cloth(dev)
        solver = pl.solvers.ForceSolver(m, pl.energies.mass_spring(), getattr(pl.integrators, integrator)())
        xs[dev] = _run(m, solver, frames=10, substeps=substeps)
    err = np.abs(xs[device] - xs["cpu"]).max()
    assert np.all(np.isfinite(xs[device]))
    assert err < 1e-8, f"{device} differs from cpu by {err:.3g} m"
    assert xs[device][-1, :, 1].min() < xs[device][0, :, 1].min() - 1e-3, "the cloth did not fall"


@pytest.mark.parametrize("schedule", ["coloring", "jacobi"])
def test_xpbd_matches_cpu(device: str, schedule: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """XPBD (either schedule) on this device reproduces the CPU trajectory (1e-8 m, float64): the CPU runs
    CUDA's schedule (its colouring, tests/test_xpbd_launches.py), the same order of projections."""
    monkeypatch.setattr(constraint_base, "CUDA_SCHEDULE_ON_CPU", True)
    xs = {}
    for dev in {"cpu", device}:
        m = _cloth(dev)
        xs[dev] = _run(m, pl.solvers.XPBD(m, iterations=10, schedule=schedule), frames=10, substeps=4)
    err = np.abs(xs[device] - xs["cpu"]).max()
    assert err < 1e-8, f"{device} differs from cpu by {err:.3g} m"
    assert xs[device][-1, :, 1].min() < xs[device][0, :, 1].min() - 1e-3, "the cloth did not fall"


def test_fem_implicit_matches_cpu(device: str) -> None:
    """A neo-Hookean box under backward Euler gives the CPU's motion on this device (1e-7 m, float64)."""
    xs = {}
    for dev in {"cpu", device}:
        b = pl.ModelBuilder()
        b.add_soft_box(
            cells=(2, 2, 2), size=(0.2, 0.2, 0.2), origin=(0.0, 0.3, 0.0), density=500.0, E=2e4, nu=0.3
        )
        b.add_ground()
        m = b.finalize(device=dev, dtype="float64")
        energies = [pl.energies.NeoHookean(), pl.energies.Gravity()]
        solver = pl.solvers.ForceSolver(m, energies, pl.integrators.BackwardEuler())
        xs[dev] = _run(m, solver, frames=10, substeps=2)
    err = np.abs(xs[device] - xs["cpu"]).max()
    assert err < 1e-7, f"{device} differs from cpu by {err:.3g} m"
    assert xs[device][-1, :, 1].mean() < xs[device][0, :, 1].mean(), "the box did not fall"


@pytest.mark.parametrize("method", ["symplectic", "implicit"])
def test_fast_mass_spring_matches_cpu(device: str, method: str) -> None:
    """FastMassSpring (gather kernels on CUDA, scatter on the CPU; CG stopping on the device in a graph)
    gives the CPU's trajectory on this device (1e-7 m, float64)."""
    substeps = 20 if method == "symplectic" else 4
    xs = {}
    for dev in {"cpu", device}:
        m = _cloth(dev)
        solver = pl.solvers.FastMassSpring(m, method=method, cg_tol=1e-10, cg_iterations=300)
        xs[dev] = _run(m, solver, frames=10, substeps=substeps)
    err = np.abs(xs[device] - xs["cpu"]).max()
    assert np.all(np.isfinite(xs[device]))
    assert err < 1e-7, f"{device} differs from cpu by {err:.3g} m"
    assert xs[device][-1, :, 1].min() < xs[device][0, :, 1].min() - 1e-3, "the cloth did not fall"


def _box(device: str, worlds: int = 1) -> pl.Model:
    b = pl.ModelBuilder()
    b.add_soft_box(
        cells=(2, 2, 2), size=(0.2, 0.2, 0.2), origin=(0.0, 0.15, 0.0), density=500.0, E=2e4, nu=0.3
    )
    b.add_ground(friction=0.5)
    if worlds > 1:
        b.replicate(worlds, spacing=(1.0, 0.0, 0.0))
    return b.finalize(device=device, dtype="float64")


def _explicit_box_solver(m: pl.Model) -> pl.solvers.ForceSolver:
    energies = [pl.energies.NeoHookean(), pl.energies.Gravity(), pl.energies.GroundPenalty()]
    return pl.solvers.ForceSolver(m, energies, pl.integrators.SymplecticEuler())


def test_explicit_fem_with_ground_penalty_matches_cpu(device: str) -> None:
    """An explicit neo-Hookean box landing on the penalty ground: this device's motion is the CPU's
    (1e-8 m, float64), and it lands (the contact acts)."""
    xs = {}
    for dev in {"cpu", device}:
        m = _box(dev)
        xs[dev] = _run(m, _explicit_box_solver(m), frames=12, substeps=40)
    err = np.abs(xs[device] - xs["cpu"]).max()
    assert err < 1e-8, f"{device} differs from cpu by {err:.3g} m"
    assert xs[device][-1, :, 1].min() > -0.01, "the box went through the ground"
    assert xs[device][-1, :, 1].mean() < xs[device][0, :, 1].mean() - 0.01, "the box did not fall"


def test_worlds_match_one_world_on_device(device: str) -> None:
    """Four worlds of the explicit box on this device: each world moves as the box alone on the CPU
    (1e-8 m; worlds are independent blocks of one model)."""
    m1 = _box("cpu")
    alone = _run(m1, _explicit_box_solver(m1), frames=8, substeps=40)
    m4 = _box(device, worlds=4)
    traj = pl.Simulator(m4, _explicit_box_solver(m4), frame_dt=1 / 60, substeps=40).run(8, progress=False)
    for w in range(4):
        xw = traj.world(w).x - np.array([w * 1.0, 0.0, 0.0])
        err = np.abs(xw - alone).max()
        assert err < 1e-8, f"world {w} on {device} differs from the box alone on cpu by {err:.3g} m"


@wp.kernel
def _weighted_sum(x: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d), out: wp.array(dtype=wp.float64)):
    i = wp.tid()
    wp.atomic_add(out, 0, wp.dot(x[i], w[i]))


def test_rollout_gradient_matches_cpu(device: str) -> None:
    """∂loss/∂(spring stiffness) of a pinned-cloth rollout (symplectic Euler, through pl.diff) on this
    device equals the CPU's (relative 1e-9, float64) and is not zero."""
    grads = {}
    for dev in {"cpu", device}:
        b = pl.ModelBuilder()
        b.add_cloth_grid(
            nx=4,
            ny=4,
            size=0.3,
            mass=0.05,
            stiffness=40.0,
            damping=0.02,
            origin=(0, 0.5, 0),
            pin="top-corners",
        )
        m = b.finalize(device=dev, dtype="float64", requires_grad=True)
        weights = np.random.default_rng(0).normal(size=(m.particle_count, 3))
        w = wp.array(weights, dtype=wp.vec3d, device=dev)

        def loss(state: pl.State, w=w, dev=dev) -> wp.array:
            out = wp.zeros(1, dtype=wp.float64, device=dev, requires_grad=True)
            wp.launch(_weighted_sum, state.particle_q.shape[0], [state.particle_q, w, out], device=dev)
            return out

        solver = pl.solvers.ForceSolver(m, pl.energies.mass_spring(), pl.integrators.SymplecticEuler())
        res = pl.diff.rollout(m, solver, loss, frames=3, substeps=10, dt=1e-3, params=["spring_stiffness"])
        grads[dev] = np.asarray(res.grads["spring_stiffness"])
    g, ref = grads[device], grads["cpu"]
    assert np.abs(ref).max() > 0
    np.testing.assert_allclose(g, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
