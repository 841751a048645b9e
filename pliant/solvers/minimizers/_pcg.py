"""Newton's method with every decision on the device (``MinimizerOptions(linear_solver="pcg")``): a step is
a fixed program of launches, replayable as a CUDA (or Warp CPU) graph, with no host read inside it.

The iteration is :func:`pliant.solvers.minimizers.minimize_incremental_potential`'s (same gradient, assembly,
round-off floor of the tolerance, step bound, Armijo line search and stopping rules), with three changes
that keep the host out of the loop:

* **the linear solve** is block-Jacobi preconditioned CG on the assembled BSR Hessian
  (:mod:`._pcg_kernels`), in chunks of :data:`CG_CHUNK` iterations that freeze once the relative residual
  reaches ``cg_tol`` (a frozen iteration launches but changes nothing);
* **the loops** (Newton iterations, CG chunks, line-search trials) are ``wp.capture_while`` on int32 flags
  that one-thread kernels set from the device's statistics. Launched directly, ``capture_while`` reads the
  flag once per pass (a CPU memory read; on CUDA a 4-byte copy and a stream sync); captured in a graph they
  are conditional nodes and a step reads nothing;
* **the step bound** of the energies is taken on the device (:meth:`pliant.energies.Energy.max_step_into`);
  an energy without a device bound falls back to its host :meth:`~pliant.energies.Energy.max_step`, and
  the solver then reports the step as not replayable (:func:`graph_blocker`).

Exact Hessians (``project_psd=False``) are used as asked; ``"auto"`` projects from the first iteration
(its switch is a host decision). The statistics stay on the device: :class:`DeviceNewtonStats` reads them
when asked (one host read), so ``solver.last_stats`` describes the latest step, replayed or launched.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from ..._warp import launch
from . import _pcg_kernels as K
from ._adjoint import differentiable
from ._assembly import assemble, control_terms, launch_gradient, stiffness_ratio
from ._band import BandLDL
from ._kernels import _step_stats, trial_point
from ._options import band_solve, step_settings
from ._problem import DeviceNewtonStats, Workspace, cache_of, workspace_of
from ._slots import (
    ACCEPTED,
    ALPHA,
    BACKTRACKS,
    CONVERGED,
    GNORM,
    ITER,
    PHI0,
    RESIDUALS,
    STEP_NORM,
    STEPS,
    TOL,
    TOTAL,
    TRIALS,
)

if TYPE_CHECKING:
    from ...energies import Energy
    from ...integrators import ImplicitOptionsLike
    from ...model import Model
    from ._options import MinimizerLike
    from ._problem import PotentialProblem

#: CG iterations per chunk (even: the two search-direction buffers alternate and a chunk ends where it
#: began). A chunk's iterations past convergence are frozen launches; launched directly, each chunk costs one
#: flag read.
CG_CHUNK = 8

#: How CG's dot products reduce: "atomic" (every thread adds its term to the one scalar) or "tile" (a block
#: sum by ``wp.tile_sum``, then one atomic add per block; :mod:`._pcg_kernels`). Read when a solver's
#: device Newton is set up (its first step), so that solvers made under either setting run side by side.
#: "tile": 1.72x faster steps on the 30³ soft box on an H100 (5.83 against 10.03 ms), the same Newton
#: iterations; on the CPU both add the same terms in the same order.
REDUCTIONS = ("atomic", "tile")
REDUCTION = "tile"


# ----------------------------------------------------------------------------------------------- kernels
@wp.kernel(enable_backward=False)
def _newton_begin(
    tol_opt: wp.float64,
    floor: wp.float64,
    gstats_in: wp.array(dtype=Any),
    state_out: wp.array(dtype=wp.float64),
    counts_out: wp.array(dtype=wp.int32),
    cg_counts_out: wp.array(dtype=wp.int32),
    residuals_out: wp.array(dtype=wp.float64),
    go_out: wp.array(dtype=wp.int32),
):
    # At x̃: the tolerance with its round-off floor 8 eps max|x| / h (``floor`` = 8 eps / h), and the first
    # test against the tolerance as given (at x̃ the gradient is no noise).
    g0 = wp.float64(gstats_in[0])
    state_out[TOL] = wp.max(tol_opt, floor * wp.max(wp.float64(gstats_in[1]), wp.float64(1.0)))
    state_out[STEP_NORM] = wp.float64(0.0)
    state_out[GNORM] = g0
    residuals_out[0] = g0
    counts_out[ITER] = 0
    counts_out[ACCEPTED] = 0
    counts_out[BACKTRACKS] = 0
    counts_out[RESIDUALS] = 1
    counts_out[STEPS] = counts_out[STEPS] + 1
    cg_counts_out[K.ITERATIONS] = 0
    converged = 0
    if g0 <= tol_opt:
        converged = 1
    counts_out[CONVERGED] = converged
    go_out[0] = 1 - converged


@wp.kernel(enable_backward=False)
def _newton_iteration(
    h2: wp.float64,
    gstats_in: wp.array(dtype=Any),
    state_out: wp.array(dtype=wp.float64),
    ratio_out: wp.array(dtype=Any),
):
    # Φ at the iterate, the reference of the line search; the stiffness ratio's accumulator cleared.
    state_out[PHI0] = wp.float64(gstats_in[2]) + h2 * wp.float64(gstats_in[3])
    ratio_out[0] = type(ratio_out[0])(0.0)


@wp.kernel(enable_backward=False)
def _first_floor(
    eps: wp.float64,
    h: wp.float64,
    gstats_in: wp.array(dtype=Any),
    ratio_in: wp.array(dtype=Any),
    counts_in: wp.array(dtype=wp.int32),
    state_io: wp.array(dtype=wp.float64),
):
    # After the first assembly: one ulp of position moves ∇Φ_i/(m_i h) by eps max|x| max_i(H_ii/m_i) / h.
    if counts_in[ITER] == 0:
        g1 = wp.max(wp.float64(gstats_in[1]), wp.float64(1.0))
        state_io[TOL] = wp.max(state_io[TOL], eps * g1 * wp.float64(ratio_in[0]) / h)


@wp.kernel(enable_backward=False)
def _bound_reset(bound_out: wp.array(dtype=Any)):
    bound_out[0] = type(bound_out[0])(1.0)


@wp.kernel(enable_backward=False)
def _search_begin(
    bound_in: wp.array(dtype=Any),
    state_out: wp.array(dtype=wp.float64),
    counts_out: wp.array(dtype=wp.int32),
    tstats_out: wp.array(dtype=Any),
    go_out: wp.array(dtype=wp.int32),
):
    # α = min(1, the energies' step bound); Φ's accumulators cleared for the first trial.
    state_out[ALPHA] = wp.min(wp.float64(1.0), wp.float64(bound_in[0]))
    counts_out[TRIALS] = 0
    counts_out[ACCEPTED] = 0
    tstats_out[0] = type(tstats_out[0])(0.0)
    tstats_out[1] = type(tstats_out[0])(0.0)
    go_out[0] = 1


@wp.kernel(enable_backward=False)
def _trial_point_at(
    inv_mass: wp.array(dtype=Any),
    mass: wp.array(dtype=Any),
    state: wp.array(dtype=wp.float64),
    x_in: wp.array(dtype=Any),
    dx_in: wp.array(dtype=Any),
    x_tilde_in: wp.array(dtype=Any),
    x_out: wp.array(dtype=Any),
    stats_out: wp.array(dtype=Any),
):
    # x_out = x + α Δx (free particles; α from the device) and stats[0] += ½‖x_out − x̃‖²_M.
    i = wp.tid()
    m = mass[i]
    x, e = trial_point(inv_mass[i], m, type(m)(state[ALPHA]), x_in[i], dx_in[i], x_tilde_in[i])
    x_out[i] = x
    wp.atomic_add(stats_out, 0, e)


@wp.kernel(enable_backward=False)
def _search_check(
    h2: wp.float64,
    eps: wp.float64,
    max_trials: int,
    state_io: wp.array(dtype=wp.float64),
    counts_io: wp.array(dtype=wp.int32),
    tstats_io: wp.array(dtype=Any),
    go_out: wp.array(dtype=wp.int32),
):
    # Armijo on Φ with an allowance for the round-off of its terms; else halve α, up to ``max_trials``
    # halvings (the host line search's rule, trial for trial).
    s0 = wp.float64(tstats_io[0])
    s1 = wp.float64(tstats_io[1])
    gdx = wp.float64(tstats_io[3])
    phi0 = state_io[PHI0]
    alpha = state_io[ALPHA]
    phi = s0 + h2 * s1
    slack = wp.float64(64.0) * eps * (wp.abs(s0) + h2 * wp.abs(s1) + wp.abs(phi0))
    go = 0
    if phi <= phi0 + wp.float64(1e-4) * alpha * gdx + slack:
        counts_io[ACCEPTED] = 1
    else:
        state_io[ALPHA] = alpha * wp.float64(0.5)
        counts_io[BACKTRACKS] = counts_io[BACKTRACKS] + 1
        if counts_io[TRIALS] < max_trials:
            counts_io[TRIALS] = counts_io[TRIALS] + 1
            tstats_io[0] = type(tstats_io[0])(0.0)
            tstats_io[1] = type(tstats_io[0])(0.0)
            go = 1
    go_out[0] = go


@wp.kernel(enable_backward=False)
def _take_step(counts: wp.array(dtype=wp.int32), x_trial_in: wp.array(dtype=Any), x_out: wp.array(dtype=Any)):
    i = wp.tid()
    if counts[ACCEPTED] != 0:
        x_out[i] = x_trial_in[i]


@wp.kernel(enable_backward=False)
def _newton_check(
    h: wp.float64,
    max_iterations: int,
    gstats_in: wp.array(dtype=Any),
    tstats_in: wp.array(dtype=Any),
    state_io: wp.array(dtype=wp.float64),
    counts_io: wp.array(dtype=wp.int32),
    residuals_out: wp.array(dtype=wp.float64),
    go_out: wp.array(dtype=wp.int32),
):
    # Stop on convergence, on a rejected step (the round-off floor, or no descent), on a step far below
    # the tolerance (stagnation) or at the iteration cap.
    it = counts_io[ITER] + 1
    counts_io[ITER] = it
    counts_io[TOTAL] = counts_io[TOTAL] + 1
    step = state_io[ALPHA] * wp.float64(tstats_in[2]) / h
    state_io[STEP_NORM] = step
    go = 0
    if counts_io[ACCEPTED] != 0:
        g0 = wp.float64(gstats_in[0])
        state_io[GNORM] = g0
        residuals_out[counts_io[RESIDUALS]] = g0
        counts_io[RESIDUALS] = counts_io[RESIDUALS] + 1
        tol = state_io[TOL]
        if g0 <= tol:
            counts_io[CONVERGED] = 1
        elif step > wp.float64(1e-3) * tol and it < max_iterations:
            go = 1
    go_out[0] = go


# ------------------------------------------------------------------------------------------------ solver
class DeviceCG:
    """Block-Jacobi preconditioned CG on a BSR(3×3) matrix whose stopping test runs on the device.

    ``solve`` launches x = −H⁻¹ g (relative residual ``tol``, at most ``cap`` iterations, launched in whole
    chunks of :data:`CG_CHUNK`) and reads nothing back; ``iterations()`` reads the count (one read).

    Args:
        model: the Model (device, dtype, inverse masses: fixed rows are left at 0).
        ws: the Newton workspace whose BSR matrix ``ws.A`` (values ``ws.values``) is solved.
        reduction: how the dot products reduce, one of :data:`REDUCTIONS` (None: :data:`REDUCTION`).
    """

    def __init__(self, model: Model, ws: Workspace, reduction: str | None = None) -> None:
        n, d, v3 = model.particle_count, model.device, model.vec3
        reduction = REDUCTION if reduction is None else reduction
        if reduction not in REDUCTIONS:
            raise ValueError(f"DeviceCG reduction must be one of {REDUCTIONS}, got {reduction!r}")
        self.model, self.ws, self.reduction = model, ws, reduction
        self.r, self.z, self.q = (wp.zeros(n, dtype=v3, device=d) for _ in range(3))
        self.p = (wp.zeros(n, dtype=v3, device=d), wp.zeros(n, dtype=v3, device=d))
        self.blocks = wp.zeros(n, dtype=model.mat33, device=d)
        self.scalars = wp.zeros(K.scalar_slots(CG_CHUNK), dtype=model.scalar, device=d)
        self.limit = wp.zeros(1, dtype=model.scalar, device=d)
        self.counts = wp.zeros(K.COUNT_SLOTS, dtype=wp.int32, device=d)
        self.go = wp.zeros(1, dtype=wp.int32, device=d)

    def solve(self, grad: wp.array, x_out: wp.array, tol: float, cap: int) -> None:
        """x_out = −H⁻¹ grad to ‖r‖ ≤ tol ‖grad‖ (device; no host read when captured)."""
        m, ws = self.model, self.ws
        n, d = m.particle_count, m.device
        # The dot-product launches: all rows, or whole blocks of rows for the block sums.
        if self.reduction == "tile":
            tiled, rows, block = K.TILE, K.tiled_dim(n), K.BLOCK_DIM
        else:
            tiled, rows, block = K.ATOMIC, n, None
        launch(K.cg_block_inverse, n, [m.particle_inv_mass, ws.diag_slots, ws.values, self.blocks], device=d)
        launch(K.cg_reset, 1, [self.limit, self.scalars, self.counts], device=d)
        launch(
            K.cg_begin,
            rows,
            [tiled, n, self.blocks, grad, x_out, self.r, self.z, *self.p, self.scalars],
            device=d,
            block_dim=block,
        )
        launch(K.cg_start, 1, [wp.float64(tol * tol), self.scalars, self.limit, self.go], device=d)
        checks = -(-cap // CG_CHUNK)
        offsets, columns = ws.A.offsets, ws.A.columns

        def chunk() -> None:
            for j in range(CG_CHUNK):
                prev = 0 if j == 0 else K.slot(j - 1)[0]
                p_old, p_new = self.p[j % 2], self.p[(j + 1) % 2]
                launch(
                    K.cg_apply,
                    rows,
                    [tiled, n, offsets, columns, ws.values, self.limit, self.counts, self.z, p_old, j, prev]
                    + [CG_CHUNK, cap, p_new, self.q, self.scalars],
                    device=d,
                    block_dim=block,
                )
                launch(
                    K.cg_update,
                    rows,
                    [tiled, n, self.blocks, self.limit, p_new, self.q, j, CG_CHUNK, cap, x_out, self.r]
                    + [self.z, self.scalars, self.counts],
                    device=d,
                    block_dim=block,
                )
            launch(
                K.cg_chunk_end,
                1,
                [CG_CHUNK, checks, self.limit, self.scalars, self.counts, self.go],
                device=d,
            )

        wp.capture_while(self.go, chunk)

    def iterations(self) -> int:
        """CG iterations that moved since the counter was last cleared (one host read)."""
        return int(self.counts.numpy()[K.ITERATIONS])


class _DeviceNewton:
    """The device Newton's buffers for one workspace: the linear solver (CG, or the banded LDLᵀ with
    ``band``), flags, float64 scalars, counters, residuals."""

    def __init__(self, model: Model, ws: Workspace, max_iterations: int, band: bool = False) -> None:
        d = model.device
        self.ws = ws
        self.key = (id(ws), max_iterations, band)
        #: The banded LDLᵀ (True) or block-Jacobi CG (False).
        self.band = band
        self.cg: DeviceCG | BandLDL = BandLDL(model, ws) if band else DeviceCG(model, ws)
        self.state = wp.zeros(5, dtype=wp.float64, device=d)
        self.counts = wp.zeros(8, dtype=wp.int32, device=d)
        self.residuals = wp.zeros(max_iterations + 1, dtype=wp.float64, device=d)
        self.go = wp.zeros(1, dtype=wp.int32, device=d)
        self.go_search = wp.zeros(1, dtype=wp.int32, device=d)
        self.bound = wp.zeros(1, dtype=model.scalar, device=d)

    def reset(self) -> None:
        """Forget what a step leaves for the next: the band solve's lagged factor (CG keeps nothing)."""
        if isinstance(self.cg, BandLDL):
            self.cg.reset()


