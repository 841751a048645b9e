"""XPBD and PBD: the lecture's Algorithm 1 with compliant (XPBD) or stiffness-scaled (PBD) projections."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import warp as wp

from ..._warp import GradientError
from ...constraints import Constraint, DihedralBending, Distance, Ground, ProjectionContext, Volume
from ...model import Control, Model, State
from .._base import Solver
from . import _kernels as K
from . import _tolerance as T

_SCHEDULES = ("jacobi", "coloring")
_JACOBI_MODES = ("average", "sum")


class XPBD(Solver):
    """Extended position-based dynamics (Macklin, Müller, Chentanez, "XPBD: position-based simulation of
    compliant constrained dynamics", MIG 2016) in the loop of the lecture's Algorithm 1.

    Per step: predict p = x + Δt(v + Δt(g + w f_ext)); generate contacts; ``iterations`` sweeps of
    Δλ = −(C + α̃λ)/(Σ w|∇C|² + α̃), Δx = wΔλ∇C with α̃ = α/Δt² and λ reset to 0 every step; then
    v = (p − x)/Δt, x = p, and a velocity pass (ground friction and restitution, damping v ← v e^{−cΔt}).

    Schedules: ``"coloring"`` is Gauss–Seidel over a greedy colouring computed once on the host (no two
    constraints of a colour share a moving particle, so a colour runs in parallel without races);
    ``"jacobi"`` projects all constraints of a set at once, accumulates their corrections atomically and
    moves each particle by their average (summing without averaging diverges for stiff constraints on
    light particles). Each constraint computes its Δλ as if particle i had the mass m_i/n_i (mass
    splitting, n_i the constraints of the set at i), so the average of its copies' corrections is exactly
    Σ_c w_i Δλ_c ∇_i C_c: λ stays consistent with the motion applied, and a converged static state is the
    same as under Gauss–Seidel (plain averaging without the split would over-count λ and sag too far).
    Contacts are always averaged. On the CPU (serial threads) a colour-sorted sweep runs as one launch;
    on CUDA each colour is a launch, over a colouring made for the fewest colours (``color_constraints(...,
    fewest=True)``: another Gauss–Seidel order than the CPU's, docs/design.md "XPBD on CUDA"). λ's reset
    rides in the first sweep and the last Jacobi average in the velocity update, so a step is predict,
    the sweeps' launches and the update. Repeated identical steps replay recorded launches (``wp.Launch``).

    Differentiable: when the model was finalized with ``requires_grad=True`` each step writes fresh arrays
    (positions after every constraint set's sweep, λ per sweep, predicted velocities) and launches afresh
    (no replay), so ``wp.Tape`` records and replays it: gradients reach the initial state, the model's
    inverse masses, each constraint set's ``compliance_array`` (and ``rest``) and :attr:`gravity`, for
    ``Distance``, ``DihedralBending``, ``Volume``, ``ShapeMatching`` (without oriented particles) and
    ``Ground`` under ``schedule="jacobi"`` with fixed ``iterations``. Ground contact, friction and
    restitution are piecewise smooth: at a switch (C = 0, the Coulomb cone, the restitution threshold) the
    gradient is one-sided. Other sets (oriented particles, generated contacts, generic constraints), the
    colouring schedule and kinematic particles raise an error when gradients are requested. Shape
    matching differentiates R through ``wp.svd3``'s adjoint, undefined where the cluster's moment has
    repeated singular values (an undeformed isotropic cluster). With gradients off nothing of this runs.

    Limitations: overlapping shape-matching clusters with oriented particles race on the orientation under
    "jacobi".

    Args:
        model: the Model; by default the constraints are its springs (``Distance``, α = 1/k), bending
            elements with k > 0 (``DihedralBending``), tetrahedra (``Volume``, α = V0/κ) and ground.
        iterations: projection sweeps per step.
        compliance: α [m/N] of the default distance constraints (overrides 1/k).
        bending_compliance: α [1/(N m)] of the default bending constraints (adds them for every element).
        volume_compliance: α of the default volume constraints.
        schedule: "jacobi" or "coloring".
        relaxation: ω in (0, 2) scaling each Δλ and its Δx together, so λ stays consistent with x.
        jacobi: "average" (mass-split corrections averaged per particle) or "sum": the sets of
            :class:`~pliant.constraints.FixedArityConstraint` (distance, area, bending, volume) see the full
            masses and their corrections are summed, as Newton's XPBD does; other sets still average.
            Accurate at one iteration per substep (docs/design.md "XPBD on CUDA"); may diverge when
            Σ_c w|∇C|² outweighs α̃ by far (stiff constraints on light particles at large steps).
            Jacobi converges much faster with ω ≈ 1.8; "coloring" over-relaxed too (the 64² drape: 0.4 %
            trajectory error at 50 substeps with ω = 1.6, 1.5 % at 100 with ω = 1), but it diverges near 1.8
            and over-corrects a coarse cloth (pliant.bench._xpbd.SETTINGS). Contacts always use 1.
        damping: c [1/s] in v ← v e^{−cΔt}.
        friction: ground μ (default ``model.ground.friction``).
        restitution: ground e (default ``model.ground.restitution``).
        constraints: explicit constraint objects (replace the defaults; a ``Ground`` is added when the
            model has a ground and none is given).
        contact: add the model's ground plane as a ``Ground`` constraint.
        contact_iterations: extra sweeps of the contact constraints alone at the end of each step.
        tolerance: stop a step's sweeps once the RMS of C + α̃λ over the bilateral constraints [constraint
            units: m for distances] is at most this; ``iterations`` is then the cap. None (the default):
            always ``iterations`` sweeps. The check runs on the device every ``check_every`` sweeps (a
            residual pass and a one-thread kernel that sets a flag; ``wp.capture_while`` repeats the sweeps
            while it is set), so a frame with a tolerance is captured and replayed as a graph like any
            other (on CUDA this needs conditional graph nodes, CUDA 12.4+; without them the frame runs
            launch by launch, :meth:`graph_blocker`). The positions equal those of a run with
            ``iterations`` = :attr:`last_iterations`. XPBD only (PBD's per-sweep stiffness depends on the
            sweep count), and not with gradients (they need a fixed count).
        check_every: sweeps between two residual checks (each costs one residual pass; launched directly,
            also one host read of the flag, which a captured graph does not need).
        collisions: contact handlers run after each step, each with ``apply(model, state_in, state_out,
            dt)`` (``pl.collision.Colliders``, ``SelfCollision``), as for every solver (:class:`Solver`).

    Example::

        solver = pl.solvers.XPBD(model, iterations=10, schedule="coloring")
        sim = pl.Simulator(model, solver, frame_dt=1 / 60, substeps=10)
    """

    pbd = False

    def __init__(
        self,
        model: Model,
        *,
        iterations: int = 10,
        compliance: float | None = None,
        bending_compliance: float | None = None,
        volume_compliance: float | None = None,
        schedule: str = "jacobi",
        relaxation: float = 1.0,
        jacobi: str = "average",
        damping: float = 0.0,
        friction: float | None = None,
        restitution: float | None = None,
        constraints: Sequence[Constraint] | None = None,
        contact: bool = True,
        contact_iterations: int = 4,
        collisions: Sequence[Any] = (),
        tolerance: float | None = None,
        check_every: int = 2,
    ) -> None:
        super().__init__(model, collisions)
        if model.tet10_count:
            raise ValueError(
                "XPBD has no constraints for quadratic (order = 2) tetrahedra; build the volume with "
                "order = 1, or simulate it with ForceSolver"
            )
        if int(iterations) < 1:
            raise ValueError(f"iterations must be >= 1, got {iterations}")
        if tolerance is not None:
            if not tolerance > 0:
                raise ValueError(f"tolerance must be > 0 (RMS constraint residual), got {tolerance}")
            if self.pbd:
                raise ValueError(
                    "tolerance: PBD's per-sweep stiffness is set by the iteration count, so PBD runs a fixed "
                    "count; use XPBD for a tolerance, or drop it"
                )
            if model.requires_grad:
                raise ValueError(
                    "tolerance: a differentiable XPBD step runs a fixed number of sweeps; drop the tolerance "
                    "or finalize the model with requires_grad=False"
                )
        if int(check_every) < 1:
            raise ValueError(f"check_every must be >= 1, got {check_every}")
        self.tolerance = None if tolerance is None else float(tolerance)
        self.check_every = int(check_every)
        if schedule not in _SCHEDULES:
            raise ValueError(f"schedule must be one of {_SCHEDULES}, got {schedule!r}")
        if jacobi not in _JACOBI_MODES:
            raise ValueError(f"jacobi must be one of {_JACOBI_MODES}, got {jacobi!r}")
        if not 0.0 < relaxation < 2.0:
            raise ValueError(f"relaxation ω must be in (0, 2), got {relaxation}")
        if damping < 0:
            raise ValueError(f"damping must be >= 0 1/s, got {damping}")
        self.iterations = int(iterations)
        self.schedule = schedule
        self.coloring = schedule == "coloring"
        self.relaxation = float(relaxation)
        self.jacobi = jacobi
        self.damping = float(damping)
        self.contact_iterations = int(contact_iterations)
        self.constraints = self._default_constraints(
            model, compliance, bending_compliance, volume_compliance, constraints
        )
        if contact and model.ground is not None and not any(isinstance(c, Ground) for c in self.constraints):
            self.constraints.append(Ground(friction=friction, restitution=restitution))
        for c in self.constraints:
            if not isinstance(c, Constraint):
                raise TypeError(f"constraints must be pl.constraints objects, got {type(c).__name__}")
            c.bind(model, self.coloring)
        self.requires_grad = bool(model.requires_grad)
        if self.requires_grad:
            self._check_differentiable()
            # Inverse masses are a differentiable parameter (the builder allocates them without a gradient).
            model.particle_inv_mass.requires_grad = True
        d, n = model.device, model.particle_count
        #: Gravity [m/s²] as a vec3 array [1] (from ``model.gravity``); its ``.grad`` under a tape.
        self.gravity: wp.array = wp.array(
            [model.gravity], dtype=model.vec3, device=d, requires_grad=self.requires_grad
        )
        self.delta = wp.zeros(n, dtype=model.vec3, device=d)
        self.delta_count = wp.zeros(n, dtype=wp.int32, device=d)
        self.v_pred = wp.zeros(n, dtype=model.vec3, device=d)
        self._residual = wp.zeros(2, dtype=model.scalar, device=d)
        # The tolerance loop's device state (see _tolerance.py): its two flags and the sweep counts.
        self._go = wp.zeros(1, dtype=wp.int32, device=d)
        self._tail = wp.zeros(1, dtype=wp.int32, device=d)
        self._counts = wp.zeros(T.COUNT_SLOTS, dtype=wp.int32, device=d)
        self._last_dt: float | None = None
        self._last_p: wp.array | None = None
        #: Replay recorded launches for repeated identical steps (set False to launch afresh every step).
        self.replay = not self.requires_grad
        self._plans: dict[tuple, list] = {}
        self._recording: list | None = None
        # ω of a Jacobi correction not applied yet: the next projection (or the velocity update, fused with
        # it) applies it first. Only the step's last one waits that long: it saves a launch per step.
        self._pending_omega: float | None = None
        self._pending_average = 1

    def _default_constraints(self, model, compliance, bending_compliance, volume_compliance, constraints):
        if constraints is not None:
            return list(constraints)
        out: list[Constraint] = []
        if model.spring_count:
            out.append(Distance(compliance=compliance, stiffness=self._stiffness("stiffness")))
        if model.bending_count:
            k = model.bending_stiffness.numpy()
            if bending_compliance is not None or np.any(k > 0):
                out.append(
                    DihedralBending(compliance=bending_compliance, stiffness=self._stiffness("bending"))
                )
        if model.tet_count:
            out.append(Volume(compliance=volume_compliance, stiffness=self._stiffness("volume")))
        return out

    def _stiffness(self, which: str) -> float:
        return 1.0

    def _check_differentiable(self) -> None:
        """Gradients requested (``requires_grad`` model): reject what cannot give a correct gradient."""
        if self.coloring:
            raise GradientError(
                "XPBD: the colouring (Gauss–Seidel) schedule projects in place and cannot be differentiated; "
                'use schedule="jacobi" when the model is finalized with requires_grad=True'
            )
        bad = [type(c).__name__ for c in self.constraints if not c.differentiable]
        if bad:
            raise GradientError(
                f"XPBD: constraint sets {bad} are not differentiable yet; with requires_grad=True use "
                "Distance, DihedralBending, Volume, ShapeMatching without radii and Ground, or finalize with "
                "requires_grad=False"
            )

    def context(self) -> ProjectionContext:
        """What the constraint sets read from this solver during a step (a fresh, declared interface)."""
        return ProjectionContext(
            model=self.model,
            iterations=self.iterations,
            coloring=self.coloring,
            relaxation=self.relaxation,
            pbd=self.pbd,
            requires_grad=self.requires_grad,
            launch=self.launch,
            call=self.call,
            delta=self.delta,
            delta_count=self.delta_count,
            v_pred=self.v_pred,
            jacobi_sum=self.jacobi == "sum",
        )

    # ------------------------------------------------------------------ launching
    def launch(self, kernel, dim: int, inputs: list) -> None:
        """Launch ``kernel`` on the model's device, recording it when a step is being recorded."""
        if dim <= 0:
            return
        if self._recording is None:
            wp.launch(kernel, dim, inputs, device=self.model.device)
            return
        cmd = wp.launch(kernel, dim, inputs, device=self.model.device, record_cmd=True)
        cmd.launch()
        self._recording.append(cmd.launch)

    def call(self, fn, *args) -> None:
        """Run a non-kernel operation of the step (a clear, a grid build, a BVH refit), recording it too."""
        fn(*args)
        if self._recording is not None:
            self._recording.append((lambda: fn(*args)) if args else fn)

    # ------------------------------------------------------------------ the loop
    def step(self, state_in: State, state_out: State, control: Control | None, dt: float) -> None:
        """Advance ``state_in`` by ``dt`` [s] into ``state_out`` (Algorithm 1); ``state_in`` is only read.

        The first step for a given (states, control, Δt, sweep settings) records its launches; later
        identical steps replay them (``wp.Launch``), which removes most of the per-step Python cost. Scalar
        control inputs (the drag handle) are part of the key, array contents (forces, kinematic targets) are
        read at replay. With a tolerance the loop bodies are recorded too (``_recorded``).
        """
        key = self._plan_key(state_in, state_out, control, dt)
        plan = self._plans.get(key) if self.replay else None
        if plan is not None:
            for f in plan:
                f()
        else:
            self._recording = [] if self.replay else None
            try:
                self._step(state_in, state_out, control, dt)
                if self._recording is not None:
                    if len(self._plans) >= 8:
                        self._plans.clear()
                    self._plans[key] = self._recording
            finally:
                self._recording = None
        self._last_dt, self._last_p = dt, state_out.particle_q
        # Handlers run outside the recorded plan: they may rebuild grids or BVHs with host logic.
        self.apply_collisions(state_in, state_out, dt)

    def reset_plans(self) -> None:
        """Forget the recorded steps; call after changing options (iterations, relaxation, constraints)."""
        self._plans.clear()

    def _apply_pending(self, p: wp.array) -> None:
        """Apply the Jacobi correction :meth:`_project` left pending, if any."""
        if self._pending_omega is not None:
            m = self.model
            args = [m.s(self._pending_omega), self._pending_average, p, self.delta, self.delta_count]
            self._pending_omega = None
            self.launch(K.apply_deltas, m.particle_count, args)

    def _project(self, ctx: ProjectionContext, c: Constraint, p: wp.array, dt: float) -> wp.array:
        """One sweep of set ``c``; returns the positions after it (``p`` itself unless differentiable).

        A Jacobi set's correction is left pending (:meth:`_apply_pending`): what reads the positions next
        applies it first."""
        m = self.model
        self._apply_pending(p)
        if not c.writes_deltas(self.coloring):
            out = c.project(ctx, p, dt)
            return p if out is None else out
        if ctx.requires_grad:
            ctx.delta = ctx.fresh(self.delta)
            ctx.delta_count = ctx.fresh(self.delta_count)
        c.project(ctx, p, dt)
        omega = 1.0 if (self.coloring or c.always_jacobi or c.relaxes_itself) else self.relaxation
        # Summed (not averaged) where the set projected with full masses (jacobi="sum").
        average = 0 if (ctx.jacobi_sum and c.sums_jacobi and not self.coloring) else 1
        if not ctx.requires_grad:
            self._pending_omega, self._pending_average = omega, average
            return p
        p_next = ctx.fresh(p)
        args = [m.s(omega), average, p, ctx.delta, ctx.delta_count, p_next]
        self.launch(K.apply_deltas_to, m.particle_count, args)
        return p_next

    def _plan_key(self, state_in: State, state_out: State, control: Control | None, dt: float) -> tuple:
        arrays = (state_in.particle_q, state_in.particle_qd, state_out.particle_q, state_out.particle_qd)
        # The sweep settings too: a plan recorded without a tolerance (or with another) must not replay.
        key = (float(dt), self.iterations, self.tolerance, self.check_every, *(a.ptr for a in arrays))
        if control is None:
            return key
        return (
            *key,
            id(control),
            control.particle_f.ptr,
            control.kinematic_indices.ptr,
            control.kinematic_targets.ptr,
            control.drag_index,
            tuple(np.asarray(control.drag_target, float).tolist()),
            float(control.drag_stiffness),
            float(control.drag_max_force),
        )

    def _step(self, state_in: State, state_out: State, control: Control | None, dt: float) -> None:
        m = self.model
        n = m.particle_count
        ctx = self.context()
        grad = ctx.requires_grad
        if grad:
            self._check_differentiable()  # again: sets may have been added after construction
        x = state_in.particle_q
        # A differentiable step never overwrites what it has read: fresh positions per sweep (below).
        p = ctx.fresh(x) if grad else state_out.particle_q
        if grad:
            ctx.v_pred = ctx.fresh(self.v_pred)
        if control is not None:
            f_ext = control.particle_f
            drag = control.drag_index
            drag_target, drag_k = m.vec3(*control.drag_target), m.s(control.drag_stiffness)
            drag_cap = m.s(control.drag_max_force)
        else:
            f_ext = self.delta  # zeros between steps
            drag, drag_target, drag_k, drag_cap = -1, m.vec3(0.0, 0.0, 0.0), m.s(0.0), m.s(0.0)
        self.launch(
            K.predict,
            n,
            [
                m.particle_inv_mass,
                self.gravity,
                f_ext,
                drag,
                drag_target,
                drag_k,
                drag_cap,
                m.s(dt),
                x,
                state_in.particle_qd,
                p,
                ctx.v_pred,
            ],
        )
        if control is not None and control.kinematic_indices.shape[0]:
            if grad:
                raise GradientError(
                    "XPBD: kinematic targets are not differentiable yet; drop them from the Control or "
                    "finalize with requires_grad=False"
                )
            self.launch(
                K.apply_kinematic,
                control.kinematic_indices.shape[0],
                [control.kinematic_indices, control.kinematic_targets, p],
            )
        for c in self.constraints:
            c.begin_step(ctx, x, p, dt)
        self._pending_omega = None
        if self.tolerance is None:
            p = self._sweeps(ctx, p, dt, self.iterations, apply=False)
        else:
            self._sweep_to_tolerance(ctx, p, dt)
        # Contacts last: extra sweeps of the unilateral constraints alone, so that averaging with the
        # bilateral corrections does not leave particles inside what they touch at the end of the step.
        contacts = [c for c in self.constraints if c.is_contact]
        for _ in range(self.contact_iterations if contacts else 0):
            for c in contacts:
                p = self._project(ctx, c, p, dt)
        v = ctx.fresh(state_out.particle_qd) if grad else state_out.particle_qd
        inv_dt, decay = m.s(1.0 / dt), m.s(math.exp(-self.damping * dt))
        if self._pending_omega is None:
            self.launch(K.update_velocity, n, [inv_dt, decay, x, p, v])
        else:
            omega, average = m.s(self._pending_omega), self._pending_average
            args = [omega, average, inv_dt, decay, x, self.delta, self.delta_count, p, v]
            self._pending_omega = None
            self.launch(K.apply_deltas_update_velocity, n, args)
        for c in self.constraints:
            out = c.end_step(ctx, x, p, v, dt)
            if isinstance(out, tuple):  # a velocity pass that moves positions too (ground friction)
                p, v = out
            elif out is not None:
                v = out
        if grad:
            self.launch(K.write_state, n, [p, v, state_out.particle_q, state_out.particle_qd])

    def _sweeps(
        self, ctx: ProjectionContext, p: wp.array, dt: float, count: int, *, apply: bool = True
    ) -> wp.array:
        """``count`` sweeps over every constraint set; returns the positions after them (with ``apply``
        False the last Jacobi correction may still be pending: :meth:`_apply_pending`)."""
        for _ in range(count):
            for c in self.constraints:
                p = self._project(ctx, c, p, dt)
        if apply:
            self._apply_pending(p)
        return p

    def _sweep_to_tolerance(self, ctx: ProjectionContext, p: wp.array, dt: float) -> None:
        """Sweeps until the RMS residual is at most ``tolerance`` (checked after every ``check_every``
        sweeps while fewer than ``iterations`` have run), deciding on the device.

        With N = ``iterations`` and c = ``check_every``: min(c, N) sweeps; then, while a check finds the
        residual too large, another c sweeps and a check, for at most M = ⌊(N − 1)/c⌋ checks; after the
        M-th the last N − Mc sweeps run unchecked. ``wp.capture_while`` and ``wp.capture_if`` branch on the
        flags ``tolerance_check`` sets: launched directly they read them on the host (a CPU memory read; on
        CUDA a copy and a sync, as the host loop did), captured they become graph nodes (a CPU graph's
        loop, a CUDA conditional node) and the step needs no host read at all. No tape: a tolerance is
        refused with gradients, so ``p`` is projected in place and stays the same array.
        """
        n, every = self.iterations, self.check_every
        first = min(every, n)
        checks = (n - 1) // every
        tail = n - checks * every
        flags = [self._residual, self._go, self._tail, self._counts]
        self.launch(T.tolerance_begin, 1, [first, *flags])
        self._sweeps(ctx, p, dt, first)
        if checks == 0:
            return
        assert self.tolerance is not None  # the caller's branch: only a solver with a tolerance sweeps here
        tol = wp.float64(self.tolerance)

        def check() -> None:
            for c in self.constraints:
                self.call(c.residual, ctx, p, dt, self._residual)  # launches of its own: recorded whole
            self.launch(T.tolerance_check, 1, [tol, every, checks, tail, *flags])

        def chunk() -> None:
            self._sweeps(ctx, p, dt, every)
            check()

        check()
        self.call(wp.capture_while, self._go, self._recorded(chunk))

        def last() -> None:
            self._sweeps(ctx, p, dt, tail)

        self.call(wp.capture_if, self._tail, self._recorded(last))

    def _recorded(self, body: Callable[[], None]) -> Callable[[], None]:
        """``body`` (a loop body's launches) as a callable that, in a step being recorded, records them on
        its first call and replays them after, so that a plan's loop bodies skip the Python launch cost
        like the rest of the plan. The body may first run in a later step (a loop that never ran while
        its step was recorded): it records then."""
        if self._recording is None:
            return body
        plan: list | None = None

        def run() -> None:
            nonlocal plan
            if plan is not None:
                for f in plan:
                    f()
                return
            outer, self._recording = self._recording, []
            try:
                body()
                plan = self._recording
            finally:
                self._recording = outer

        return run

    # ------------------------------------------------------------------ diagnostics
    @property
    def last_iterations(self) -> int:
        """Sweeps the last step ran: ``iterations`` unless a ``tolerance`` stopped it earlier (then one
        host read of the device's count, whether the step was launched or replayed from a graph)."""
        if self.tolerance is None:
            return self.iterations
        return int(self._counts.numpy()[T.SWEEPS])

    def sweep_counts(self) -> tuple[int, int]:
        """(steps, sweeps) run with a tolerance since the solver was made, counted on the device (one host
        read): sweeps / steps is the mean sweep count a tolerance left, replayed frames included."""
        c = self._counts.numpy()
        return int(c[T.STEPS]), int(c[T.TOTAL])

    def residual(self) -> float:
        """RMS of C + α̃λ over the bilateral constraints after the last step (host sync) [constraint units]."""
        if self._last_dt is None or self._last_p is None:
            raise RuntimeError("residual() needs a step first")
        return self._rms_residual(self.context(), self._last_p, self._last_dt)

    def _rms_residual(self, ctx: ProjectionContext, p: wp.array, dt: float) -> float:
        self._residual.zero_()
        for c in self.constraints:
            c.residual(ctx, p, dt, self._residual)
        s, n = self._residual.numpy()
        return float(math.sqrt(s / n)) if n > 0 else 0.0

    @property
    def constraint_count(self) -> int:
        """Number of bilateral constraints (shape-matching clusters count one each) projected per sweep."""
        return sum(c.count for c in self.constraints if not c.is_contact)

    def graph_blocker(self) -> str | None:
        """None without a tape: a fixed sweep count, or a tolerance tested on the device (on CUDA only
        where conditional graph nodes exist: ``wp.capture_while`` needs a CUDA 12.4+ driver and toolkit)."""
        if self.requires_grad:
            return "a differentiable model's steps write fresh arrays each step"
        if self.tolerance is not None and wp.get_device(self.model.device).is_cuda:
            if not wp.is_conditional_graph_supported():
                return (
                    "an XPBD tolerance loops on a device flag (wp.capture_while), which a CUDA graph holds "
                    "only with conditional nodes (CUDA driver and toolkit 12.4+); update the driver, or use "
                    "a fixed iteration count (tolerance=None)"
                )
        return self._collisions_blocker()

    def refresh_parameters(self) -> str | None:
        """Bind every constraint set again (compliances from the new spring k, ...) into the arrays it held
        (``Constraint.rebind``); why not when an array changed shape (:meth:`Solver.refresh_parameters`)."""
        for c in self.constraints:
            why = c.rebind(self.model, self.coloring)
            if why is not None:
                return why
        return None

    def describe(self) -> dict:
        """Solver options and constraint sets."""
        return {
            "solver": type(self).__name__,
            "integrator": "xpbd" if not self.pbd else "pbd",
            "iterations": self.iterations,
            "schedule": self.schedule,
            "relaxation": self.relaxation,
            "jacobi": self.jacobi,
            "damping": self.damping,
            "constraints": [c.describe() for c in self.constraints],
        }


class PBD(XPBD):
    """Position-based dynamics (Müller, Heidelberger, Hennix, Ratcliff, VRIPHYS 2006): XPBD's loop with
    Δλ = −k' C/Σ w|∇C|², k' = 1 − (1 − k)^(1/n) for n iterations, so that the stiffness k ∈ [0, 1] acts
    the same whatever the iteration count (but still depends on Δt and the mesh).

    Args:
        model: the Model.
        iterations: projection sweeps per step.
        stiffness: k of the default distance constraints.
        bending_stiffness: k of the default bending constraints (added for every element when > 0).
        volume_stiffness: k of the default volume constraints.

    Other keyword arguments as :class:`XPBD`; constraint objects carry their own ``stiffness``.
    """

    pbd = True

    def __init__(
        self,
        model: Model,
        *,
        iterations: int = 10,
        stiffness: float = 1.0,
        bending_stiffness: float = 0.0,
        volume_stiffness: float = 1.0,
        **kwargs,
    ) -> None:
        self._k = {"stiffness": stiffness, "bending": bending_stiffness, "volume": volume_stiffness}
        for name, k in self._k.items():
            if not 0.0 <= k <= 1.0:
                raise ValueError(f"PBD {name} must be in [0, 1], got {k}")
        if bending_stiffness > 0 and "bending_compliance" not in kwargs:
            kwargs["bending_compliance"] = 0.0
        super().__init__(model, iterations=iterations, **kwargs)

    def _stiffness(self, which: str) -> float:
        return self._k[which]
