"""A specialised mass-spring solver: one fused, atomic-free kernel per explicit step, or Baraff–Witkin.

The generic :class:`~pliant.solvers.ForceSolver` launches one kernel per energy term and scatters spring
forces with atomics; on the CPU, where Warp runs a kernel's threads one after another, the launches and
the scatter dominate a cloth step. Here each particle *gathers* the forces of its own springs from a CSR
adjacency (spring ``s`` appears once in the row of each endpoint), so

* the explicit path (symplectic Euler) is one kernel per step on CUDA: gather spring + dashpot + gravity +
  external forces, update v then x — no atomics, no scratch force array. On the CPU, where a launch runs
  its threads one after another and an atomic add is a plain add, the gather's cost is its arithmetic,
  and it evaluates every spring twice (once from each end); there the step is two kernels instead — each
  spring once, adding its force into a scratch array, then the update, which clears the array again —
  1.47× (64²) and 1.53× (128²) the gather's frames per second on the drape, at the same trajectory
  error (``benchmarks/bench_cloth_kernels.py``, one core);
* the implicit path is Baraff & Witkin's linearised backward Euler,
  (M + hD + h²K) Δv = h(f(xⁿ, vⁿ) − hK vⁿ), solved matrix-free by block-Jacobi preconditioned CG with
  two kernels per CG iteration (the search-direction update is fused into the product A·p by double
  buffering p). K is the PSD-projected spring Hessian (compressed springs keep only their axial term),
  D the dashpot Jacobian γ n̂n̂ᵀ. The CG scalars live in device arrays (one slot per iteration), so a step
  never synchronises with the host.

Only springs, dashpots (``model.spring_damping``), gravity, ``Control.particle_f``, the drag handle,
kinematic targets, ground contact and post-step contact handlers are handled — a model with FEM
tetrahedra needs ForceSolver.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import warp as wp

from ..._warp import capturing, grad_enabled
from ...collision import ground_coefficients
from ...energies import Dashpots, Gravity, Springs
from ...integrators import SymplecticEuler
from ...model import Control, Model, Parameter, State, declares
from .._base import DAMPING_RATE, Solver
from .._post import add_drag_force, check_collisions, finish_step
from ..force import ForceSolver
from ._adjoint import BaraffWitkinStep
from ._explicit import (
    TILE_LANES,
    EllRows,
    _springs_scatter,
    _symplectic_gather,
    _symplectic_gather_tiled,
    _symplectic_gather_unrolled,
    _symplectic_update,
    ell_gather_kernel,
)
from ._fused_frame import FusedFrame, fused_frame_blocker
from ._system import BaraffWitkinSystem, _bw_assemble, _bw_finish

#: The gather kernel of each ``FastMassSpring(gather=...)`` variant (``_explicit`` says how they differ).
GATHER_KERNELS = {
    "loop": _symplectic_gather,
    "unrolled": _symplectic_gather_unrolled,
    "ell": None,  # built per slot count (ell_gather_kernel)
    "tiled": _symplectic_gather_tiled,
    "tiled16": _symplectic_gather_tiled,
}


#: The gather kernel's block below SMALL_BLOCK_BELOW particles (``FastMassSpring(block_dim=None)``).
SMALL_BLOCK = 64
SMALL_BLOCK_BELOW = 32768


def spring_adjacency(model: Model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR rows of the spring graph: (offsets [N+1], neighbour [2S], spring index [2S]), int32."""
    idx = model.spring_indices.numpy().astype(np.int64) if model.spring_count else np.zeros((0, 2), np.int64)
    n = model.particle_count
    rows = np.concatenate([idx[:, 0], idx[:, 1]])
    cols = np.concatenate([idx[:, 1], idx[:, 0]])
    spr = np.concatenate([np.arange(idx.shape[0]), np.arange(idx.shape[0])])
    order = np.lexsort((cols, rows))
    offsets = np.zeros(n + 1, np.int64)
    np.add.at(offsets, rows + 1, 1)
    offsets = np.cumsum(offsets)
    return offsets.astype(np.int32), cols[order].astype(np.int32), spr[order].astype(np.int32)


