"""The Solver contract shared by every model (Newton's / warp.sim's convention)."""

from __future__ import annotations

import abc
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._warp import GradientError, _tape_active, grad_enabled
from ..model import Control, Model, Parameter, State, solver_array
from ._post import check_collisions

#: The velocity damping rate c of v ← v·exp(−cΔt), declared by the solvers that hold it as an array.
DAMPING_RATE = Parameter(
    "damping_rate",
    "velocity damping rate of v <- v exp(-c dt)",
    "1/s",
    "global",
    ("solver.damping_rate_array",),
    (1e-3, 30.0),
    get=solver_array(
        "damping_rate_array",
        "with ForceSolver(damping_rate=c) or FastMassSpring(damping_rate=c) on a requires_grad model",
    ),
)


class Solver(abc.ABC):
    """Advances a Model one step: ``step(state_in, state_out, control, dt)``; never writes ``state_in``.

    Every solver owns the same post-step contact handlers: ``collisions`` are objects with
    ``apply(model, state_in, state_out, dt)`` (``pl.collision.Colliders``, ``SelfCollision``), run in order
    after the solver's own step and ground response (:meth:`apply_collisions`).

    Args:
        model: the Model.
        collisions: contact handlers run after each step (checked here for an ``apply`` method).
    """

    def __init__(self, model: Model, collisions: Sequence[Any] = ()) -> None:
        self.model = model
        self.collisions = check_collisions(collisions)

    @abc.abstractmethod
    def step(self, state_in: State, state_out: State, control: Control | None, dt: float) -> None:
        """Advance ``state_in`` by ``dt`` [s] into ``state_out``."""

    def step_frame(
        self, state: State, spare: State, control: Control | None, dt: float, substeps: int
    ) -> bool:
        """Advance ``state`` by ``substeps`` steps of ``dt`` [s] in one call, leaving the end state where
        ping-pong stepping would (``state`` for an even count, ``spare`` for an odd one), if this solver can
        do a frame at once; returns whether it did. Default: False (the caller steps; see ``FrameStep``).

        Args:
            state: the frame's first state (its buffer holds the end for an even count).
            spare: the second buffer (overwritten).
            control: the Control the solver reads (None: none).
            dt: the substep Δt [s].
            substeps: steps in the frame (>= 1).
        """
        return False

    def frame_is_one_launch(self) -> bool:
        """Whether :meth:`step_frame` runs a whole frame as one kernel launch: a replayed graph of it saves
        nothing, so the Simulator launches such a frame directly (no per-frame fingerprint). Default False.
        """
        return False

    def apply_collisions(self, state_in: State, state_out: State, dt: float) -> None:
        """Run each contact handler on the finished step (``state_out`` is corrected in place)."""
        if self.collisions and grad_enabled(self.model) and _tape_active():
            # The handlers correct state_out in place: a tape cannot replay that, and a silently wrong
            # gradient is worse than none.
            raise GradientError(
                f"{type(self).__name__}: contact handlers (collisions=) run in place and cannot be "
                "differentiated; drop them while recording a wp.Tape (the ground is differentiable through "
                "the solver's own contact, colliders through energies.ColliderPenalty with ForceSolver)"
            )
        for c in self.collisions:
            c.apply(self.model, state_in, state_out, dt)

    def graph_blocker(self) -> str | None:
        """Why a frame of this solver cannot be captured as a graph and replayed, or None when it can.

        A step can be replayed when it is kernel launches and device copies only: no host read of a
        residual, no host solve, no grid or BVH rebuilt on the host, no arrays allocated per step. Solvers
        that know they qualify override this; the default keeps every other solver on direct launches.
        """
        return f"{type(self).__name__} does not declare its step replayable"

    def _collisions_blocker(self) -> str | None:
        """The first contact handler's reason not to replay (handlers without ``graph_blocker`` block)."""
        for c in self.collisions:
            blocker = getattr(c, "graph_blocker", None)  # optional: handlers without one block
            why = blocker() if callable(blocker) else "an unknown handler"
            if why is not None:
                return f"contact handler {type(c).__name__}: {why}"
        return None

    def refresh_parameters(self) -> str | None:
        """Take parameter values written in place into the model's arrays (``spring_stiffness``,
        ``tet_mu``, ...) since construction: afterwards the next step reads them, as a solver built on the
        changed model would, and the arrays that captured graphs and recorded launches hold stay the same.

        Returns:
            None when it did (or has nothing to do: its step reads the arrays), else one line saying why this
            solver must be rebuilt to take them (it caches what they give). Default: the reason that this
            solver does not say how; a solver that can overrides this.
        """
        return f"{type(self).__name__} is not known to read the model's parameter arrays in its step"

    def describe(self) -> dict:
        """Name and options, recorded in trajectory metadata and benchmark lines."""
        return {"solver": type(self).__name__}

    def checkpoint_state(self) -> dict[str, np.ndarray]:
        """What this solver keeps from one step to the next, as named host arrays (copies).

        Together with the state's positions and velocities it makes a resumed run continue bit for bit:
        L-BFGS curvature pairs and warm start, a multistep integrator's history. Default: nothing.
        """
        return {}

    def restore_checkpoint_state(self, state: dict[str, np.ndarray]) -> None:
        """Take back what :meth:`checkpoint_state` returned (possibly from another process).

        Raises:
            ValueError: a key this solver does not know, or an array of the wrong shape or dtype.
        """
        if state:
            raise ValueError(
                f"{type(self).__name__} keeps no state between steps, but got {sorted(state)}; "
                "resume with the solver that wrote the checkpoint"
            )
