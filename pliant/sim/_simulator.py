"""Simulator: frames × substeps, recording, divergence detection, checkpoints and resume."""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import warp as wp

from .._time import substep_dt
from ..io import Trajectory
from ..model import Control, Model, State, write_range
from ..solvers import FrameStep, Solver
from ._checkpoints import Checkpoints, solver_and_handler_state
from ._divergence import DivergenceError, stability_advice
from ._graph import FrameGraphs

#: ``graph_reason`` of a frame that is one launch (``Solver.frame_is_one_launch``): launched directly.
_ONE_LAUNCH = "the frame is one fused launch (a graph would save nothing)"
#: Reasons already reported for running without a CUDA graph (each is reported once per process).
_REPORTED: set[str] = set()


@wp.kernel
def _health(
    v: wp.array(dtype=Any),
    x: wp.array(dtype=Any),
    x_start: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=Any),
    stats_out: wp.array(dtype=Any),
):
    # stats: [0] max |v|², [1] max |x − x_start|² over the frame, [2] count of non-finite particles,
    # [3], [4]: [0] and [1] over kinematic and pinned particles only (inverse mass 0: handles).
    i = wp.tid()
    s = wp.dot(v[i], v[i])
    p = wp.dot(x[i], x[i])
    d = x[i] - x_start[i]
    dd = wp.dot(d, d)
    if wp.isnan(s) or wp.isinf(s) or wp.isnan(p) or wp.isinf(p):
        wp.atomic_add(stats_out, 2, type(s)(1.0))
    else:
        wp.atomic_max(stats_out, 0, s)
        wp.atomic_max(stats_out, 1, dd)
        if inv_mass[i] == type(s)(0.0):
            wp.atomic_max(stats_out, 3, s)
            wp.atomic_max(stats_out, 4, dd)


@wp.kernel
def _health_worlds(
    v: wp.array(dtype=Any),
    x: wp.array(dtype=Any),
    x_start: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=Any),
    particle_world: wp.array(dtype=wp.int32),
    stats_out: wp.array2d(dtype=Any),
):
    # Per world w: [w, 0] max |v|², [w, 1] max |x − x_start|² over the frame, [w, 2] non-finite particles,
    # of the moving particles (inverse mass > 0: handles are checked by _health, for the whole model).
    i = wp.tid()
    if inv_mass[i] == inv_mass[i] * type(inv_mass[i])(0.0):
        return
    w = particle_world[i]
    s = wp.dot(v[i], v[i])
    p = wp.dot(x[i], x[i])
    d = x[i] - x_start[i]
    if wp.isnan(s) or wp.isinf(s) or wp.isnan(p) or wp.isinf(p):
        wp.atomic_add(stats_out, w, 2, type(s)(1.0))
    else:
        wp.atomic_max(stats_out, w, 0, s)
        wp.atomic_max(stats_out, w, 1, wp.dot(d, d))