@declares
class FastMassSpring(Solver):
    """Mass-spring dynamics (springs, dashpots, gravity) with fused, atomic-free per-particle kernels.

    Args:
        model: the Model (springs only; FEM tetrahedra are rejected — use ForceSolver).
        method: ``"symplectic"`` (one fused kernel per step; stable for Δt ≲ 2/ω_max) or ``"implicit"``
            (Baraff–Witkin linearised backward Euler, unconditionally stable; one Newton step per call).
        cg_iterations: the most CG iterations per implicit step.
        cg_tol: relative residual (preconditioned norm, √(rᵀP⁻¹r / r₀ᵀP⁻¹r₀)) at which CG stops.
        cg_check_every: iterations between host reads of the residual; the step stops launching once it
            is reached (``last_cg_iterations`` says after how many). None: 4 on the CPU, where a read is a
            copy of a few numbers, 16 on CUDA, where it synchronises; 0: never read (all ``cg_iterations``
            launched, the update frozen on the device after convergence).
        kernel: the symplectic step's spring kernel: ``"scatter"`` (each spring once, its force added to
            both ends: the CPU's choice, where atomic adds are plain adds and the sum order is fixed) or
            ``"gather"`` (each particle sums its own springs, every spring evaluated from both ends, one
            fused kernel, no atomics: CUDA's choice, deterministic there). None: by device. Both give the
            same step to round-off.
        gather: the gather kernel's variant: ``"loop"`` (a thread per particle, one spring after another),
            ``"unrolled"`` (the same sums, bit for bit, with four springs' loads issued together: less
            latency per step on a GPU), ``"ell"`` (the same sums, bit for bit, from column-major ELL rows
            with the slot loop unrolled: coalesced loads, the whole row's issued at once; at most 16
            springs per particle) or ``"tiled"`` / ``"tiled16"`` (a block of 32 / 16 lanes per
            particle, one spring each, summed by a tile reduction: equal to round-off). Picking one other
            than ``"loop"`` implies ``kernel="gather"``. None (default): ``"unrolled"`` on CUDA (measured
            on an H100, frames replayed as graphs: 1.28× the loop's frames per second at 64², 1.26× at
            128², 1.09× at 256², 1.02× at 512², the same trajectory error; the tiled ones are 0.16-1.09×),
            ``"loop"`` on the CPU (whose default kernel is the scatter).
        block_dim: threads per block of the symplectic gather kernel on CUDA (not the tiled variants, whose
            block is a particle's lanes). None: 64 for fewer than 32 768 particles, Warp's 256 above
            (measured on an H100, drape frames replayed as graphs: 64 threads gave 1.18× the frames per
            second at 64², 1.06× at 128², where a few blocks of 256 leave most SMs idle and each thread's
            loads wait in line; 0.96-1.02× at 256² and 512²).
        theta: the implicit step's θ: (M + θhD + θ²h²K)Δv = h(f − θhKv), x¹ = x + h(v + θΔv). 1 is
            Baraff–Witkin's linearised backward Euler (dissipative: it damps fast motion); 0.5 the
            linearised implicit midpoint rule (second order, no numerical damping; the drape benchmark
            reaches trajectory_error ≤ 2 % with far fewer steps).
        fused_frame: run a frame's symplectic substeps (:meth:`step_frame`, which ``FrameStep`` and the
            Simulator call) as one CPU launch that loops over them in C++: the scatter's arithmetic in its
            order, the drag handle, kinematic targets and the ground response (projection or compliant),
            the same frame bit for bit, without per-step launches and Python (1.78× the frames per second
            on the 64² and 128² drapes, one core; :mod:`._fused_frame`). None (default): wherever it
            applies (the CPU, the scatter kernel, no gradients, no contact handlers), else
            step by step (``fused_frame_blocker`` says why); True: always, and a setup it cannot run raises
            ValueError; False: never.
        velocity_damping: the lecture's δ, multiplying velocities each step (1 = none).
        damping_rate: c [1/s]: v ← v·exp(−cΔt), Δt-independent; overrides ``velocity_damping``.
        contact: resolve ground contact after each step (needs ``model.ground``; a compliant ground is
            a spring–damper solved after the step, :func:`pliant.collision.ground_response`).
        collisions: contact handlers applied after the step, each with ``apply(model, state_in, state_out,
            dt)`` (e.g. :class:`pliant.collision.Colliders`, :class:`pliant.collision.SelfCollision`).

    Example::

        solver = pl.solvers.FastMassSpring(model, method="implicit", cg_iterations=40, damping_rate=1.0)
        solver.step(state_0, state_1, control, 1 / 60)
    """

    @classmethod
    def parameters(cls) -> tuple[Parameter, ...]:
        """The velocity damping rate c [1/s] (its recorded, requires_grad step holds it as an array)."""
        return (DAMPING_RATE,)

    def __init__(
        self,
        model: Model,
        *,
        method: str = "symplectic",
        cg_iterations: int = 50,
        cg_tol: float = 1.0e-6,
        cg_check_every: int | None = None,
        kernel: str | None = None,
        gather: str | None = None,
        block_dim: int | None = None,
        theta: float = 1.0,
        fused_frame: bool | None = None,
        velocity_damping: float = 1.0,
        damping_rate: float | None = None,
        contact: bool = True,
        collisions: Sequence[Any] = (),
    ) -> None:
        super().__init__(model)
        if method not in ("symplectic", "implicit"):
            raise ValueError(f"method must be 'symplectic' or 'implicit', got {method!r}")
        if model.tet_count or model.tet10_count:
            raise ValueError(
                "FastMassSpring handles springs only; this model has FEM tetrahedra: use ForceSolver"
            )
        if cg_iterations < 1:
            raise ValueError(f"cg_iterations must be >= 1, got {cg_iterations}")
        if not 0.0 < velocity_damping <= 1.0:
            raise ValueError(f"velocity_damping δ must be in (0, 1], got {velocity_damping}")
        if damping_rate is not None and damping_rate < 0:
            raise ValueError(f"damping_rate must be >= 0 1/s, got {damping_rate}")
        self.method = method
        self.cg_iterations = int(cg_iterations)
        self.cg_tol = float(cg_tol)
        if not cg_tol > 0:
            raise ValueError(f"cg_tol must be > 0 (a relative residual), got {cg_tol}")
        if cg_check_every is None:
            cg_check_every = 4 if wp.get_device(model.device).is_cpu else 16
        if cg_check_every < 0:
            raise ValueError(f"cg_check_every must be >= 0 iterations (0: never check), got {cg_check_every}")
        self.cg_check_every = int(cg_check_every)
        if not 0.5 <= theta <= 1.0:
            raise ValueError(
                f"theta must be in [0.5, 1] (1: backward Euler, 0.5: implicit midpoint), got {theta}"
            )
        if theta != 1.0 and grad_enabled(model) and method == "implicit":
            raise ValueError(
                "theta != 1 has no adjoint yet: differentiable implicit FastMassSpring steps are backward "
                "Euler's (theta=1); use theta=1 with requires_grad, or ForceSolver with ImplicitMidpoint"
            )
        self.theta = float(theta)
        #: CG iterations the last implicit step took to reach ``cg_tol`` (``cg_iterations`` if it did not).
        self.last_cg_iterations = 0
        #: Implicit steps taken and CG iterations summed over them (for means over a run).
        self.cg_steps = 0
        self.cg_iterations_total = 0
        self.velocity_damping_factor = float(velocity_damping)
        self.damping_rate = damping_rate
        self.contact = contact and model.ground is not None
        self._ground = ground_coefficients(model) if self.contact else None
        self.collisions = check_collisions(collisions)
        d = model.device
        off, nb, spr = spring_adjacency(model)
        self.adj_offsets: wp.array = wp.array(off, dtype=wp.int32, device=d)
        self.adj_neighbor: wp.array = wp.array(nb, dtype=wp.int32, device=d)
        self.adj_spring: wp.array = wp.array(spr, dtype=wp.int32, device=d)
        self._adj_param = wp.zeros(max(nb.shape[0], 1), dtype=model.vec3, device=d)
        if gather is None:
            gather = "loop" if wp.get_device(d).is_cpu else "unrolled"
        if gather not in GATHER_KERNELS:
            raise ValueError(f"gather must be one of {sorted(GATHER_KERNELS)}, got {gather!r}")
        if kernel is None:
            kernel = "scatter" if wp.get_device(d).is_cpu and gather == "loop" else "gather"
        if kernel not in ("scatter", "gather"):
            raise ValueError(f"kernel must be 'scatter', 'gather' or None (by device), got {kernel!r}")
        if kernel == "scatter" and gather != "loop":
            raise ValueError(f"gather={gather!r} is a variant of kernel='gather'; drop kernel='scatter'")
        #: The gather kernel's variant (a key of :data:`GATHER_KERNELS`).
        self.gather = gather
        if block_dim is None:
            block_dim = SMALL_BLOCK if model.particle_count < SMALL_BLOCK_BELOW else 256
        if not isinstance(block_dim, int) or not 1 <= block_dim <= 1024:
            raise ValueError(f"block_dim must be an integer in [1, 1024] threads, got {block_dim!r}")
        #: Threads per block of the gather kernel (CUDA; a CPU launch runs its threads in sequence).
        self.block_dim = block_dim
        self._ell = EllRows.build(off, nb, model.vec3, d) if gather == "ell" else None
        #: The symplectic step's spring kernel (the implicit step always gathers).
        self.kernel = kernel
        self._scatter = method == "symplectic" and kernel == "scatter"
        if self._scatter:
            pairs = model.spring_indices.numpy().reshape(-1, 2) if model.spring_count else np.zeros((0, 2))
            self._spring_pairs: wp.array = wp.array(pairs.astype(np.int32), dtype=wp.vec2i, device=d)
            self._f_springs = wp.zeros(model.particle_count, dtype=model.vec3, device=d)
        #: Why frames run step by step rather than as one launch (None: they are fused; ``fused_frame``).
        self.fused_frame, self.fused_frame_blocker = (
            fused_frame,
            fused_frame_blocker(fused_frame, model, method, self._scatter, len(self.collisions)),
        )
        self._fused = (
            None
            if self.fused_frame_blocker
            else FusedFrame(model, self._spring_pairs, self._f_springs, self._ground)
        )
        self.update_parameters()
        n = model.particle_count
        self._f_zero = wp.zeros(n, dtype=model.vec3, device=d)
        self._f_work = wp.zeros(n, dtype=model.vec3, device=d)
        #: The implicit step's linear system (adjacency, blocks, CG buffers); None for the symplectic method.
        self._system: BaraffWitkinSystem | None = None
        if method == "implicit":
            self._system = BaraffWitkinSystem(
                model, self.adj_offsets, self.adj_neighbor, self.adj_spring, self.cg_iterations, self.cg_tol
            )
        #: Under requires_grad: the same step by ForceSolver's tape-correct path (see :meth:`step`).
        self._recorded: ForceSolver | None = None
        if grad_enabled(model):
            self._recorded = self._recorded_solver(
                method, velocity_damping, damping_rate, contact, collisions
            )

    def _recorded_solver(self, method, velocity_damping, damping_rate, contact, collisions) -> ForceSolver:
        """The symplectic step as ``ForceSolver(Springs, Dashpots, Gravity; SymplecticEuler)``: the same
        update (equal to round-off, not bit for bit: the gather kernel sums in another order), written into
        fresh arrays so that ``wp.Tape`` can differentiate it, and reading the model's parameter arrays
        directly (no host-side packing)."""
        if method == "implicit":
            # The same Δv by the same kernels and buffers, with the adjoint of the linear solve on the tape.
            return ForceSolver(
                self.model,
                energies=[Springs(), Dashpots(), Gravity()],
                integrator=BaraffWitkinStep(self._implicit_system()),
                velocity_damping=velocity_damping,
                damping_rate=damping_rate,
                contact=contact,
                collisions=collisions,
            )
        return ForceSolver(
            self.model,
            energies=[Springs(), Dashpots(), Gravity()],
            integrator=SymplecticEuler(),
            velocity_damping=velocity_damping,
            damping_rate=damping_rate,
            contact=contact,
            collisions=collisions,
        )

    @property
    def gravity(self) -> wp.array | None:
        """g [m/s²] (1-element vec3) read by recorded steps (its ``.grad`` after backward), else None."""
        return None if self._recorded is None else self._recorded.gravity

    @property
    def damping_rate_array(self) -> wp.array | None:
        """The damping rate c [1/s] read by recorded steps (with ``damping_rate``), else None."""
        return None if self._recorded is None else self._recorded.damping_rate_array

    @property
    def ground_coefficients(self) -> wp.array | None:
        """[friction μ, restitution e] read by recorded steps (their ``.grad`` after backward), else None."""
        return None if self._recorded is None else self._recorded.ground_coefficients

    def update_parameters(self) -> None:
        """Re-pack spring rest lengths, stiffness and damping per adjacency entry (after changing them)."""
        m = self.model
        spr = self.adj_spring.numpy()
        if spr.shape[0]:
            per_spring = np.stack(
                [m.spring_rest_length.numpy(), m.spring_stiffness.numpy(), m.spring_damping.numpy()], axis=1
            )
            per_entry = per_spring[spr]
            self._adj_param.assign(per_entry)
            if self._fused is not None:
                self._fused.pack(per_spring)
            if self._ell is not None:
                self._ell.pack(per_entry)
            self._damped = int(np.any(per_spring[:, 2] > 0))
        else:
            self._damped = 0
        self._cmds: dict[tuple[int, int, int, int, float, float], list] = {}

    def refresh_parameters(self) -> str | None:
        """Pack the springs' parameters again per row (:meth:`update_parameters`), into the arrays its graphs
        and recorded launches hold (its implicit step and recorded path read the model's arrays); always
        None (see :meth:`Solver.refresh_parameters`)."""
        self.update_parameters()
        return None

    def _implicit_system(self) -> BaraffWitkinSystem:
        """The implicit method's linear system (the symplectic method has none)."""
        if self._system is None:
            raise RuntimeError(f"FastMassSpring(method={self.method!r}) has no implicit linear system")
        return self._system

    def velocity_damping(self, dt: float) -> float:
        """δ for a step of ``dt`` [s]: exp(−cΔt) when ``damping_rate`` c is set, else the fixed δ."""
        if self.damping_rate is not None:
            return math.exp(-self.damping_rate * dt)
        return self.velocity_damping_factor

    def _external(self, control: Control | None, x: wp.array) -> wp.array:
        if control is None:
            return self._f_zero
        if control.drag_index < 0:
            return control.particle_f
        m = self.model
        wp.copy(self._f_work, control.particle_f)
        wp.launch(
            add_drag_force,
            1,
            [
                control.drag_index,
                m.vec3(*control.drag_target),
                m.s(control.drag_stiffness),
                m.s(control.drag_max_force),
                x,
                self._f_work,
            ],
            device=m.device,
        )
        return self._f_work

    def _commands(self, state_in: State, state_out: State, f_ext: wp.array, dt: float) -> list:
        """Pre-recorded launches for this (state_in, state_out, forces, dt): no argument packing per step."""
        # δ is baked into the recorded launches: a damping_rate set between frames must record new ones.
        vd = self.velocity_damping(dt)
        key = (state_in.particle_q.ptr, state_in.particle_qd.ptr, state_out.particle_q.ptr, f_ext.ptr, dt, vd)
        cmds = self._cmds.get(key)
        if cmds is not None:
            return cmds
        if len(self._cmds) > 8:
            self._cmds.clear()
        m, s, dev = self.model, self.model.s, self.model.device
        n = m.particle_count
        xi, vi, xo, vo = (
            state_in.particle_q,
            state_in.particle_qd,
            state_out.particle_q,
            state_out.particle_qd,
        )
        delta = s(vd)
        if self._scatter:
            cmds = [
                wp.launch(
                    _springs_scatter,
                    m.spring_count,
                    [self._spring_pairs, m.spring_rest_length, m.spring_stiffness, m.spring_damping]
                    + [self._damped, xi, vi, self._f_springs],
                    device=dev,
                    record_cmd=True,
                ),
                wp.launch(
                    _symplectic_update,
                    n,
                    [m.particle_inv_mass, m.gravity_vec, f_ext, xi, vi, s(dt), delta]
                    + [self._f_springs, xo, vo],
                    device=dev,
                    record_cmd=True,
                ),
            ]
            cmds = [c for c in cmds if c is not None]  # a launch over no springs records nothing
        elif self.method == "symplectic":
            args: list[Any] = [self.adj_offsets, self.adj_neighbor, self._adj_param, m.particle_inv_mass]
            args += [m.gravity_vec, self._damped, f_ext, xi, vi, s(dt), delta, xo, vo]
            kernel = GATHER_KERNELS[self.gather]
            if self._ell is not None:
                kernel = ell_gather_kernel(self._ell.slots)
                args[:3] = [self._ell.lengths, self._ell.neighbor, self._ell.param]
            lanes = TILE_LANES.get(self.gather)
            if lanes is not None:  # a block of lanes per particle (1 on the CPU)
                cmd = wp.launch_tiled(
                    kernel, dim=n, inputs=args, device=dev, block_dim=lanes, record_cmd=True
                )
            else:
                cmd = wp.launch(kernel, n, args, device=dev, block_dim=self.block_dim, record_cmd=True)
            cmds = [cmd]
        else:
            h = s(dt)
            bw = self._implicit_system()
            cmds = [
                wp.launch(
                    _bw_assemble,
                    n,
                    [
                        *bw.model_inputs(),
                        f_ext,
                        xi,
                        vi,
                        h,
                        s(self.theta),
                        bw.block,
                        bw.precond,
                        bw.r,
                        bw.z,
                        bw.p[0],
                        bw.dv,
                        bw.scalars,
                    ],
                    device=dev,
                    record_cmd=True,
                )
            ]
            cmds += bw.cg(record=True)
            cmds.append(
                wp.launch(
                    _bw_finish,
                    n,
                    [m.particle_inv_mass, xi, vi, bw.dv, h, s(self.theta), delta, xo, vo],
                    device=dev,
                    record_cmd=True,
                )
            )
        self._cmds[key] = cmds
        return cmds

    def _launch_cg(self, cg: list) -> None:
        """Launch the recorded CG iterations (two launches each) in chunks of ``cg_check_every``, stopping
        after the chunk in which the residual reached ``cg_tol``; record how many iterations that took."""
        total = len(cg) // 2
        if capturing(self.model.device):
            # In a graph: every iteration, no host read (converged ones skip their work on the device);
            # the iteration statistics count directly launched steps only.
            for cmd in cg:
                cmd.launch()
            return
        every = self.cg_check_every or total
        tol2 = self.cg_tol**2
        done, used = 0, None
        while done < total and used is None:
            end = min(total, done + every)
            for cmd in cg[2 * done : 2 * end]:
                cmd.launch()
            done = end
            used = self._converged_at(done, tol2)  # one host read per chunk
        self.last_cg_iterations = total if used is None else used
        self.cg_steps += 1
        self.cg_iterations_total += self.last_cg_iterations

    def _converged_at(self, k_max: int, tol2: float) -> int | None:
        """The first iteration k ≤ ``k_max`` whose residual rz_k ≤ tol²·rz_0 (one host read), else None."""
        sc = self._implicit_system().scalars.numpy()
        rz = sc[0 : 2 * k_max + 1 : 2]
        hit = np.flatnonzero(rz <= tol2 * sc[0])
        return int(hit[0]) if hit.size else None

    def step(self, state_in: State, state_out: State, control: Control | None, dt: float) -> None:
        """Advance by ``dt`` [s]: fused step, then kinematic targets, ground contact, contact handlers."""
        if self._recorded is not None:
            self._recorded.step(state_in, state_out, control, dt)
            return
        m = self.model
        f_ext = self._external(control, state_in.particle_q)
        cmds = self._commands(state_in, state_out, f_ext, float(dt))

        def integrate(x: wp.array, v: wp.array) -> None:
            # (x, v) are state_out's arrays here (no tape: recorded steps went to ForceSolver above), which
            # the commands were built to write.
            if self.method == "implicit":
                self._implicit_system().scalars.zero_()
                cmds[0].launch()
                self._launch_cg(cmds[1:-1])
                cmds[-1].launch()
            else:
                for cmd in cmds:
                    cmd.launch()

        # x¹ = x + h(v + θΔv): friction's Δv_t after the step moves a particle by θhΔv_t (hΔv_t explicitly).
        shift = self.theta if self.method == "implicit" else 1.0
        finish_step(
            m,
            control,
            state_in,
            state_out,
            dt,
            integrate,
            ground=self._ground,
            collisions=self.collisions,
            contact=(1.0, 1.0, shift),
        )

    def step_frame(
        self, state: State, spare: State, control: Control | None, dt: float, substeps: int
    ) -> bool:
        """Advance ``state`` by ``substeps`` symplectic steps of ``dt`` [s] in one launch where
        ``fused_frame`` allows (the end state in ``state`` for an even count, in ``spare`` for an odd one,
        as ping-pong stepping leaves it; ``spare`` is overwritten); False (nothing done) where it does not.

        Raises:
            ValueError: ``fused_frame=True`` with a strided state or control array.
        """
        if self._fused is None:
            return False
        f_ext = self._f_zero if control is None else control.particle_f
        delta = self.velocity_damping(dt)
        args = (state, spare, control, f_ext, self._f_work, float(dt), delta, int(substeps), self._damped)
        if self._fused.launch(*args):
            return True
        if self.fused_frame:
            raise ValueError("FastMassSpring(fused_frame=True) cannot fuse this frame: a strided state array")
        return False

    def frame_is_one_launch(self) -> bool:
        """True where frames are fused (``fused_frame_blocker`` is None): one launch on the CPU."""
        return self._fused is not None

    def graph_blocker(self) -> str | None:
        """None without a tape: explicit kernels, and implicit steps whose CG stops on the device when
        captured (a converged iteration is a no-op; ``_launch_cg``)."""
        if self._recorded is not None:
            return "a differentiable model's steps write fresh arrays each step"
        return self._collisions_blocker()

    def describe(self) -> dict:
        """Solver, method and options."""
        return {
            "solver": "FastMassSpring",
            "integrator": "SymplecticEuler"
            if self.method == "symplectic"
            else ("BaraffWitkin" if self.theta == 1.0 else f"BaraffWitkin(theta={self.theta:g})"),
            "cg_iterations": self.cg_iterations if self.method == "implicit" else 0,
            "kernel": self.kernel if self.method == "symplectic" else "gather",
            "gather": self.gather,
            "fused_frame": self.fused_frame_blocker is None,
            "velocity_damping": self.velocity_damping_factor,
            "damping_rate": self.damping_rate,
        }
