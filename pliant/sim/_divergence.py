"""What a blown-up run raises, and the advice it gives (shared by the Simulator and pl.diff rollouts)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..solvers import Solver


class DivergenceError(RuntimeError):
    """The simulation blew up; the message names the frame, the quantity and what to change."""

    def __init__(self, frame: int, quantity: str, value: float, advice: str) -> None:
        self.frame, self.quantity, self.value, self.advice = frame, quantity, value, advice
        super().__init__(f"diverged at frame {frame}: {quantity} {value:.3g}; {advice}")


def stability_advice(solver: Solver, substep: float, substeps: int) -> str:
    """What to change when a run blows up: a smaller step, an implicit integrator (for an explicit one), a
    softer material. Shared by :class:`Simulator` and :func:`pliant.diff.rollout`.

    Args:
        solver: the solver that stepped (its ``integrator`` decides whether an implicit one is suggested).
        substep: the solver step Δt [s].
        substeps: solver steps per frame.
    """
    integrator = getattr(solver, "integrator", None)
    return (
        f"lower dt (substep {substep:.3g} s: raise substeps above {substeps})"
        + (
            ", or use an implicit integrator (BackwardEuler)"
            if getattr(integrator, "explicit", False)
            else ""
        )
        + ", or soften the stiffest material"
    )