def _device_newton(
    problem: PotentialProblem, ws: Workspace, max_iterations: int, band: bool = False
) -> _DeviceNewton:
    cache = cache_of(problem)
    dn = cache.pcg
    if not isinstance(dn, _DeviceNewton) or dn.key != (id(ws), max_iterations, band):
        dn = _DeviceNewton(problem.model, ws, max_iterations, band)
        cache.pcg = dn
    if isinstance(dn.cg, BandLDL):
        dn.cg.take_state(cache)  # a checkpoint's, restored before this first step
    return dn


def host_bound_energies(energies: list, model: Model, x: wp.array, dx: wp.array, bound: wp.array) -> list:
    """Lower ``bound[0]`` by every energy's device step bound; return the energies whose bound needs the
    host (their :meth:`max_step`)."""
    return [e for e in energies if not e.max_step_into(model, x, dx, bound)]


def _device_bound(cls: type[Energy]) -> bool:
    """Whether an energy class bounds the step on the device (or has no bound)."""
    from ...energies import Energy

    return cls.max_step is Energy.max_step or cls.max_step_into is not Energy.max_step_into


def graph_blocker(energies: list, device: wp.DeviceLike) -> str | None:
    """Why a device-Newton step on ``device`` cannot be replayed as a graph (an energy whose step bound is
    read on the host; CUDA without conditional graph nodes), or None."""
    host = [type(e).__name__ for e in energies if not _device_bound(type(e))]
    if host:
        return f"the step bound of {', '.join(host)} is read on the host (no Energy.max_step_into)"
    if wp.get_device(device).is_cuda and not wp.is_conditional_graph_supported():
        return "the device Newton loops on device flags (wp.capture_while): CUDA 12.4+ driver and toolkit"
    return None


