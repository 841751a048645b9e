"""The generated projection kernels (pliant/constraints/_factory.py) reproduce the hand-written ones.

``tests/data/xpbd_schedules_before_factory.npz`` was written by the hand-written distance, dihedral and
volume kernels (commit dfbd1c2): a cloth with bending and a tet box with volume constraints on the
ground, both schedules, XPBD and PBD, float32 and float64, 30 steps. The generated kernels must give the
same positions bit for bit (same arithmetic in the same order), including the Gauss–Seidel colouring
sweep that the golden scene trajectories do not cover.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import warp as wp

import pliant as pl
import pliant.constraints as pc
from pliant.model import ModelBuilder

wp.init()
wp.config.quiet = True

FIXTURE = Path(__file__).parent / "data" / "xpbd_schedules_before_factory.npz"


def _run(dtype: str, schedule: str, pbd: bool) -> np.ndarray:
    b = ModelBuilder(gravity=(0, -9.81, 0))
    b.add_cloth_grid(
        nx=10,
        ny=10,
        size=0.5,
        mass=0.1,
        stiffness=200.0,
        origin=(-0.25, 0.3, -0.25),
        plane="xz",
        pin="top-corners",
        bend_stiffness=1e-3,
    )
    b.add_soft_box(
        origin=(0.5, 0.5, 0), size=(0.2, 0.2, 0.2), cells=(2, 2, 2), stiffness=500.0, E=1e4, nu=0.3
    )
    b.add_ground(0.0, friction=0.4)
    m = b.finalize(device="cpu", dtype=dtype)
    cls = pl.solvers.PBD if pbd else pl.solvers.XPBD
    kw = {"bending_stiffness": 0.5} if pbd else {"bending_compliance": 1e-2, "volume_compliance": 1e-6}
    relaxation = 1.0 if schedule == "coloring" else 1.5
    s = cls(m, iterations=4, schedule=schedule, relaxation=relaxation, **kw)
    assert [type(c) for c in s.constraints] == [pc.Distance, pc.DihedralBending, pc.Volume, pc.Ground]
    s0, s1 = m.state(), m.state()
    for _ in range(30):
        s.step(s0, s1, None, 1 / 240)
        s0, s1 = s1, s0
    return s0.particle_q.numpy()


def test_generated_kernels_equal_the_hand_written_ones_bit_for_bit():
    """Both schedules × XPBD/PBD × float32/float64: identical to the pre-factory kernels' positions."""
    with np.load(FIXTURE) as f:
        expected = [f[f"arr_{k}"] for k in range(len(f.files))]
    k = 0
    for dtype in ("float32", "float64"):
        for schedule in ("coloring", "jacobi"):
            for pbd in (False, True):
                np.testing.assert_array_equal(_run(dtype, schedule, pbd), expected[k], err_msg=f"case {k}")
                k += 1
    assert k == len(expected)


def test_factory_caches_one_kernel_set_per_family():
    """Every constraint family built from the same (name, arity) shares one compiled kernel set."""
    a = pc.projection_kernels("distance", pc.distance_c, pc.distance_grad, 2, unit_gradient=True)
    assert a is pc.Distance.kernels
    assert pc.Volume.kernels is not pc.DihedralBending.kernels
    assert len(set(pc.Volume.kernels)) == 4


def test_three_particle_area_constraint_holds_in_xpbd():
    """TriangleArea (k = 3, from the same factory): a randomly squashed cloth, free of gravity, regains
    every triangle's rest area under rigid XPBD (from over 20 % off to 1e-4 with colouring, 1e-2 Jacobi), and
    keeps its momentum (∇C sums to 0)."""
    for schedule in ("coloring", "jacobi"):
        b = ModelBuilder(gravity=(0.0, 0.0, 0.0))
        b.add_cloth_grid(
            nx=4, ny=4, size=0.4, mass=0.2, stiffness=0.0, origin=(0, 0, 0), plane="xz", pin="none"
        )
        m = b.finalize(device="cpu", dtype="float64")
        area = pc.TriangleArea(compliance=0.0)
        assert pc.TriangleArea.kernels.jacobi is not pc.Volume.kernels.jacobi
        s = pl.solvers.XPBD(m, iterations=100, schedule=schedule, constraints=[area], contact=False)
        tris = m.tri_indices.numpy()
        rest = pc._area.triangle_areas_np(m.particle_q_np, tris)
        rng = np.random.default_rng(0)
        s0, s1 = m.state(), m.state()
        s0.particle_q.assign(
            m.particle_q_np * np.array([0.8, 1.0, 0.9]) + 0.01 * rng.normal(size=(m.particle_count, 3))
        )
        squashed = pc._area.triangle_areas_np(s0.particle_q.numpy(), tris)
        assert np.abs(squashed - rest).max() > 0.2 * rest.min()
        for _ in range(20):
            s.step(s0, s1, None, 1 / 240)
            s0, s1 = s1, s0
        x, v = s0.particle_q.numpy(), s0.particle_qd.numpy()
        err = np.abs(pc._area.triangle_areas_np(x, tris) / rest - 1.0).max()
        # Jacobi's mass-split averaging converges more slowly than Gauss–Seidel (measured 2.5e-5 and 6e-3).
        assert err < (1e-4 if schedule == "coloring" else 1e-2), f"{schedule}: relative area error {err:.2e}"
        p = (m.particle_mass_np[:, None] * v).sum(axis=0)
        assert np.abs(p).max() < 1e-10, f"{schedule}: momentum {p}"


@wp.func
def _height_c(x0: Any, rest: Any):
    """C = y − h: one particle per constraint (k = 1)."""
    return x0[1] - rest


@wp.func
def _height_grad(x0: Any):
    zero = type(x0[0])(0.0)
    return type(x0)(zero, type(x0[0])(1.0), zero)


class _Height(pc.FixedArityConstraint):
    """A one-particle constraint made by the factory (private: test-only, not registered)."""

    kernels = pc.projection_kernels("test_height", _height_c, _height_grad, 1)

    def __init__(self, indices, height):
        super().__init__(compliance=0.0)
        self._idx, self._h = np.asarray(indices).reshape(-1, 1), height

    def bind(self, model, coloring):
        self.model = model
        n = self._idx.shape[0]
        self._device_arrays(self._idx, np.full(n, self._h), np.zeros(n), coloring)


def test_one_particle_constraint_from_the_factory_projects_exactly():
    """k = 1: rigid C = y − h puts each listed particle at height h in one step, and leaves the others."""
    b = ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles([[0.0, 0.3, 0.0], [0.1, -0.2, 0.0], [0.2, 0.5, 0.1]], 0.1)
    m = b.finalize(device="cpu", dtype="float64")
    c = _Height([0, 1], 0.05)
    s = pl.solvers.XPBD(m, iterations=1, constraints=[c], contact=False)
    s0, s1 = m.state(), m.state()
    s.step(s0, s1, None, 1e-2)
    x = s1.particle_q.numpy()
    np.testing.assert_allclose(x[:2, 1], 0.05, atol=1e-15)
    np.testing.assert_array_equal(x[2], m.particle_q_np[2])
    with pytest.raises(ValueError, match="arity must be an integer >= 1"):
        pc.projection_kernels("bad", _height_c, _height_grad, 0)
