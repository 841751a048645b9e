"""What a fit's stage returns (CMA-ES, the gradient stages): at the bottom of ``pliant.fit`` so that the
stages and the checkpoints that store them (``_resume.py``) import it without importing each other."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class StageResult:
    """What one stage found.

    Attributes:
        values: Global parameters (name → value) of the best candidate.
        loss: Its training loss.
        history: Best training loss after each iteration (generation / epoch).
        evaluations: Simulations run.
        wall_time: Seconds.
        interrupted: Stopped by Ctrl-C (the best values so far are kept).
        per_element: Per-element arrays (``model.<array>`` / ``constraints.<i>.<array>`` → values), if any.
        kept: Whether :func:`fit` kept this stage's values (the gradient stage's are dropped when they do
            not lower the open-loop loss on the validation frames).
        validation: The gradient stage's validation frames [lo, hi) and their open-loop loss before and
            after it (set by :func:`fit`; None when it trained on every training frame).
        stop: Why the stage stopped (CMA-ES: ``"converged"``, ``"step"``, ``"cap"`` or ``"interrupted"``).
    """

    values: dict[str, float]
    loss: float
    history: list[float] = field(default_factory=list)
    evaluations: int = 0
    wall_time: float = 0.0
    interrupted: bool = False
    per_element: dict[str, np.ndarray] = field(default_factory=dict)
    kept: bool = True
    validation: dict | None = None
    stop: str = ""


__all__ = ["StageResult"]
