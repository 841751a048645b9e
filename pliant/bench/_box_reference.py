"""The soft box's stored motion reference and the error of a run against it (no simulation here).

``trajectory_error`` is the largest deviation of a run's centre-of-mass height from the converged float64
curve over frames 1–:data:`WINDOW` (the fall, the impact and the rebound), relative to the drop height.
The curves are made by :mod:`pliant.bench._box_motion` (``python -m pliant.bench._box_motion N``); the
benchmark rows of :mod:`pliant.bench._fem` report :func:`motion_fields`. This module sits below both so
that neither imports the other.
"""

from __future__ import annotations

import numpy as np

from ._common import REFERENCES, curve_deviation, load_reference

#: The drop height [m]: the scale of ``trajectory_error``.
DROP_HEIGHT = 0.1
#: Frames judged: the fall, the impact (frame 10) and the rebound to its top (frame 20).
WINDOW = 24


def reference_curve(n: int) -> np.ndarray:
    """The stored converged centre-of-mass curve [m] of the n³ drop (frames 1 … :data:`WINDOW`)."""
    return load_reference(f"soft_box_{n}", "com", f"python -m pliant.bench._box_motion {n}")


def trajectory_error(curve: np.ndarray, reference: np.ndarray) -> float:
    """max_k |curve_k − reference_k| / :data:`DROP_HEIGHT` over the frames both have (inf if not finite):
    the reference's :data:`WINDOW` frames."""
    return curve_deviation(curve, reference, DROP_HEIGHT)


def motion_fields(n: int, curve: np.ndarray) -> dict:
    """The ``trajectory_error`` column of a soft-box row (None without a stored reference for n), and the
    lowest centre-of-mass height [m] of the run and of the reference (the impact's depth)."""
    if not (REFERENCES / f"soft_box_{n}.npz").exists():
        return {"trajectory_error": None}
    ref = reference_curve(n)
    return {
        "trajectory_error": round(trajectory_error(curve, ref), 5),
        "min_height_com": round(float(np.min(curve)), 5),
        "min_height_com_reference": round(float(np.min(ref)), 5),
    }
