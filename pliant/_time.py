"""pliant's words for time: a *frame* lasts ``frame_dt`` [s] (the interval between two recorded states), and
each frame runs ``substeps`` solver steps of ``dt`` [s] each (``dt`` is the solver's step everywhere).
"""

from __future__ import annotations


def substep_dt(frame_dt: float, substeps: int) -> float:
    """The solver's step ``dt`` [s] when a frame of ``frame_dt`` [s] runs ``substeps`` steps.

    The one place the frame is divided (the Simulator, the scenes, the fitting stages, the live viewer and
    the benchmarks call it, or ``Simulator.substep_dt`` / ``Scene.substep_dt``), so that every caller steps
    with the same float. Pure Python, in the base layer: any layer may use it.

    Args:
        frame_dt: frame duration [s], > 0.
        substeps: solver steps per frame, an integer >= 1.

    Returns:
        ``frame_dt / substeps`` [s].

    Raises:
        ValueError: ``substeps`` is not an integer >= 1 or ``frame_dt`` is not a positive number.
    """
    if isinstance(substeps, bool) or int(substeps) != substeps or substeps < 1:
        raise ValueError(f"substeps must be an integer >= 1 (solver steps per frame), got {substeps!r}")
    if not frame_dt > 0:
        raise ValueError(f"frame_dt must be a positive frame duration [s], got {frame_dt!r}")
    return frame_dt / substeps
