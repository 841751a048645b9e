"""Many worlds in one model: throughput of W copies (``ModelBuilder.replicate``) stepped together against
one world alone, in worlds × frames per CPU second.

Rows: a 16 × 16 cloth (the demo's mass-spring cloth: ForceSolver with symplectic Euler, 80 substeps per
frame of 1/30 s, ground) and a 4 × 4 × 4-cell FEM soft box (backward Euler with L-BFGS, 4 substeps per frame
of 1/60 s, ground). Each world has its own stiffness or Young's modulus. The sanity column is world 0's final
centroid height, which must not depend on W (the worlds are independent). Figures: ``worlds_frames_per_s``
per W and ``speedup`` over W = 1 (issue #16's goal: ≥ 10 at W = 256 on one core).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Any

from ._common import print_rows


def _cloth(worlds: int) -> tuple[Any, Any, float, int]:
    from ..energies import mass_spring
    from ..integrators import SymplecticEuler
    from ..model import ModelBuilder
    from ..solvers import ForceSolver

    b = ModelBuilder()
    b.add_cloth_grid(
        nx=16, ny=16, size=1.0, mass=0.2, stiffness=300.0, bend_stiffness=6.0, damping=0.005,
        origin=(-0.5, 0.9, -0.5), pin="top-corners",
    )  # fmt: skip
    b.add_ground(0.0, friction=0.6)
    b.replicate(worlds)
    model = b.finalize(device="cpu", dtype="float32")
    for w in range(worlds):
        model.set_world_parameter("spring_stiffness", w, 300.0 + w)
    solver = ForceSolver(
        model,
        energies=mass_spring(),
        integrator=SymplecticEuler(),
        damping_rate=1.0,
    )
    return model, solver, 1.0 / 30.0, 80


def _soft_box(worlds: int) -> tuple[Any, Any, float, int]:
    from ..energies import Gravity, NeoHookean
    from ..integrators import BackwardEuler
    from ..model import ModelBuilder
    from ..solvers import ForceSolver

    b = ModelBuilder()
    b.add_soft_box(cells=(4, 4, 4), size=(0.2, 0.2, 0.2), origin=(0.0, 0.15, 0.0), E=5e4, nu=0.3, density=500)
    b.add_ground(0.0, friction=0.5)
    b.replicate(worlds)
    model = b.finalize(device="cpu", dtype="float64")
    for w in range(worlds):
        model.set_world_material(w, 5e4 * (1.0 + 0.001 * w), 0.3)
    solver = ForceSolver(
        model,
        energies=[NeoHookean(), Gravity()],
        integrator=BackwardEuler(newton_tol=1e-4),
        minimizer={"method": "lbfgs"},
    )
    return model, solver, 1.0 / 60.0, 4


def _throughput(make: Callable[[int], tuple], counts: tuple[int, ...], frames: int) -> dict:
    from ..sim import Simulator

    rates, heights = {}, {}
    for w in counts:
        model, solver, frame_dt, substeps = make(w)
        sim = Simulator(model, solver, frame_dt=frame_dt, substeps=substeps)
        sim.run(1, progress=False)  # compile and record launches outside the timing
        t0 = time.process_time()
        traj = sim.run(frames + 1, progress=False)
        cpu = time.process_time() - t0
        rates[w] = w * frames / cpu
        heights[w] = float(traj.world(0).x[-1, :, 1].mean()) if w > 1 else float(traj.x[-1, :, 1].mean())
    one = rates[counts[0]]
    spread = max(heights.values()) - min(heights.values())
    return {
        "worlds_frames_per_s": {str(w): round(r, 2) for w, r in rates.items()},
        "speedup": {str(w): round(r / one, 2) for w, r in rates.items()},
        # world 0 moves the same whatever W is (bit for bit for explicit steps; to the tolerance for L-BFGS)
        "world0_height_m": round(heights[counts[0]], 6),
        "world0_height_spread_m": float(f"{spread:.3g}"),
        "frames": frames,
    }


def worlds_cloth_16(quick: bool = False) -> dict:
    """W = 1, 16, 256 (quick: 1, 4) worlds of the 16 × 16 cloth, 10 frames (quick: 2) of 80 substeps."""
    counts, frames = ((1, 4), 2) if quick else ((1, 16, 256), 10)
    return {"scene": "cloth 16x16, ForceSolver + SymplecticEuler", **_throughput(_cloth, counts, frames)}


def worlds_soft_box_4(quick: bool = False) -> dict:
    """W = 1, 16, 256 (quick: 1, 4) worlds of a 4³-cell FEM box, 10 frames (quick: 2) of 4 L-BFGS steps."""
    counts, frames = ((1, 4), 2) if quick else ((1, 16, 256), 10)
    return {"scene": "soft box 4x4x4 cells, BackwardEuler L-BFGS", **_throughput(_soft_box, counts, frames)}


BENCHMARKS: dict[str, Callable[..., dict]] = {
    "worlds_cloth_16": worlds_cloth_16,
    "worlds_soft_box_4": worlds_soft_box_4,
}


if __name__ == "__main__":
    print_rows(BENCHMARKS, sys.argv[1:])
