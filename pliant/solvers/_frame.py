"""One frame of substeps as one callable: the stepping loop every frame-based driver shares (the Simulator,
the benchmarks, ``pl.diff.rollout`` and through it ``pl.fit``).

Two ways to hold the states:

- ping-pong (``fresh=False``): two State buffers swap roles after each substep, nothing is allocated; one
  frame is a fixed sequence of launches on fixed arrays, which is what a CUDA graph can capture;
- fresh (``fresh=True``): every substep writes new arrays, so that a ``wp.Tape`` recording the frame keeps
  every intermediate state for the backward pass.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import warp as wp

from ..model import Control, State

if TYPE_CHECKING:
    from ._base import Solver


class FrameStep:
    """``substeps`` steps of ``solver`` of ``dt`` [s] each, one frame, as one call.

    Args:
        solver: any solver (``step(state_in, state_out, control, dt)``).
        dt: the substep Δt [s] (frame duration / substeps).
        substeps: solver steps per frame (>= 1).
        fresh: allocate a new State per substep (recorded, differentiable frames) instead of alternating
            two buffers.
        on_step: called after every substep (solver statistics in the benchmarks).

    Example::

        frame = FrameStep(solver, frame_dt / 16, 16)
        s0, s1 = model.state(), model.state()
        for _ in range(frames):
            s0, s1 = frame(s0, control, s1)   # s0: the frame's end state
    """

    def __init__(
        self,
        solver: Solver,
        dt: float,
        substeps: int,
        *,
        fresh: bool = False,
        on_step: Callable[[], None] | None = None,
    ) -> None:
        if isinstance(substeps, bool) or int(substeps) != substeps or substeps < 1:
            raise ValueError(f"FrameStep: substeps must be an integer >= 1, got {substeps!r}")
        if not dt > 0:
            raise ValueError(f"FrameStep: dt must be a positive substep [s], got {dt!r}")
        self.solver, self.dt, self.substeps = solver, float(dt), int(substeps)
        self.fresh, self.on_step = fresh, on_step

    def __call__(
        self, state: State, control: Control | None, spare: State | None = None
    ) -> tuple[State, Any]:
        """Advance ``state`` by one frame.

        Args:
            state: the frame's first state (read; with ``fresh`` never written).
            control: the Control the solver reads (None: none).
            spare: ping-pong only: the second buffer (written).

        Returns:
            ``(end, spare)``: the frame's end state and the other buffer (ping-pong), or ``(end, None)``
            (fresh: ``end`` is a new State).
        """
        step = self.solver.step
        if self.fresh:
            for _ in range(self.substeps):
                nxt = State(
                    wp.empty_like(state.particle_q, requires_grad=True),
                    wp.empty_like(state.particle_qd, requires_grad=True),
                )
                step(state, nxt, control, self.dt)
                state = nxt
                if self.on_step is not None:
                    self.on_step()
            return state, None
        if spare is None:
            raise ValueError("FrameStep: ping-pong stepping needs the spare state buffer")
        # One call for the whole frame where the solver has it (FastMassSpring's fused CPU frame): the same
        # end state in the same buffer; not with a per-substep callback.
        whole = getattr(self.solver, "step_frame", None) if self.on_step is None else None
        if whole is not None and whole(state, spare, control, self.dt, self.substeps):
            return (state, spare) if self.substeps % 2 == 0 else (spare, state)
        for _ in range(self.substeps):
            step(state, spare, control, self.dt)
            state, spare = spare, state
            if self.on_step is not None:
                self.on_step()
        return state, spare


__all__ = ["FrameStep"]
