"""Checkpoints of a :class:`~pliant.sim.Simulator`: the last good state, its time, the fitted parameters,
the solver's state between steps and the recorded frames, written atomically and resumed bit for bit."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from ..io import CheckpointError, CheckpointSpec, Trajectory, load_checkpoint, save_checkpoint

if TYPE_CHECKING:
    from ..model import Model, State
    from ..solvers import Solver

#: Model parameters that fitting may change; checkpoints carry them so a resumed run is the same run.
_PARAMS = (
    "spring_stiffness",
    "spring_rest_length",
    "spring_damping",
    "tet_mu",
    "tet_lam",
    "bending_stiffness",
)


_HANDLER = re.compile(r"handler(\d+)_(.+)")


def solver_and_handler_state(solver: Solver) -> dict[str, np.ndarray]:
    """The solver's state between steps, plus each contact handler's (a moving collider's pose) under
    ``handler<k>_<name>`` (k: its index in ``solver.collisions``)."""
    out = dict(solver.checkpoint_state())
    for k, c in enumerate(getattr(solver, "collisions", ())):
        own = getattr(c, "checkpoint_state", None)
        if callable(own):
            out.update({f"handler{k}_{name}": a for name, a in own().items()})
    return out


def restore_solver_and_handlers(solver: Solver, state: dict[str, np.ndarray]) -> None:
    """Give :func:`solver_and_handler_state`'s arrays back to the solver and its handlers (ValueError for
    a key no one takes)."""
    handlers = list(getattr(solver, "collisions", ()))
    per: dict[int, dict[str, np.ndarray]] = {}
    rest = {}
    for key, a in state.items():
        hit = _HANDLER.fullmatch(key)
        if hit is None:
            rest[key] = a
            continue
        k = int(hit.group(1))
        if k >= len(handlers) or not callable(getattr(handlers[k], "restore_checkpoint_state", None)):
            raise ValueError(
                f"{key}: no contact handler {k} that keeps a state; resume with the same collisions"
            )
        per.setdefault(k, {})[hit.group(2)] = a
    solver.restore_checkpoint_state(rest)
    for k, d in per.items():
        handlers[k].restore_checkpoint_state(d)


class Checkpoints:
    """The checkpoint half of :class:`~pliant.sim.Simulator` (a mixin: it reads and sets the simulator's
    state, records and worlds, declared here for the type checker)."""

    model: Model
    solver: Solver
    frame_dt: float
    frame: int
    time: float
    state_0: State
    _last_good: tuple[int, float, np.ndarray, np.ndarray] | None
    _solver_state: dict[str, np.ndarray]
    _record_velocity: bool
    _xs: list[np.ndarray]
    _vs: list[np.ndarray]
    _ts: list[float]
    _per_world: bool
    diverged_worlds: dict[int, dict]
    world_resets: list[tuple[int, int]]
    #: What the run that writes a checkpoint is (``pl.run_scene``: a hash of its scene but the frame count
    #: and outputs), stored in the checkpoint's meta; a resume whose tag differs is refused. None: untagged.
    checkpoint_tag: str | None = None

    if TYPE_CHECKING:  # the Simulator's methods these call

        def trajectory(self) -> Trajectory: ...
        def _freeze(self, inv: np.ndarray, w: int) -> slice: ...
        def _solver_changed(self) -> None: ...

    def _params(self) -> dict[str, Any]:
        """The model's parameter arrays a checkpoint carries (the whitelist, only those the model has)."""
        m = self.model
        return {k: getattr(m, k) for k in _PARAMS if isinstance(getattr(m, k, None), wp.array)}

    def save_checkpoint(self, path: str | os.PathLike) -> Path:
        """Write the last recorded state, its time, fitted parameters, the solver's state between steps
        (``Solver.checkpoint_state``) and the trajectory, atomically."""
        traj = self.trajectory()
        params = {k: a.numpy() for k, a in self._params().items()}
        if self._last_good is None:
            raise ValueError("nothing to checkpoint yet: run at least frame 0 first")
        frame, time, x, v = self._last_good
        return save_checkpoint(
            path,
            frame=frame,
            time=time,
            x=x,
            v=v,
            params=params,
            traj_x=traj.x,
            traj_t=traj.t,
            traj_v=traj.v,
            meta={**traj.meta, "run": self.checkpoint_tag} if self.checkpoint_tag else traj.meta,
            solver_state=self._solver_state,
        )

    def load_checkpoint(self, path: str | os.PathLike, *, max_frame: int | None = None) -> None:
        """Continue from a checkpoint: state, time, parameters, solver state and the recorded frames.

        The file is validated against this simulator first (known keys, shapes and dtypes of the model,
        ``frame`` in [0, ``max_frame``], the frame duration); nothing changes unless it all holds.

        Raises:
            CheckpointError: what is wrong, naming the file and the key.
        """
        m = self.model
        spec = CheckpointSpec(
            particle_count=m.particle_count,
            dtype=m.dtype,
            params={k: tuple(a.shape) for k, a in self._params().items()},
            max_frame=max_frame,
        )
        ck = load_checkpoint(path, spec)
        tag = ck["meta"].get("run")
        if self.checkpoint_tag and tag is not None and tag != self.checkpoint_tag:
            raise CheckpointError(
                f"{path}: the checkpoint is from another scene or other settings (objects, materials, "
                "solver, substeps, ...) than this run; resume with the ones that wrote it, or delete it to "
                "start over"
            )
        if not np.isclose(ck["time"], ck["frame"] * self.frame_dt, rtol=1e-9, atol=0.0):
            raise CheckpointError(
                f"{path}: time: {ck['time']} s at frame {ck['frame']} is not frame x frame_dt = "
                f"{ck['frame'] * self.frame_dt} s; resume with the frame duration (frame_dt) that wrote the "
                "checkpoint"
            )
        if ck["traj_v"] is None and self._record_velocity and ck["frame"] > 0:
            raise CheckpointError(
                f"{path}: traj_v: missing, but this run records velocities; resume with the same "
                "record_velocity setting"
            )
        try:
            restore_solver_and_handlers(self.solver, ck["solver_state"])
        except CheckpointError:
            raise
        except Exception as exc:  # whatever a foreign or corrupt solver_ array makes the solver raise
            raise CheckpointError(
                f"{path}: solver state: {exc}; resume with the solver that wrote the checkpoint, or "
                "delete it to start over"
            ) from None
        for k, a in ck["params"].items():
            getattr(m, k).assign(a)
        self.state_0.particle_q.assign(ck["x"])
        self.state_0.particle_qd.assign(ck["v"])
        self.frame = ck["frame"]
        self.time = self.frame * self.frame_dt  # as step_frame computes it, so control_fn sees the same times
        self._last_good = (ck["frame"], self.time, ck["x"], ck["v"])
        self._solver_state = dict(ck["solver_state"])
        self._xs = list(ck["traj_x"])
        self._ts = list(ck["traj_t"])
        # Velocities only when this run records them too (else the trajectory's v would stop short of x).
        self._vs = list(ck["traj_v"]) if ck["traj_v"] is not None and self._record_velocity else []
        self._restore_worlds(ck["meta"].get("worlds", {}), path)

    def _restore_worlds(self, worlds: dict, path: str | os.PathLike) -> None:
        """Freeze again the worlds a checkpoint lists as diverged (as the run that wrote it had them)."""
        m = self.model
        try:
            diverged = {int(w): dict(d) for w, d in worlds.get("diverged", {}).items()}
            diverged = diverged if self._per_world else {}
            resets = [(int(f), int(w)) for f, w in worlds.get("resets", [])]
            for w in [*diverged, *(w for _, w in resets)]:
                m.world_slice("particle", w)
        except (ValueError, TypeError, AttributeError) as exc:
            raise CheckpointError(f"{path}: worlds: {exc}; resume with the scene that wrote it") from None
        self.diverged_worlds, self.world_resets = diverged, resets
        if diverged:
            inv = m.particle_inv_mass.numpy()
            for w in diverged:
                self._freeze(inv, w)
            m.particle_inv_mass.assign(inv)
            self._solver_changed()
