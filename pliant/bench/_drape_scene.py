"""The cloth drape scene and the solvers of its rows, shared by the benchmark and its motion references.

The scene (:mod:`pliant.bench._mass_spring` describes it: 1 m, n × n cells, 0.5 kg, E·t = 1000 N/m, ν = 0.3,
two pinned corners, no ground) and the sag it is judged by. It sits below :mod:`pliant.bench._mass_spring`
(the timed rows) and :mod:`pliant.bench._drape_motion` (the converged curves), which both build it, so that
neither of those imports the other.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..model import Model, State
    from ..solvers import Solver

#: Frames of 1/60 s per run: the fall, which the motion references cover.
FRAMES = 30
FRAME_DT = 1.0 / 60.0


def cloth_drape_model(
    n: int,
    *,
    device: str | None = "cpu",
    dtype: str = "float32",
    damping: float = 0.0,
    bend_stiffness: float = 0.0,
) -> Model:
    """The drape scene's Model: n × n cells, 1 m, 0.5 kg, E·t = 1000 N/m, ν = 0.3, two pinned corners;
    ``damping`` γ [N s/m] of the springs' dashpots and ``bend_stiffness`` [N/m] of bend springs (two cells
    apart) are 0 in the scene, which has neither."""
    from ..model import ModelBuilder

    b = ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_cloth_grid(
        nx=n,
        ny=n,
        size=1.0,
        mass=0.5,
        youngs_modulus_thickness=1000.0,
        poisson=0.3,
        damping=damping,
        bend_stiffness=bend_stiffness,
        origin=(-0.5, 0.0, -0.5),
        plane="xz",
        pin="top-corners",
    )
    return b.finalize(device=device, dtype=dtype)


def sag(model: Model, x: np.ndarray) -> float:
    """Pin height minus the lowest particle's height [m]."""
    pinned = model.particle_inv_mass.numpy() == 0
    return float(x[pinned, 1].mean() - x[:, 1].min())


def sag_fields(model: Model, state: State, reference: float) -> dict:
    """The sanity columns of a drape row: sag [m] of the final ``state``, ``reference``, relative error,
    and whether every position is finite (the sag is NaN otherwise)."""
    x = state.particle_q.numpy()
    finite = bool(np.all(np.isfinite(x)))
    sg = sag(model, x) if finite else float("nan")
    comparable = bool(np.isfinite(reference)) and finite
    return {
        "sag": round(sg, 5),
        "sag_reference": reference,
        "sag_rel_error": round(abs(sg - reference) / reference, 5) if comparable else None,
        "stable": finite,
    }


def make_solver(
    model: Model,
    method: str,
    *,
    cg_iterations: int = 100,
    cg_tol: float = 1.0e-2,
    damping_rate: float = 0.0,
    fused_frame: bool | None = None,
) -> Solver:
    """The solver of a benchmark row: "implicit" / "symplectic" (FastMassSpring) or "force" (ForceSolver).

    Args:
        model: the drape model.
        method: "implicit", "symplectic" or "force".
        cg_iterations: the most CG iterations per implicit step.
        cg_tol: CG's relative residual; the step stops there (FastMassSpring's host check).
        damping_rate: velocity damping c [1/s]; 0 for the benchmark's physics.
        fused_frame: FastMassSpring's one-launch CPU frame (None: where it applies; False: step by step).
    """
    from ..solvers import FastMassSpring

    if method == "force":
        from ..energies import Gravity, Springs
        from ..integrators import SymplecticEuler
        from ..solvers import ForceSolver

        return ForceSolver(
            model, energies=[Springs(), Gravity()], integrator=SymplecticEuler(), damping_rate=damping_rate
        )
    return FastMassSpring(
        model,
        method=method,
        cg_iterations=cg_iterations,
        cg_tol=cg_tol,
        damping_rate=damping_rate,
        fused_frame=fused_frame,
    )
