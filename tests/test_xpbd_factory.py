"""The generated projection kernels (pliant/constraints/_factory.py) reproduce the hand-written ones.

``tests/data/xpbd_schedules_before_factory.npz`` was written by the hand-written distance, dihedral and
volume kernels (commit dfbd1c2): a cloth with bending and a tet box with volume constraints on the
ground, both schedules, XPBD and PBD, float32 and float64, 30 steps. The generated kernels must give the
same positions bit for bit (same arithmetic in the same order), including the Gauss–Seidel colouring
sweep that the golden scene trajectories do not cover.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
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
    assert len(set(pc.Volume.kernels)) == 3
