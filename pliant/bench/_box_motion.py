"""The soft box's whole motion: its centre-of-mass height per frame against a converged reference.

The drop (:mod:`pliant.bench._fem`: 0.5 m neo-Hookean cube, bottom 0.1 m above the ground, 60 frames of
1/60 s) is judged like the drape: ``trajectory_error`` is the largest deviation of the centre-of-mass height
over the fall, the impact and the rebound (frames 1–:data:`WINDOW`) from a converged float64 curve of the
same physics (the same energies, ground penalty and post-step friction), relative to the drop height
(0.1 m). One implicit step per frame damps the impact (the centre bottoms out higher and rebounds less),
which the resting height alone does not show. Later the box keeps bouncing and the curves of converging
runs drift apart in phase (first-order convergence: the contact is not smooth), so the window ends at the
top of the first rebound.

The references are symplectic Euler at :data:`REFERENCE_SUBSTEPS` substeps per frame in float64, with the
same ground penalty and friction as every row (:func:`pliant.bench._fem.make_solver`), stored in
``pliant/bench/references/soft_box_<n>.npz``; regenerate with ``python -m pliant.bench._box_motion N``. The
stored curve's own error is estimated from the run at a quarter of the substeps (``self_error`` in the
file, and printed).

Why not backward Euler (the former references, 256 / 512 substeps): it converges slowly and not
monotonically here, because its numerical damping takes energy out of the box's vibration after the impact,
and the rebound depends on that energy. Measured at n = 4: backward Euler at 128 / 256 / 512 / 1024
substeps is 0.55 % / 0 / 3.7 % / 8.1 % from the 256-substep curve, moving towards the curve symplectic Euler
converges to (160 / 640 substeps differ by 0.08 %; that curve is 14 % from backward Euler's at 256, as
ImplicitMidpoint's was). At n = 10 symplectic Euler at 320 / 1280 substeps differ by 0.13 % and sit 2.4 %
from backward Euler's 512-substep curve. Symplectic Euler has no numerical damping, so its small-step limit
is the undamped physics the scene states.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

# The stored curve and the error against it live one module down, where the benchmark rows read them.
from ._box_reference import DROP_HEIGHT, WINDOW, motion_fields, reference_curve, trajectory_error
from ._common import REFERENCES
from ._fem import soft_box_drop

#: Substeps per frame of the references (symplectic Euler, float64; the rows' explicit setting is 20).
REFERENCE_SUBSTEPS = {4: 1280, 10: 1280, 20: 1280, 30: 1280}


def com_curve(
    n: int,
    *,
    method: str = "implicit",
    substeps: int = 1,
    dtype: str = "float64",
    minimizer: str = "lbfgs",
    tol: float | None = None,
    frames: int = 60,
    integrator: str = "BackwardEuler",
) -> np.ndarray:
    """Centre-of-mass height [m] at frames 1 … ``frames`` of the n³ drop with the benchmark's solver.

    Args:
        n: cells per side.
        method: "implicit" (backward Euler) or "explicit" (symplectic Euler).
        substeps: steps per frame of 1/60 s.
        dtype: "float32" or "float64".
        minimizer: the implicit step's minimiser, "lbfgs" or "newton".
        tol: the minimiser's tolerance per frame [m/s] (None: the benchmark's).
        frames: frames to run.
        integrator: the implicit integrator's class name in :mod:`pliant.integrators`.
    """
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "com.npy"
        soft_box_drop(
            n,
            method,
            substeps,
            frames,
            dtype=dtype,
            minimizer=minimizer,
            trajectory=str(path),
            integrator=integrator,
            newton_tol=tol,
        )
        return np.load(path)


def compute_reference(n: int, substeps: int | None = None) -> np.ndarray:
    """The converged curve: float64 symplectic Euler at ``substeps`` (default :data:`REFERENCE_SUBSTEPS`)."""
    return com_curve(n, method="explicit", substeps=substeps or REFERENCE_SUBSTEPS[n], frames=WINDOW)


__all__ = [
    "DROP_HEIGHT",
    "REFERENCE_SUBSTEPS",
    "WINDOW",
    "com_curve",
    "compute_reference",
    "motion_fields",
    "reference_curve",
    "trajectory_error",
]


if __name__ == "__main__":
    for arg in sys.argv[1:]:
        size = int(arg)
        REFERENCES.mkdir(exist_ok=True)
        subs = REFERENCE_SUBSTEPS[size]
        com = compute_reference(size, subs)
        # First order: the quarter-step run is about 4/3 of this from the limit, the stored curve 1/3.
        self_error = trajectory_error(compute_reference(size, subs // 4), com)
        np.savez(REFERENCES / f"soft_box_{size}.npz", com=com, substeps=subs, self_error=self_error)
        print(
            f"soft_box_{size}: min com {com.min():.6f} m, final {com[-1]:.6f} m, "
            f"quarter-step diff {self_error:.2e}"
        )