@differentiable
def minimize_device(
    solver: PotentialProblem,
    t: float,
    h: float,
    x_tilde: wp.array,
    x_ref: wp.array,
    v_ref: wp.array,
    x_out: wp.array,
    options: ImplicitOptionsLike = None,
    minimizer: MinimizerLike = None,
) -> DeviceNewtonStats:
    """x_out = argmin Φ by Newton with device-side PCG, line search and stopping tests (see the module).

    Arguments as :func:`~pliant.solvers.minimizers.minimize_incremental_potential`; the minimiser's
    ``cg_tol`` and ``cg_max_iterations`` set the CG. Returns (and stores in ``solver.last_stats``) a
    :class:`DeviceNewtonStats`, which reads the device only when asked.
    """
    m = solver.model
    n, d = m.particle_count, m.device
    ws = workspace_of(solver)
    opts, mz = step_settings(options, minimizer)
    max_it = int(opts.max_newton_iterations)
    dn = _device_newton(solver, ws, max_it, band_solve(mz, d))
    eps = float(np.finfo(np.float32 if m.dtype == "float32" else np.float64).eps)
    cg_tol = max(float(mz.cg_tol), 30.0 * eps)
    project = opts.project_psd is not False
    h2 = h * h
    f64 = wp.float64

    for e in solver.energies:
        if e.dissipative:
            e.begin_step(m, x_ref, v_ref, h)
    wp.copy(x_out, x_tilde)
    x = x_out
    band = dn.cg if isinstance(dn.cg, BandLDL) else None
    if band is None:
        launch_gradient(solver, ws, x, x_tilde, h)
    else:
        band.warm_start(solver, x_tilde, x, h, lambda at: launch_gradient(solver, ws, at, x_tilde, h))
    launch(
        _newton_begin,
        1,
        [f64(opts.newton_tol), f64(8.0 * eps / h), ws.gstats, dn.state, dn.counts, dn.cg.counts]
        + [dn.residuals, dn.go],
        device=d,
    )

    def trial() -> None:
        launch(
            _trial_point_at,
            n,
            [m.particle_inv_mass, m.particle_mass, dn.state, x, ws.dx, x_tilde, ws.x_trial, ws.tstats],
            device=d,
        )
        for e in solver.energies:
            e.value(m, ws.x_trial, ws.tstats_e)
        control_terms(solver, ws, ws.x_trial, ws.egrad_scratch, ws.tstats_e)
        launch(
            _search_check,
            1,
            [f64(h2), f64(eps), int(opts.max_line_search), dn.state, dn.counts, ws.tstats, dn.go_search],
            device=d,
        )

    def reassemble() -> None:
        assemble(solver, ws, x, h, project)
        launch(stiffness_ratio, n, [m.particle_inv_mass, ws.diag_slots, ws.values, ws.hstats], device=d)

    def factor() -> None:
        # The band solve's factorisation, when its lagging rule asks (the ratio: the factor's Hessian's).
        assert band is not None  # launched only on the band solve's branch
        ws.hstats.zero_()
        reassemble()
        band.factor(h)

    def iteration() -> None:
        if band is None:
            launch(_newton_iteration, 1, [f64(h2), ws.gstats, dn.state, ws.hstats], device=d)
            reassemble()
        else:
            launch(_newton_iteration, 1, [f64(h2), ws.gstats, dn.state, band.ratio_scratch], device=d)
            band.iteration_begin(dn.state)
            wp.capture_if(band.refactor, factor)
        launch(_first_floor, 1, [f64(eps), f64(h), ws.gstats, ws.hstats, dn.counts, dn.state], device=d)
        dn.cg.solve(ws.grad, ws.dx, cg_tol, int(mz.cg_max_iterations))
        ws.tstats.zero_()
        launch(_step_stats, n, [m.particle_inv_mass, ws.grad, ws.dx, ws.tstats_step], device=d)
        launch(_bound_reset, 1, [dn.bound], device=d)
        for e in host_bound_energies(solver.energies, m, x, ws.dx, dn.bound):
            dn.bound.fill_(m.s(min(float(dn.bound.numpy()[0]), float(e.max_step(m, x, ws.dx)))))
        launch(_search_begin, 1, [dn.bound, dn.state, dn.counts, ws.tstats, dn.go_search], device=d)
        wp.capture_while(dn.go_search, trial)
        launch(_take_step, n, [dn.counts, ws.x_trial, x], device=d)
        launch_gradient(solver, ws, x, x_tilde, h)
        launch(
            _newton_check,
            1,
            [f64(h), max_it, ws.gstats, ws.tstats, dn.state, dn.counts, dn.residuals, dn.go],
            device=d,
        )
        if band is not None:
            band.decide(dn.state, dn.counts, dn.go, max_it)

    if band is not None:
        band.step_begin(h)
    wp.capture_while(dn.go, iteration)
    if band is not None:
        band.keep_correction(x, x_tilde, h)
    stats = DeviceNewtonStats(dn, project)
    solver.last_stats = stats
    return stats
