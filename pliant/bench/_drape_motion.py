"""The drape's whole motion, not only its rest: the sag per frame against a converged reference.

A speed figure means little if the solver buys it by damping the motion away (truncated CG acts as heavy
damping; a benchmark's extra velocity damping slows the fall). ``trajectory_error`` is the largest deviation
of a run's sag curve (pin height minus the lowest particle, every frame) from the converged curve of the
same physics, relative to the reference's final sag, over the fall: the first 30 frames (0.5 s), where
truncated iterations and extra damping show (the issue's 128 × 128 drape: sag 0.61 m at frame 30 with 20 CG
iterations, 0.97 m converged). Later the undamped drape (no dashpots, no bending) folds chaotically and no
run converges over long windows (n = 16, 60 frames: 320 and 640 substeps per frame still differ by 8 %),
so the window stops at the fall. The references are float64 symplectic Euler at 640 substeps per frame
(n = 16: 320 substeps are within 6e-5 of it, first-order convergence measured 40 → 320), undamped, computed
once and stored in ``pliant/bench/references/cloth_drape_<n>.npz``; regenerate with
``python -m pliant.bench._drape_motion N`` (n = 16: a second; n = 128: about a minute on one core).
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

import numpy as np

from ._common import REFERENCES, curve_deviation, frame_curve, load_reference
from ._drape_scene import FRAME_DT, cloth_drape_model, make_solver, sag

if TYPE_CHECKING:
    from ..model import Model
    from ..solvers import Solver

#: Substeps per frame of the references (8× or more the stable benchmark setting).
REFERENCE_SUBSTEPS = {16: 640, 64: 640, 128: 1280}
#: Frames of 1/60 s the references cover: the fall.
REFERENCE_FRAMES = 30


def sag_curve(
    n: int,
    method: str,
    *,
    substeps: int,
    cg_iterations: int = 100,
    cg_tol: float = 1.0e-2,
    damping_rate: float = 0.0,
    frames: int = REFERENCE_FRAMES,
    dtype: str = "float32",
    device: str | None = "cpu",
) -> np.ndarray:
    """Sag [m] at frames 0 … ``frames`` of the n × n drape run with a benchmark solver (``method``:
    "implicit", "symplectic" or "force"; see :func:`pliant.bench._drape_scene.make_solver`)."""
    model = cloth_drape_model(n, device=device, dtype=dtype)
    solver = make_solver(model, method, cg_iterations=cg_iterations, cg_tol=cg_tol, damping_rate=damping_rate)
    return solver_curve(model, solver, substeps=substeps, frames=frames)


def solver_curve(
    model: Model, solver: Solver, *, substeps: int, frames: int = REFERENCE_FRAMES
) -> np.ndarray:
    """Sag [m] at frames 0 … ``frames`` of ``solver`` stepping ``model`` from its initial state, ``substeps``
    steps of 1/60 s / ``substeps`` per frame (any pliant solver: mass-spring, XPBD, ...)."""
    return frame_curve(
        model, solver, lambda x: sag(model, x), substeps=substeps, frames=frames, frame_dt=FRAME_DT
    )


def reference_curve(n: int) -> np.ndarray:
    """The stored converged sag curve [m] of the n × n drape (frames 0 … 30)."""
    return load_reference(f"cloth_drape_{n}", "sag", f"python -m pliant.bench._drape_motion {n}")


def compute_reference(n: int) -> np.ndarray:
    """The converged curve: float64 symplectic Euler, undamped, at :data:`REFERENCE_SUBSTEPS`."""
    return sag_curve(n, "symplectic", substeps=REFERENCE_SUBSTEPS[n], dtype="float64")


def trajectory_error(curve: np.ndarray, reference: np.ndarray) -> float:
    """max_k |curve_k − reference_k| / reference_final over the frames both have (inf if not finite)."""
    return curve_deviation(curve, reference, abs(reference[-1]))


def curve_error(n: int, curve: np.ndarray) -> dict:
    """``{"trajectory_error": ...}`` of a sag ``curve`` of the n × n drape (None without a reference)."""
    if not (REFERENCES / f"cloth_drape_{n}.npz").exists():
        return {"trajectory_error": None}
    return {"trajectory_error": round(trajectory_error(curve, reference_curve(n)), 5)}


def motion_fields(
    n: int, method: str, substeps: int, cg_iterations: int, damping_rate: float, **kw: Any
) -> dict:
    """The ``trajectory_error`` column of a drape row: a second, untimed run of the row's settings over
    the reference's frames (None when there is no reference for n)."""
    if not (REFERENCES / f"cloth_drape_{n}.npz").exists():
        return {"trajectory_error": None}
    curve = sag_curve(
        n, method, substeps=substeps, cg_iterations=cg_iterations, damping_rate=damping_rate, **kw
    )
    return curve_error(n, curve)


def export_network(n: int, path: str) -> None:
    """Write the n × n drape's spring network for peers (benchmarks/peers/cloth_drape_newton.py): positions
    ``x`` [P, 3] m, lumped ``mass`` [P] kg, ``free`` [P] (False: pinned), ``springs`` [S, 2], ``rest`` [S] m
    and ``stiffness`` [S] N/m."""
    model = cloth_drape_model(n, device="cpu", dtype="float64")
    np.savez(
        path,
        x=model.particle_q.numpy(),
        mass=model.particle_mass.numpy(),
        free=model.particle_inv_mass.numpy() > 0,
        springs=model.spring_indices.numpy(),
        rest=model.spring_rest_length.numpy(),
        stiffness=model.spring_stiffness.numpy(),
    )


if __name__ == "__main__":
    if sys.argv[1:2] == ["export"]:
        export_network(int(sys.argv[2]), sys.argv[3])
        sys.exit(0)
    for arg in sys.argv[1:]:
        size = int(arg)
        REFERENCES.mkdir(exist_ok=True)
        curve = compute_reference(size)
        np.savez(REFERENCES / f"cloth_drape_{size}.npz", sag=curve, substeps=REFERENCE_SUBSTEPS[size])
        print(f"cloth_drape_{size}: final sag {curve[-1]:.6f} m, max {curve.max():.6f} m")