class Simulator(Checkpoints):
    """Owns model, solver, two states and the control; runs frames of ``substeps`` solver steps.

    Args:
        model: the Model.
        solver: any Solver.
        frame_dt: frame duration [s] (the recording interval). The solver's step size is
            ``frame_dt / substeps``: "dt" in pliant's solvers always means that step.
        substeps: solver steps per frame (substep Δt = frame_dt / substeps).
        control: a Control (default ``model.control()``).
        max_speed: divergence bound on any particle speed [m/s]: on the velocity array and on the frame's
            displacement divided by ``frame_dt`` (so colliders and handles that teleport particles count too).
        control_fn: optional ``f(t, control)`` called before each frame to move kinematic targets [s].
        dt: deprecated name of ``frame_dt`` (a DeprecationWarning says so).
        per_world_divergence: with several worlds (:meth:`pliant.ModelBuilder.replicate`), a world that
            diverges is frozen at its last good frame (velocities 0, inverse masses 0) and listed in
            :attr:`diverged_worlds` while the others run on; only when every world has diverged does the run
            raise. False: any divergence raises, as with one world. Worlds stay independent under
            explicit solvers and XPBD; an implicit solve shares one linear system, so a non-finite world
            can spoil the others within that step.
        graph: replay each frame as a captured graph (CUDA graphs; Warp's CPU graphs on the CPU) when the
            solver allows it. None (default): whenever it does (``graph_reason`` says why not otherwise)
            and a frame is more than one launch (``Solver.frame_is_one_launch``: a graph of one launch
            saves nothing, and its per-frame fingerprint would cost as much as the frame); True: require it
            (ValueError with the reason if the solver cannot; a one-launch frame is then replayed too);
            False: launch by launch.
            ``PLIANT_GRAPH=0`` in the environment turns the automatic choice off for a whole command.

    Example::

        sim = pl.Simulator(model, solver, frame_dt=1 / 60, substeps=16)
        traj = sim.run(frames=240)
    """

    def __init__(
        self,
        model: Model,
        solver: Solver,
        *,
        frame_dt: float | None = None,
        substeps: int = 16,
        control: Control | None = None,
        max_speed: float = 1.0e3,
        control_fn: Callable[[float, Control], None] | None = None,
        dt: float | None = None,
        per_world_divergence: bool = True,
        graph: bool | None = None,
    ) -> None:
        if dt is not None:
            if frame_dt is not None:
                raise TypeError("Simulator: give frame_dt only (dt is its deprecated name)")
            warnings.warn(
                "Simulator(dt=...) is deprecated: the frame duration is frame_dt=... (dt is the solver's "
                "step size everywhere else)",
                DeprecationWarning,
                stacklevel=2,
            )
            frame_dt = dt
        frame_dt = 1.0 / 60.0 if frame_dt is None else frame_dt
        if not (frame_dt > 0 and np.isfinite(frame_dt)):
            raise ValueError(f"frame_dt must be a positive number of seconds, got {frame_dt}")
        if substeps < 1:
            raise ValueError(f"substeps must be >= 1, got {substeps}")
        if not max_speed > 0:
            raise ValueError(f"max_speed must be a positive speed [m/s], got {max_speed}")
        self.model, self.solver = model, solver
        self.frame_dt, self.substeps = float(frame_dt), int(substeps)
        self._frame_step: FrameStep | None = None  # one frame's substeps as one callable
        self.control = control if control is not None else model.control()
        self.control_fn = control_fn
        self.max_speed = float(max_speed)
        self.state_0: State = model.state()
        self.state_1: State = model.state()
        # The two buffers in their first order and whether the control is this simulator's own: what
        # restart() puts back (a captured graph is keyed by the buffers, so they are reused, not replaced).
        self._buffers = (self.state_0, self.state_1)
        self._own_control = control is None
        self.frame = 0
        self.time = 0.0
        self._xs: list[np.ndarray] = []
        self._vs: list[np.ndarray] = []
        self._ts: list[float] = []
        self._stats = wp.zeros(5, dtype=model.scalar, device=model.device)
        # Positions at the start of the current frame: the displacement check's reference.
        self._x_start = wp.clone(self.state_0.particle_q)
        self._last_good: tuple[int, float, np.ndarray, np.ndarray] | None = None
        self._solver_state: dict[str, np.ndarray] = {}
        self._record_velocity = False
        self._snapshot_solver = False  # copy the solver's state at each recorded frame (for checkpoints)
        self._warned_newton = False
        #: Worlds frozen after diverging: world → {"frame", "quantity", "value"}.
        self.diverged_worlds: dict[int, dict] = {}
        #: (frame, world) of every :meth:`reset_world`, in order.
        self.world_resets: list[tuple[int, int]] = []
        self._frozen_inv: dict[int, np.ndarray] = {}  # a frozen world's inverse masses before freezing
        self._per_world = per_world_divergence and model.world_count > 1
        if self._per_world:
            self._particle_world: wp.array = wp.array(
                model.particle_world(), dtype=wp.int32, device=model.device
            )
            self._world_stats = wp.zeros((model.world_count, 3), dtype=model.scalar, device=model.device)
        self._graphs: FrameGraphs | None = None
        #: Why frames run launch by launch instead of as a replayed graph (None while graphs are used).
        self.graph_reason: str | None = None
        self.set_graph(graph)

    def set_graph(self, graph: bool | None) -> None:
        """Choose how frames run: replayed graphs when the solver allows (None), required (True; ValueError
        with the reason when the solver cannot), or launch by launch (False). See ``graph`` in the class."""
        if graph is not None and not isinstance(graph, bool):
            raise TypeError(f"graph must be True, False or None (automatic), got {graph!r}")
        if graph is None and os.environ.get("PLIANT_GRAPH", "1") == "0":
            graph = False  # the environment switch for a whole command (comparing, troubleshooting)
        why = "graph=False" if graph is False else self.solver.graph_blocker()
        if why is not None and graph:
            raise ValueError(f"graph=True: a frame cannot be replayed as a graph: {why}; pass graph=None")
        self.graph_reason = why
        self._graph_required = graph is True  # a one-launch frame is captured only when asked to be
        # Kept unless graphs are off: the solver's options can change between frames (an XPBD tolerance
        # set later), so step_frame asks graph_blocker() again each frame.
        self._graphs = FrameGraphs(self.model.device) if graph is not False else None
        if (
            why is not None
            and graph is None
            and wp.get_device(self.model.device).is_cuda
            and why not in _REPORTED
        ):
            _REPORTED.add(why)  # once per reason and process: on CUDA a graph is the expected path
            warnings.warn(f"pliant: frames run launch by launch (no CUDA graph): {why}", RuntimeWarning, 2)

    @property
    def dt(self) -> float:
        """Deprecated name of :attr:`frame_dt` (the frame duration [s]); the step is :attr:`substep_dt`."""
        msg = "Simulator.dt is deprecated; use Simulator.frame_dt (the frame [s]) or .substep_dt (the step)"
        warnings.warn(msg, DeprecationWarning, stacklevel=2)
        return self.frame_dt

    @property
    def substep_dt(self) -> float:
        """The solver's step ``dt`` [s]: ``frame_dt / substeps`` (:func:`pliant._time.substep_dt`)."""
        return substep_dt(self.frame_dt, self.substeps)

    # ------------------------------------------------------------------ stepping
    def step_frame(self) -> None:
        """Advance one frame (``substeps`` solver steps, :class:`pliant.solvers.FrameStep`); no host
        synchronisation.

        When the solver allows it (``Solver.graph_blocker``), the frame's launches are captured once as a
        graph and replayed (:mod:`pliant.sim._graph`): the same launches, bit for bit, without their Python
        cost. ``graph_reason`` says why a simulator runs launch by launch.
        """
        wp.copy(self._x_start, self.state_0.particle_q)
        if self.control_fn is not None:
            self.control_fn(self.time, self.control)
        h = self.substep_dt
        fs = self._frame_step
        if fs is None or (fs.solver, fs.dt, fs.substeps) != (self.solver, h, self.substeps):
            fs = self._frame_step = FrameStep(self.solver, h, self.substeps)  # settings changed: rebuild

        def frame(states: tuple[State, State]) -> tuple[State, State]:
            return fs(states[0], self.control, states[1])

        states = (self.state_0, self.state_1)
        if self._graphs is not None:
            self.graph_reason = self.solver.graph_blocker()
            if self.graph_reason is None and not self._graph_required and self.solver.frame_is_one_launch():
                self.graph_reason = _ONE_LAUNCH
        if self._graphs is not None and self.graph_reason is None:
            # Δt and the substep count are part of what a graph bakes in: they join the fingerprint.
            states = self._graphs.run(frame, states, (self.solver, self.control, fs.dt, fs.substeps))
            if self._graphs.failed is not None:
                self.graph_reason, self._graphs = self._graphs.failed, None
        else:
            states = frame(states)
        self.state_0, self.state_1 = states
        self.frame += 1
        self.time = self.frame * self.frame_dt

    def check_initial_state(self) -> None:
        """Frame 0 is checked like every other: raise :class:`DivergenceError` (frame 0) if the current
        state is already non-finite (e.g. an origin that overflows float32) or moves faster than
        ``max_speed``."""
        wp.copy(self._x_start, self.state_0.particle_q)
        self.check()

    def check(self) -> None:
        """Raise :class:`DivergenceError` if any value is non-finite or a speed exceeds ``max_speed``.

        Two speeds are bounded: the velocity array's, and the frame's displacement divided by ``frame_dt``
        (what a collider or handle that teleports particles produces without touching the velocities). One
        host read per call.
        """
        self._stats.zero_()
        s = self.state_0
        wp.launch(
            _health,
            self.model.particle_count,
            [s.particle_qd, s.particle_q, self._x_start, self.model.particle_inv_mass, self._stats],
            device=self.model.device,
        )
        speed2, disp2, bad, kin_speed2, kin_disp2 = (float(a) for a in self._stats.numpy())
        if self._per_world and self.frame > 0:
            speed2, disp2, bad = self._check_worlds(speed2, disp2, bad)
        advice = stability_advice(self.solver, self.substep_dt, self.substeps)
        if bad:
            if self.frame == 0:
                raise DivergenceError(
                    0,
                    "non-finite initial positions/velocities in particles:",
                    bad,
                    "the initial state overflows the model's dtype or is NaN: check the objects' origin, "
                    "size and velocity (float32 holds |x| < 3.4e38), or use dtype float64",
                )
            raise DivergenceError(self.frame, "non-finite positions/velocities in particles:", bad, advice)
        stats = getattr(self.solver, "last_stats", None)
        if stats is not None and getattr(stats, "converged", True) is False and not self._warned_newton:
            # Not fatal (the state is finite), but the motion is not backward Euler's: say so once per run.
            self._warned_newton = True
            if getattr(stats, "linear_solver", "") == "lbfgs":
                what, fix = "L-BFGS", "raise lbfgs_max_iterations, use method='newton', or add substeps"
            else:
                what, fix = "Newton", "raise max_newton_iterations, keep project_psd=True, or add substeps"
            warnings.warn(
                f"{what} did not converge at frame {self.frame} (gradient {stats.gradient_norm:.3g} m/s "
                f"after {stats.iterations} iterations); {fix}",
                RuntimeWarning,
                stacklevel=2,
            )
        kin = max(float(np.sqrt(kin_speed2)), float(np.sqrt(kin_disp2)) / self.frame_dt)
        if kin > self.max_speed:
            # Checked first: the motion is prescribed, so the solver's step size is not the cause.
            raise DivergenceError(
                self.frame,
                "max speed of a handle or kinematic particle (m/s)",
                kin,
                "a handle's path or velocity moves its particles faster than max_speed: slow the handle "
                "(its path's times or velocity), or raise max_speed if such speeds are meant",
            )
        speed = float(np.sqrt(speed2))
        if speed > self.max_speed:
            raise DivergenceError(self.frame, "max speed (m/s)", speed, advice)
        jump = float(np.sqrt(disp2)) / self.frame_dt
        if jump > self.max_speed:
            raise DivergenceError(
                self.frame,
                "max displacement speed (m/s, displacement over the frame / frame_dt)",
                jump,
                "a particle moved farther in one frame than max_speed allows: a collider that encloses or "
                "jumps onto the body, a handle or kinematic target moving faster than max_speed, or an "
                f"unstable step ({advice}); raise max_speed only if such speeds are meant",
            )

    def _check_worlds(self, speed2: float, disp2: float, bad: float) -> tuple[float, float, float]:
        """Freeze each world that is non-finite or too fast at its last recorded frame; return the whole
        model's figures over the worlds that remain (what :meth:`check` goes on to judge)."""
        m = self.model
        limit2 = self.max_speed**2
        if bad == 0 and speed2 <= limit2 and disp2 <= limit2 * self.frame_dt**2:
            return speed2, disp2, bad
        self._world_stats.zero_()
        s = self.state_0
        wp.launch(
            _health_worlds,
            m.particle_count,
            [s.particle_qd, s.particle_q, self._x_start, m.particle_inv_mass, self._particle_world],
            outputs=[self._world_stats],
            device=m.device,
        )
        stats = self._world_stats.numpy()
        failing = []
        for w in range(m.world_count):
            if w in self.diverged_worlds:
                continue
            v2, d2, nonfinite = (float(a) for a in stats[w])
            if nonfinite:
                failing.append((w, "non-finite positions/velocities in particles:", nonfinite))
            elif v2 > limit2:
                failing.append((w, "max speed (m/s)", v2**0.5))
            elif d2 > limit2 * self.frame_dt**2:
                failing.append((w, "max displacement speed (m/s)", d2**0.5 / self.frame_dt))
        if len(failing) + len(self.diverged_worlds) >= m.world_count:
            return speed2, disp2, bad  # every world is gone: check() raises as for one world
        x = self.state_0.particle_q.numpy()
        v = self.state_0.particle_qd.numpy()
        inv = m.particle_inv_mass.numpy()
        last = self._xs[-1]
        for w, quantity, value in failing:
            sl = self._freeze(inv, w)
            x[sl], v[sl] = last[sl], 0.0
            self.diverged_worlds[w] = {"frame": self.frame, "quantity": quantity, "value": float(value)}
            warnings.warn(
                f"world {w} diverged at frame {self.frame} ({quantity} {value:.3g}); it is frozen at frame "
                f"{self.frame - 1} and the other worlds run on",
                RuntimeWarning,
                stacklevel=3,
            )
        self.state_0.particle_q.assign(x)
        self.state_0.particle_qd.assign(v)
        m.particle_inv_mass.assign(inv)
        self._solver_changed()
        # The remaining worlds' figures: the largest over the worlds still running.
        alive = [w for w in range(m.world_count) if w not in self.diverged_worlds]
        return float(stats[alive, 0].max()), float(stats[alive, 1].max()), float(stats[alive, 2].sum())

    def _freeze(self, inv: np.ndarray, w: int) -> slice:
        """Zero world ``w``'s inverse masses in the host copy ``inv``, keeping them for a thaw
        (:meth:`reset_world`); returns the world's particle range."""
        sl = self.model.world_slice("particle", w)
        self._frozen_inv[w] = inv[sl].copy()
        inv[sl] = 0.0
        return sl

    def _solver_changed(self) -> None:
        """Tell the solver the model's masses or a world's state changed under it."""
        for hook in ("update_parameters", "reset"):  # solvers that cached masses or curvature
            fn = getattr(self.solver, hook, None)
            if callable(fn):
                fn()
        if self._graphs is not None:
            self._graphs.clear()  # the hooks may have rebuilt what a graph baked in

    def reset_world(self, w: int) -> None:
        """Put world ``w`` back to the model's initial positions and velocities (``Model.set_world_state``
        sets them); the other worlds' states are untouched. A world frozen after diverging is thawed
        (its inverse masses restored, removed from :attr:`diverged_worlds`), so change its parameters
        first (``Model.set_world_parameter``) to run it again differently. Recorded with the frame in
        :attr:`world_resets` and the trajectory's ``meta["worlds"]["resets"]``.

        Solver history is shared by all worlds: solvers that carry some between steps (L-BFGS curvature
        pairs and warm start, BDF2's previous state) forget it for every world (``Solver.reset``), so under
        those the other worlds' next step starts like a first step and is no longer bit-identical to an
        uninterrupted run. Explicit solvers and XPBD keep none: the other worlds go on exactly as if
        nothing happened (tested bit for bit).

        Args:
            w: world index in [0, model.world_count).

        Raises:
            ValueError: ``w`` out of range.
        """
        m = self.model
        sl = m.world_slice("particle", w)
        m.reset_world(self.state_0, w)
        frozen = self._frozen_inv.pop(int(w), None)
        if frozen is not None:
            write_range(m.particle_inv_mass, sl, frozen, m.dtype)
            self.diverged_worlds.pop(int(w), None)
        self.world_resets.append((self.frame, int(w)))
        self._solver_changed()

    def restart(self) -> None:
        """Start over from frame 0: the model's initial positions and velocities, no recorded frames, no
        diverged or reset worlds, the solver's history forgotten (``Solver.reset``), a control this
        simulator made itself back at rest, while the captured frame graphs are kept.

        A run after ``restart()`` is the run a new Simulator of the same model and solver would make, bit
        for bit, but replays from its first frame (no direct frame, no capture): what the CMA-ES stage does
        with one batched scene across generations after writing new parameters into the model's arrays in
        place (``pliant.fit._reuse``). The states are written in place, so a graph's baked-in addresses
        stay valid; what the fingerprint cannot see must not change between runs (a solver that caches
        values derived from the model arrays, see :class:`~pliant.sim._graph.FrameGraphs`).
        """
        m = self.model
        for s in self._buffers:
            wp.copy(s.particle_q, m.particle_q)
            wp.copy(s.particle_qd, m.particle_qd)
        self.state_0, self.state_1 = self._buffers
        if self._own_control:
            c, fresh = self.control, m.control()
            wp.copy(c.particle_f, fresh.particle_f)
            wp.copy(c.kinematic_targets, fresh.kinematic_targets)
            c.drag_index, c.drag_target = fresh.drag_index, fresh.drag_target
            c.drag_stiffness, c.drag_max_force = fresh.drag_stiffness, fresh.drag_max_force
        if self._frozen_inv:
            inv = m.particle_inv_mass.numpy()
            for w, frozen in self._frozen_inv.items():
                inv[m.world_slice("particle", w)] = frozen
            m.particle_inv_mass.assign(inv)
        self._frozen_inv, self.diverged_worlds, self.world_resets = {}, {}, []
        reset = getattr(self.solver, "reset", None)
        if callable(reset):
            reset()  # history only (L-BFGS pairs, BDF2's past): set-up and arrays stay where graphs see them
        for handler in getattr(self.solver, "collisions", ()):
            back = getattr(handler, "reset", None)  # moving colliders: back to their pose at t = 0, in place
            if callable(back):
                back()
        self.frame, self.time = 0, 0.0
        self._xs, self._vs, self._ts = [], [], []
        self._last_good, self._solver_state = None, {}
        self._warned_newton = False

    # ------------------------------------------------------------------ recording
    def _record(self, with_velocity: bool) -> None:
        x = self.state_0.particle_q.numpy().copy()
        v = self.state_0.particle_qd.numpy().copy()
        self._xs.append(x)
        if with_velocity:
            self._vs.append(v)
        self._ts.append(self.time)
        # The last state that passed its check: what a checkpoint stores, whatever happens next, with the
        # solver's state between steps at that point (L-BFGS history, a multistep integrator's past).
        self._last_good = (self.frame, self.time, x, v)
        if self._snapshot_solver:
            self._solver_state = solver_and_handler_state(self.solver)

    def trajectory(self) -> Trajectory:
        """Everything recorded so far (frame 0 included) as a :class:`Trajectory`."""
        m = self.model
        x = np.stack(self._xs) if self._xs else np.zeros((0, m.particle_count, 3))
        v = np.stack(self._vs) if self._vs else None
        faces = m.render_faces if m.render_faces.size else None
        tets = m.tet_indices_np if m.tet_indices_np.size else None
        meta = {
            "frame_dt": self.frame_dt,
            "substeps": self.substeps,
            "dtype": m.dtype,
            "device": m.device,
            **self.solver.describe(),
            "objects": m.objects,
        }
        if m.world_count > 1 and m.world_offsets is not None:  # replicate() sets both
            meta["worlds"] = {
                "count": m.world_count,
                "particle_offsets": [int(o) for o in m.world_offsets["particle"]],
                "diverged": {str(w): d for w, d in self.diverged_worlds.items()},
                "resets": [list(r) for r in self.world_resets],
            }
        return Trajectory(x=x, t=np.asarray(self._ts), v=v, faces=faces, tets=tets, meta=meta)

    # ------------------------------------------------------------------ the loop
    def run(
        self,
        frames: int,
        *,
        progress: bool = True,
        record_velocity: bool = False,
        checkpoint: str | os.PathLike | None = None,
        checkpoint_every: int = 50,
        resume: bool = False,
        on_frame: Callable[[Simulator], None] | None = None,
    ) -> Trajectory:
        """Run until ``frames`` frames exist after frame 0, recording each; returns the trajectory.

        With ``checkpoint``, state is saved every ``checkpoint_every`` frames and when the run stops for any
        reason (Ctrl-C, divergence, an exception), so nothing computed is lost; ``resume=True`` continues
        from that file bit-identically on the CPU.
        """
        if frames < 0:
            raise ValueError(f"frames must be >= 0, got {frames}")
        self._record_velocity = record_velocity
        self._snapshot_solver = checkpoint is not None
        if resume:
            if checkpoint is None or not Path(checkpoint).exists():
                raise FileNotFoundError(f"--resume needs an existing checkpoint, none at {checkpoint}")
            self.load_checkpoint(checkpoint, max_frame=frames)
        if not self._xs:
            self.check_initial_state()
            self._record(record_velocity)
        bar = None
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(
                total=frames,
                initial=min(self.frame, frames),
                unit="frame",
                desc="simulating",
                leave=False,
                dynamic_ncols=True,
            )
        try:
            while self.frame < frames:
                self.step_frame()
                self.check()
                self._record(record_velocity)
                if on_frame is not None:
                    on_frame(self)
                if bar is not None:
                    bar.update(1)
                if checkpoint is not None and checkpoint_every > 0 and self.frame % checkpoint_every == 0:
                    self.save_checkpoint(checkpoint)
        finally:
            if bar is not None:
                bar.close()
            if checkpoint is not None and self._last_good is not None:
                # On Ctrl-C or divergence this holds the last frame that passed its check.
                self.save_checkpoint(checkpoint)
        return self.trajectory()
