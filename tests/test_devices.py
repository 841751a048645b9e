"""The same scenes on every available device agree with the CPU (CUDA runs when a GPU is present)."""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl


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
def test_xpbd_matches_cpu(device: str, schedule: str) -> None:
    """XPBD (either schedule) on this device reproduces the CPU trajectory (1e-8 m, float64)."""
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
