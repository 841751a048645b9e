"""A live simulation a person can touch: step it, grab a particle and drag it, change the material while it
moves, record what happened. No browser here: :mod:`pliant.live._server` puts a viser page on top, and tests
drive the same methods the mouse does."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from ..integrators import Integrator
    from ..model import Model
    from ..scene import Scene
    from ..solvers import Solver

#: The grab's force cap, in weights of the grabbed object (M |g|): enough to lift and swing it.
GRAB_WEIGHTS = 2.0
#: The cursor distance, as a fraction of the object's size, at which the grab reaches its force cap.
GRAB_REACH = 0.1
#: Explicit updates (force solvers with an explicit integrator, FastMassSpring's external force, XPBD's
#: prediction) take the grab spring explicitly: k h² / m stays below this so the spring alone is stable.
EXPLICIT_LIMIT = 0.25
#: Under explicit force integration the grab's force cap keeps the particle's own step per substep, from
#: rest, at most this fraction of its spacing (see :meth:`LiveSession.grab_spring`).
EXPLICIT_STEP = 0.1


@dataclass
class LiveParameter:
    """A material parameter the live view can scale while the simulation runs.

    Attributes:
        name: ``"stiffness"`` (spring k), ``"E"`` (tets' μ and λ together), ``"compliance"`` (XPBD α),
            ``"damping"`` (spring dashpots γ) or ``"damping_rate"`` (the solver's velocity damping [1/s]).
        doc: What it is, with units.
        arrays: The Warp arrays scaled together (empty for ``damping_rate``, a solver attribute).
        base: Their values when the session started (NumPy copies): a factor multiplies these.
        value: The factor now (1: the scene's values); for ``damping_rate`` the rate itself [1/s].
        lo: Smallest value a slider offers.
        hi: Largest value a slider offers.
        stable: The largest value the scene's own substeps take stably (spring stiffness under an explicit
            step: past it :func:`write_parameter` adds substeps); infinity when any value is.
    """

    name: str
    doc: str
    arrays: list[Any]
    base: list[np.ndarray]
    value: float
    lo: float
    hi: float
    stable: float = float("inf")


def live_parameters(scene: Scene) -> dict[str, LiveParameter]:
    """The knobs of a built scene that :func:`write_parameter` can change: a view of
    :data:`pliant.scene.KNOBS` (those with a ``live`` range). A knob held in per-element arrays (stiffness,
    E, compliance, spring damping) is a factor on the arrays the solver's step reads (the model's, or a
    position-based solver's constraint compliances), over the knob's ``live`` range; one held by the solver
    alone (the velocity damping rate [1/s]) is its value, from the range's floor to max(its ceiling, 4× the
    scene's value).

    Args:
        scene: a built scene (:func:`pliant.scene.build_scene`).

    Returns:
        name → :class:`LiveParameter`, with the arrays' current values as the base the factors scale.
    """
    from ..scene import KNOBS, knob_arrays

    out: dict[str, LiveParameter] = {}
    # Position-based solvers read their constraints' compliances, the others the model's arrays.
    home = "constraints." if getattr(scene.solver, "constraints", None) is not None else "model."
    attr = _damping_attribute(scene.solver)
    for name, k in KNOBS.items():
        if k.live is None:
            continue
        lo, hi = k.live
        if k.section == "solver" and k.per_element is None:  # a solver value, not an array
            if attr is not None:
                rate = float(getattr(scene.solver, attr))
                out[name] = LiveParameter(name, k.doc, [], [], rate, lo, max(hi, 4.0 * rate))
            continue
        # All-zero arrays (a rigid constraint set, no dashpots) are left out: a factor cannot change them.
        arrays = [
            a for key, a in knob_arrays(scene, k).items() if key.startswith(home) and np.any(a.numpy() != 0)
        ]
        if arrays:
            doc = k.per_element[1].replace("log-scale ", "") if k.per_element else f"factor of the {k.doc}"
            out[name] = LiveParameter(name, doc, arrays, [], 1.0, lo, hi)
    if "stiffness" in out and _explicit_springs(scene.solver):
        # Gershgorin's bound is safe, not tight: a scene that runs at 1x is taken as stable there.
        out["stiffness"].stable = max(1.0, _stable_stiffness_factor(scene))
    for p in out.values():
        p.base = [a.numpy().copy() for a in p.arrays]
    return out


def _explicit_springs(solver: Solver) -> bool:
    """Whether ``solver`` applies spring forces explicitly (an explicit integrator, or FastMassSpring's
    symplectic method): then a stiffer spring can cross the step's stability limit."""
    integrator = getattr(solver, "integrator", None)
    if integrator is not None:
        return bool(getattr(integrator, "explicit", False))
    return getattr(solver, "method", None) == "symplectic"


def _stable_stiffness_factor(scene: Scene) -> float:
    """The largest factor on every spring's k that keeps an explicit step of h = frame_dt / substeps stable,
    by Gershgorin's bound on M⁻¹K: λ_max ≤ max_i 2 Σ_j k_ij / m_i, and h² λ_max ≤ 4 (a safe bound: the true
    limit is at or above it)."""
    m = scene.model
    h = scene.substep_dt
    idx = m.spring_indices.numpy().reshape(-1, 2)
    k = m.spring_stiffness.numpy().astype(np.float64)
    ksum = np.bincount(idx.ravel(), weights=np.repeat(k, 2), minlength=m.particle_count)
    free = (m.particle_inv_mass.numpy() > 0) & (ksum > 0)
    if not free.any():
        return float("inf")
    mass = m.particle_mass.numpy().astype(np.float64)
    return float(np.min(2.0 * mass[free] / (h * h * ksum[free])))


def _damping_attribute(solver: Solver) -> str | None:
    """The solver attribute holding its velocity damping rate [1/s]: force solvers' and FastMassSpring's
    ``damping_rate``, XPBD / PBD's ``damping``; None when it has none (or a fixed factor instead)."""
    for attr in ("damping_rate", "damping"):
        rate = getattr(solver, attr, None)
        if isinstance(rate, float | int) and not isinstance(rate, bool):
            return attr
    return None


def write_parameter(session: LiveSession, name: str, value: float) -> None:
    """Set live parameter ``name`` to ``value`` on the running model: the one place the live view writes
    material parameters (a factor on the session's starting arrays, or ``damping_rate`` in 1/s).

    The solver is told (``update_parameters`` / ``reset``: FastMassSpring's factorisation, the lagged
    L-BFGS Hessian), between two frames: the stepping thread holds the session's lock. A stiffness past
    the parameter's ``stable`` value (an explicit step's limit, λ_max ∝ k, h ∝ 1 / substeps) raises the
    substeps per frame to ⌈n₀ √(value / stable)⌉ (n₀: the scene's), and a softer one takes them back down;
    :attr:`LiveSession.note` says so (the frame costs more in proportion).

    Args:
        session: the running session.
        name: a key of :attr:`LiveSession.parameters`.
        value: the factor (or the rate [1/s] for ``damping_rate``), within the parameter's [lo, hi].

    Raises:
        KeyError: a name this scene has no parameter for (the message lists those it has).
        ValueError: a value outside [lo, hi] or not finite.
    """
    p = session.parameters.get(name)
    if p is None:
        raise KeyError(f"no live parameter {name!r} in this scene; it has {', '.join(session.parameters)}")
    value = float(value)
    if not (np.isfinite(value) and p.lo <= value <= p.hi):
        raise ValueError(f"{name}: {value} is outside [{p.lo}, {p.hi}]")
    with session.lock:
        for a, b in zip(p.arrays, p.base, strict=True):
            a.assign((b * value).astype(b.dtype))
        if not p.arrays:  # a solver value (the damping rate)
            attr = _damping_attribute(session.sim.solver)
            assert attr is not None  # a solver value is offered only for a solver that has one
            setattr(session.sim.solver, attr, value)
            arr = getattr(session.sim.solver, "damping_rate_array", None)
            if arr is not None:
                arr.fill_(value)
        p.value = value
        if np.isfinite(p.stable):
            _stable_substeps(session, value / p.stable)
        session.sim._solver_changed()


def _stable_substeps(session: LiveSession, over: float) -> None:
    """Set the substeps per frame for a stiffness ``over`` times the scene's stable one (≤ 1: the scene's
    own), re-tune a held grab to the new step, and say so in ``session.note``."""
    n0 = session.base_substeps
    n = max(n0, int(np.ceil(n0 * np.sqrt(max(over, 0.0)) - 1e-9)))
    if n == session.sim.substeps:
        return
    session.sim.substeps = n
    session.note = (
        f"stiffness past the explicit step's limit: {n} substeps per frame (the scene's {n0}), "
        f"{n / n0:.2g}x the work per frame"
        if n > n0
        else ""
    )
    if session.grabbed is not None and session.target is not None:  # the grab's spring and cap depend on h
        session.control.set_drag(session.grabbed, session.target, *session.grab_spring(session.grabbed))


def _object_ranges(model: Model) -> list[tuple[int, int]]:
    """(start, stop) particle range of each object (the whole model when it lists none)."""
    spans = [(int(o["start"]), int(o["start"]) + int(o["count"])) for o in model.objects or []]
    return spans or [(0, model.particle_count)]


def interactive_integrator(solver: Solver) -> str:
    """Make ``solver`` step with backward Euler when its integrator is implicit but symplectic (the implicit
    midpoint rule); returns a note saying so, or "" when nothing changed.

    Why: the midpoint rule is A-stable but not L-stable. It keeps every mode at its amplitude, the stiff ones
    included, which is right for predicting an observed motion (``pliant twin`` fits and scores with it) but
    not for hands on the object: the grab's spring on one particle and any minimiser step not converged to
    the end ring on at full amplitude, and a capped, non-linear force pumps them up (MuJoCo's beam twin
    diverged 27 frames into a drag, and 35 frames after one with backward Euler during it). Backward Euler
    damps the unresolved modes; the live view is for touching, the twin's ``twin.json`` for predicting.

    Args:
        solver: The live scene's solver (changed in place).
    """
    integrator: Integrator | None = getattr(solver, "integrator", None)  # ForceSolver's; others have none
    if integrator is None or integrator.explicit or not getattr(integrator, "symplectic", False):
        return ""
    from dataclasses import fields

    from ..integrators import BackwardEuler

    # The settings the scene changed are kept; the others stay at their defaults (deprecated ones unset).
    opts = getattr(integrator, "options", None)
    given = [] if opts is None else [(f.name, getattr(opts, f.name), f.default) for f in fields(opts)]
    changed = {name: value for name, value, default in given if value != default}
    setattr(solver, "integrator", BackwardEuler(**changed))  # noqa: B010 - Solver declares no integrator
    return (
        f"live: {integrator.name} keeps stiff modes ringing under a drag; stepping with BackwardEuler "
        "(the scene file is unchanged)"
    )


class LiveSession:
    """A built scene running frame by frame, with a drag handle and recording.

    Every interaction the browser offers is a method here, so a test drives exactly what the mouse does:
    :meth:`pick` (the particle under a click), :meth:`grab` / :meth:`move` / :meth:`release` (the drag,
    through ``Control.set_drag``: a spring to the cursor whose force is capped, so every solver family
    takes it, explicit ones stably), :meth:`step`, :meth:`reset`, :func:`write_parameter`, and
    :meth:`start_recording` / :meth:`stop_recording`.

    Args:
        scene: a built scene (:func:`pliant.scene.build_scene`).
        grab_weights: the grab's force cap in weights of the grabbed object (M |g|).
        grab_reach: the cursor distance, as a fraction of the object's size, where the cap is reached.

    Attributes:
        x: the positions [m] after the last frame, [N, 3] float32 (a host copy, replaced each frame).
        t: the simulated time [s] of ``x`` (0 at the start and after :meth:`reset`): a moving collider is
            drawn where it is then.
        lock: held while a frame is stepped or parameters are written.
        last_event: (wall time [s] of a grab/move, wall time when the first frame that read it finished).
        latencies: drag latencies [s]: for each frame that began after a new grab/move, the time from the
            latest such event to the end of that frame (the positions that follow it).
        base_substeps: the scene's substeps per frame (a stiffness past the explicit limit steps more).
        note: what the session changed on its own ("" when nothing): substeps added for a stiff material.
    """

    def __init__(
        self, scene: Scene, *, grab_weights: float = GRAB_WEIGHTS, grab_reach: float = GRAB_REACH
    ) -> None:
        if not (grab_weights > 0 and grab_reach > 0):
            raise ValueError(f"grab_weights and grab_reach must be > 0, got {grab_weights}, {grab_reach}")
        self.scene = scene
        self.model = scene.model
        self.sim = scene.simulator()
        self.sim.check_initial_state()
        self.control = self.sim.control
        self.lock = threading.RLock()
        self.grab_weights, self.grab_reach = float(grab_weights), float(grab_reach)
        self._x0 = self.sim.state_0.particle_q.numpy().copy()
        self._v0 = self.sim.state_0.particle_qd.numpy().copy()
        self.x = self._x0.astype(np.float32)
        self.t = 0.0
        self._mass = self.model.particle_mass.numpy().astype(np.float64)
        self._inv_mass = self.model.particle_inv_mass.numpy()
        self._ranges = _object_ranges(self.model)
        self.parameters = live_parameters(scene)
        self.grabbed: int | None = None
        self.target: np.ndarray | None = None
        self.last_event: tuple[float, float] | None = None
        self._event_t: float | None = None
        self._measured: float | None = None  # the event whose latency was taken last
        self.latencies: list[float] = []
        self.recording = False
        self.base_substeps = int(self.sim.substeps)
        self.note = interactive_integrator(self.sim.solver)
        self.frame_listeners: list[Callable[[LiveSession], None]] = []

    # ------------------------------------------------------------------ stepping
    @property
    def frame(self) -> int:
        """Frames stepped since the start or the last :meth:`reset`."""
        return self.sim.frame

    def step(self, frames: int = 1) -> np.ndarray:
        """Advance ``frames`` frames (each ``substeps`` solver steps), check them, record them when
        recording; returns the new positions [N, 3] (float32).

        Args:
            frames: how many frames to step.

        Raises:
            pliant.sim.DivergenceError: the simulation blew up (the live view pauses and says so).
        """
        for _ in range(int(frames)):
            with self.lock:
                event = self._event_t
                self.sim.step_frame()
                self.sim.check()
                if self.recording:
                    self.sim._record(False)
                x = self.sim.state_0.particle_q.numpy().astype(np.float32)
                t = float(self.sim.time)
            self.x, self.t = x, t
            if event is not None and event != self._measured:
                # The latest drag event before this frame began: this frame is the first to read it.
                self._measured = event
                done = time.perf_counter()
                self.last_event = (event, done)
                self.latencies.append(done - event)
            for fn in self.frame_listeners:
                fn(self)
        return self.x

    def reset(self) -> None:
        """Back to the scene's initial state (frame 0, t = 0, moving colliders where they were added), letting
        go of any grab; parameters stay as set."""
        with self.lock:
            self.release()
            s = self.sim.state_0
            s.particle_q.assign(self._x0)
            s.particle_qd.assign(self._v0)
            self.sim.frame, self.sim.time = 0, 0.0
            if self.scene.control_fn is not None:
                self.scene.control_fn(0.0, None)  # [[handles]] back to their start
            for handler in getattr(self.sim.solver, "collisions", ()):
                back = getattr(handler, "reset", None)  # moving colliders back to their pose at t = 0
                if callable(back):
                    back()
            self.sim._solver_changed()
            self.x, self.t = self._x0.astype(np.float32), 0.0

    # ------------------------------------------------------------------ grab and drag
    def pick(
        self,
        origin: Any,
        direction: Any,
        *,
        hit: Any = None,
        among: tuple[int, int] | None = None,
    ) -> int | None:
        """The particle a click means: the one nearest the point ``hit`` [m] the click landed on when the
        browser gives it, else the one nearest the ray ``origin + s direction`` (s > 0) — of those within
        1.5 × that distance, the closest to the eye, so a click on a solid takes the near side.

        Args:
            origin: the ray's origin [m] (the camera).
            direction: the ray's direction (any length).
            hit: the world point the ray hit on an object's surface [m], or None.
            among: only particles in [start, stop) (the clicked object), or None for all.

        Returns:
            The particle index, or None when no movable particle lies in front of the eye.
        """
        lo, hi = among if among is not None else (0, self.model.particle_count)
        x = self.x[lo:hi].astype(np.float64)
        free = self._inv_mass[lo:hi] > 0
        if not free.any():
            return None
        if hit is not None:
            d2 = np.sum((x - np.asarray(hit, float)) ** 2, axis=1)
            d2[~free] = np.inf
            return lo + int(np.argmin(d2))
        o = np.asarray(origin, float)
        u = np.asarray(direction, float)
        u = u / max(float(np.linalg.norm(u)), 1e-300)
        rel = x - o
        s = rel @ u
        perp = np.linalg.norm(rel - s[:, None] * u, axis=1)
        ok = free & (s > 0)
        if not ok.any():
            return None
        best = float(perp[ok].min())
        near = ok & (perp <= 1.5 * best + 1e-12)
        cand = np.flatnonzero(near)
        return lo + int(cand[np.argmin(s[cand])])

    def object_of(self, particle: int) -> tuple[int, int]:
        """The (start, stop) particle range of the object holding ``particle`` (a model index)."""
        for lo, hi in self._ranges:
            if lo <= particle < hi:
                return lo, hi
        return 0, self.model.particle_count

    def grab_spring(self, particle: int) -> tuple[float, float]:
        """(stiffness k [N/m], force cap F [N]) of the grab on ``particle``.

        F = ``grab_weights`` × the weight of the particle's object (M |g|, g = 9.81 m/s² in zero gravity);
        k = F / (``grab_reach`` × the object's size), so the cap is reached that far from the cursor. Where
        the spring is taken explicitly (every solver but an implicit integrator's Newton solve), k is also
        held below ``EXPLICIT_LIMIT`` m / h² of the particle (h: the substep), the stability bound of an
        explicit update; and where forces are integrated explicitly (not XPBD / PBD, whose projection
        holds the shape), F is held below ``EXPLICIT_STEP`` m s / h², so that from rest the grab alone
        moves the particle at most ``EXPLICIT_STEP`` of its spacing s (the distance to its nearest
        neighbour) per substep: one node of a heavy solid pulled with its whole weight would invert its
        elements within a step.

        Args:
            particle: the particle's index in the model.
        """
        lo, hi = self.object_of(particle)
        g = float(np.linalg.norm(self.model.gravity)) or 9.81
        mass = float(self._mass[lo:hi].sum())
        span = self._x0[lo:hi]
        size = max(float(np.linalg.norm(span.max(axis=0) - span.min(axis=0))), 1e-3)
        force = self.grab_weights * mass * g
        k = force / (self.grab_reach * size)
        solver = self.sim.solver
        integrator = getattr(solver, "integrator", None)
        position_based = getattr(solver, "constraints", None) is not None
        if position_based or integrator is None or getattr(integrator, "explicit", True):
            h = self.sim.substep_dt
            m_i = float(self._mass[particle])
            k = min(k, EXPLICIT_LIMIT * m_i / (h * h))
            if not position_based:
                d = np.linalg.norm(span - self._x0[particle], axis=1)
                spacing = float(np.min(d[d > 0])) if np.any(d > 0) else size
                force = min(force, EXPLICIT_STEP * m_i * spacing / (h * h))
        return k, force

    def grab(self, particle: int, target: Any = None) -> None:
        """Take hold of ``particle`` (a pinned or kinematic one cannot move: ValueError) and pull it toward
        ``target`` [m] (default: where it is) with the capped spring of :meth:`grab_spring`.

        Args:
            particle: the particle's index in the model.
            target: where the cursor is [m], (3,), or None for the particle's position.
        """
        p = int(particle)
        if not 0 <= p < self.model.particle_count:
            raise ValueError(f"particle {p} out of range [0, {self.model.particle_count})")
        if self._inv_mass[p] == 0:
            raise ValueError(f"particle {p} is pinned or kinematic: grab a free particle")
        k, force = self.grab_spring(p)
        t = self.x[p].astype(float) if target is None else np.asarray(target, float).reshape(3)
        self._check_target(t)
        self._event_t = time.perf_counter()
        self.control.set_drag(p, t, k, force)
        self.grabbed, self.target = p, t

    def move(self, target: Any) -> None:
        """Move the grab's target to ``target`` [m] (the solver reads it at its next substep); no-op when
        nothing is grabbed.

        Args:
            target: the cursor's new position [m], (3,).
        """
        if self.grabbed is None:
            return
        t = np.asarray(target, float).reshape(3)
        self._check_target(t)
        self._event_t = time.perf_counter()
        self.control.drag_target = t  # one rebinding: the stepping thread sees the old or the new target
        self.target = t

    def release(self) -> None:
        """Let go."""
        self.control.release_drag()
        self.grabbed, self.target = None, None

    @staticmethod
    def _check_target(t: np.ndarray) -> None:
        if not np.all(np.isfinite(t)):
            raise ValueError(f"grab target {t} is not finite")

    # ------------------------------------------------------------------ energy
    def kinetic_energy(self) -> float:
        """Σ ½ m |v|² [J] of the current state."""
        v = self.sim.state_0.particle_qd.numpy().astype(np.float64)
        return float(0.5 * np.sum(self._mass * np.sum(v * v, axis=1)))

    # ------------------------------------------------------------------ recording
    def start_recording(self) -> None:
        """Record every frame from now on (the current one first)."""
        with self.lock:
            self.sim._xs.clear()
            self.sim._vs.clear()
            self.sim._ts.clear()
            self.sim._record(False)
            self.recording = True

    def stop_recording(self, path: str | Path, *, video: bool = True) -> list[Path]:
        """Stop recording and write ``path`` (a ``.npz`` trajectory that ``pliant view`` and ``pliant export``
        read, with the objects, colliders and ground) and, with ``video``, the ``.mp4`` beside it drawn by
        pliant's renderer with the scene's camera.

        Args:
            path: the trajectory file (``.npz`` is added when missing); its folder is created.
            video: also render the ``.mp4``.

        Returns:
            The files written.

        Raises:
            ValueError: nothing was recorded (call :meth:`start_recording` first).
        """
        with self.lock:
            if not self.recording and not self.sim._xs:
                raise ValueError("nothing recorded: start_recording() first")
            self.recording = False
            traj = self.sim.trajectory()
        traj.meta.update(scene_trajectory_meta(self.scene))
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_suffix(".npz")
        path.parent.mkdir(parents=True, exist_ok=True)
        written = [traj.save(path)]
        if video and traj.frame_count > 1:
            from ..render import render_video

            m = self.model
            xr, fr, colors = self.scene.render_mesh(traj.x, traj.faces, traj.t)
            mp4 = path.with_suffix(".mp4")
            render_video(
                xr,
                mp4,
                faces=fr,
                colors=colors,
                fps=1.0 / self.sim.frame_dt,
                camera=self.scene.camera,
                progress=False,
                ground=m.ground.height if m.ground is not None else False,
            )
            written.append(mp4)
        return [Path(w) for w in written]


def scene_trajectory_meta(scene: Scene) -> dict[str, Any]:
    """What a saved trajectory carries beside the simulator's meta so that ``pliant view`` and
    ``pliant export`` draw the whole scene: its name, the ground height (None without one) and the drawn
    colliders (points and faces).

    Args:
        scene: a built scene (:func:`pliant.scene.build_scene`).
    """
    return scene.trajectory_meta()
