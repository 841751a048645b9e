"""Choosing an object's mass distribution by validation (issue 38 item 2): lumped by length, area or volume,
even per particle (MuJoCo's flexcomp, PhysTwin), or the blend α the global stage fitted (the
``mass_uniformity`` knob, pliant/scene/_knobs.py).

CMA-ES searches α ∈ [0, 1] with the other global parameters when the tracks cover the object
(:func:`pliant.fit._params.tracks_cover`). :func:`choose_mass_distribution` then compares, on validation
frames (the end of the training window: the test frames stay held out), the fitted parameters with α
replaced by 0 (lumped) and by 1 (uniform) against the fitted α, and keeps the simpler named distribution
unless the blend predicts clearly better. ``fit/_run.py`` may call it
after the global stage (see the function).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ._problem import Problem

#: The named distributions and their α.
NAMED = {"lumped": 0.0, "uniform": 1.0}


@dataclass
class MassChoice:
    """The mass distribution kept after validation.

    Attributes:
        name: ``"lumped"``, ``"uniform"`` or ``"fitted"`` (the blend α found by the global stage).
        uniformity: Its α ∈ [0, 1] (the value to set as ``mass_uniformity``).
        errors: Validation mean track error [m] per candidate name (inf where its run diverged).
        reason: One line saying why it was kept, with the errors in mm.
    """

    name: str
    uniformity: float
    errors: dict[str, float] = field(default_factory=dict)
    reason: str = ""


def validation_frames(problem: Problem, validation: float = 0.2) -> tuple[int, int]:
    """The last ``validation`` share of the training frames, [lo, n_train), as the per-element stage's
    validation (``fit(validation=)``): frames the choice may look at without touching the test frames."""
    n = problem.n_train
    lo = n - int(round(validation * (n - 1))) if n >= 6 else 1
    return min(max(lo, 1), n - 1), n


def _window_error(problem: Problem, values: dict[str, float], lo: int, hi: int) -> float:
    """Mean track error [m] of an open-loop run with ``values`` over frames [lo, hi); inf when the run
    diverges or the scene cannot be built."""
    from ..scene import SceneError
    from ..sim import DivergenceError

    try:
        x = problem.simulate(problem.build(values), hi, forced=False)
    except (DivergenceError, SceneError, ValueError):
        return math.inf
    e = problem.errors(x)[lo:hi]
    v = float(np.nanmean(e)) if np.isfinite(e).any() else math.inf
    return v if math.isfinite(v) else math.inf


def choose_mass_distribution(
    problem: Problem,
    values: dict[str, float],
    *,
    frames: tuple[int, int] | None = None,
    rtol: float = 0.02,
) -> MassChoice:
    """Pick the mass distribution of the fitted parameters ``values`` by validation track error.

    The candidates are ``values`` with ``mass_uniformity`` set to 0 (lumped), 1 (uniform) and, when
    ``values`` has one strictly between, the fitted α. A named distribution is kept when its error is within
    ``rtol`` (relative) of the best one's (the simpler explanation wins a tie; lumped before uniform);
    otherwise the best. Runs 2 or 3 open-loop simulations up to the window's end; the test frames are never
    looked at (they stay held out for the report).

    Wiring (``fit/_run.py``, after the global stage, when ``"mass_uniformity"`` is among
    ``problem.globals``): ``c = choose_mass_distribution(problem, values)``; ``values["mass_uniformity"] =
    c.uniformity``; print ``c.reason``.

    Args:
        problem: The fitting problem (its observations, train / test split and scene).
        values: Global parameter values (name → value), e.g. the global stage's best.
        frames: The validation frames [lo, hi); None: :func:`validation_frames` (the last fifth of the
            training frames).
        rtol: Relative tolerance of a tie in validation error (dimensionless, ≥ 0).

    Returns:
        The :class:`MassChoice`.

    Raises:
        ValueError: ``rtol`` negative or not finite, or ``frames`` not a window inside the observations.
    """
    if not (math.isfinite(rtol) and rtol >= 0.0):
        raise ValueError(f"choose_mass_distribution: rtol must be a finite number >= 0, got {rtol}")
    lo, hi = validation_frames(problem) if frames is None else frames
    if not 1 <= lo < hi <= problem.frames:
        raise ValueError(
            f"choose_mass_distribution: frames ({lo}, {hi}) must satisfy 1 <= lo < hi <= {problem.frames}"
        )
    alphas = dict(NAMED)
    fitted = values.get("mass_uniformity")
    if fitted is not None and 0.0 < float(fitted) < 1.0:
        alphas["fitted"] = float(fitted)
    errors = {n: _window_error(problem, {**values, "mass_uniformity": a}, lo, hi) for n, a in alphas.items()}
    best = min(errors, key=lambda n: errors[n])
    name = next((n for n in NAMED if errors[n] <= (1.0 + rtol) * errors[best]), best)
    shown = ", ".join(f"{n} {errors[n] * 1e3:.3g} mm" for n in errors)
    if name == best:
        why = "the lowest validation error"
    else:
        why = f"within {rtol:.0%} of the best ({best}): the simpler explanation"
    reason = (
        f"mass distribution: {name} (α = {alphas[name]:.3g}), {why}; errors on frames {lo}-{hi - 1}: {shown}"
    )
    return MassChoice(name, alphas[name], errors, reason)


__all__ = ["NAMED", "MassChoice", "choose_mass_distribution", "validation_frames"]
