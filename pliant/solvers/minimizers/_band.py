"""Newton's linear solve for small problems, on the device: banded LDLᵀ in a bandwidth-reducing order,
factorised again only when convergence slows (``MinimizerOptions(linear_solver="band")``; what
``method="auto"`` takes on the CPU for small bodies, :func:`._options.small_problem`).

The device Newton (:mod:`._pcg`) keeps every decision on the device, so a Simulator replays its frames as
graphs, on the CPU too (Warp's CPU graphs): no Python per step. On a 117-particle beam its block-Jacobi CG
needed ~90 iterations per Newton step (two launches each); here a solve is one launch:

* :func:`_band_scatter`: the lower triangle of the assembled BSR(3×3) Hessian into a band matrix in float64,
  rows and columns permuted by reverse Cuthill–McKee on the particle graph (a 12×2×2-cell beam's
  half-bandwidth is 10 particles, 32 scalar columns);
* :func:`_band_factor`: one thread factors H = L D Lᵀ in place (Crout order, no pivoting), N b²/2
  multiply-adds for N = 3n unknowns and half-bandwidth b (``_band_order.band_work``);
* :func:`_band_solve`: one thread solves L D Lᵀ Δx = −∇Φ, 2 N b multiply-adds.

**Lagging.** On the CPU the Hessian's assembly (the neo-Hookean kernel with its PSD projection: 0.33 ms
for 288 tets in float32, 0.59 ms in float64) and the factorisation (0.08 ms) cost more than the rest of a
Newton iteration together (~0.05 ms). So the factor is kept while it works (:func:`_lag_decide`): the next
iteration factorises afresh when an iteration left the gradient norm above :data:`LAG_RATE` times its
value at the iteration's start, a
step's first iteration when the previous step needed more than :data:`LAG_MAX_ITERATIONS` iterations or h
changed, and where Newton would stop unconverged with a lagged factor (a rejected step, stagnation) it goes
on with a fresh one. The iteration then is Newton's with a lagged Hessian, converging to the same
tolerance (tests/test_band_newton.py: within 1e-9 m of the host Newton, L-BFGS and the device Newton with
CG, tolerances tight, float64); with
``LAG_RATE = 0``, ``LAG_MAX_ITERATIONS = -1`` and no warm start every iteration factorises and the iterates
are the host Newton's.

**Warm start.** As L-BFGS's: a step starts from x̃ plus the correction x − x̃ of the last two steps,
extrapolated (1.5 c − 0.5 c_last), when that lowers Φ below Φ(x̃), else from x̃; decided on the device
(``wp.capture_if``). On the beam it cuts the iterations per step from 1.6 to 1.1 (float32).

LDLᵀ rather than Cholesky: with PSD-projected Hessians (the default) H ⪰ M is positive definite and both
agree; with exact ones (``project_psd=False``) H may be indefinite, and LDLᵀ still gives the exact Newton
step, as the host Newton's sparse LU does, which the line search then accepts or rejects. A zero or
non-finite pivot (a singular H) gives Δx = 0: the line search accepts no movement and Newton stops (after
one retry with a fresh factor when the singular one was lagged); such factorisations are counted
(:attr:`BandLDL.failures`).

What a step leaves for the next (the factor, its Hessian's stiffness ratio, the lagging flags, the warm
start's corrections) is forgotten by ``Simulator.restart`` (``MinimizerCache.reset``: a restarted run is a
new one, bit for bit) and saved in checkpoints (``band_*`` keys: a resumed run continues bit for bit).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from ..._warp import launch
from ._pcg_kernels import COUNT_SLOTS
from ._pcg_kernels import ITERATIONS as CG_ITERATIONS
from ._pcg_kernels import TOTAL as CG_TOTAL
from ._slots import CONVERGED, GNORM, ITER

if TYPE_CHECKING:
    from ...model import Model
    from ._problem import MinimizerCache, PotentialProblem, Workspace

#: ``counts`` slot of :class:`BandLDL`: factorisations that met a zero or non-finite pivot.
FAILURES = COUNT_SLOTS
#: Lagging: a lagged factor is refreshed for the next iteration when an iteration left the gradient norm
#: above this fraction of its value at the iteration's start, and at a step's start when the previous step
#: needed more than :data:`LAG_MAX_ITERATIONS` iterations. 0 and −1: a factorisation every iteration.
#: Measured on the 12x2x2 beam (float32, 4 substeps of 1/120 s, with the warm start): 0.25 and 2 take 1.14
#: iterations and 0.07 factorisations per step, trajectory error 5.8e-5 m (L-BFGS: 5.7e-5 m); 0.5 and 3
#: 1.24 and 0.05, 6.8e-5 m; 0.1 and 1 1.09 and 0.17, 5.7e-5 m.
LAG_RATE = 0.25
LAG_MAX_ITERATIONS = 2
#: Start each step from x̃ plus the correction x − x̃ of the last steps, extrapolated, when that lowers Φ
#: (L-BFGS's warm start).
WARM_START = True

#: ``lag`` slots (float64): the gradient norm at the start of the iteration, the h of the factorisation, the
#: h of the last step (the warm start's).
G_START, FACTOR_H, WARM_H = range(3)
#: ``flags`` slots (int32): factorise before the next solve, the current iteration's factor is fresh, a
#: factor exists, the last factor is singular, iterations of the last step; a step's correction is kept
#: (for the next step's warm start), the warm start is taken, the gradient at x̃ is needed after all.
REFACTOR, FRESH, HAVE, SINGULAR, LAST_ITERATIONS, HAVE_WARM, TAKE_WARM, REDO_GRADIENT = range(8)
FLAG_SLOTS = 8


@wp.kernel(enable_backward=False)
def _band_scatter(
    inv_perm: wp.array(dtype=wp.int32),
    block_rows: wp.array(dtype=wp.int32),
    block_cols: wp.array(dtype=wp.int32),
    values: wp.array(dtype=Any),
    b: int,
    band_out: wp.array(dtype=wp.float64),
):
    # One BSR block per thread: its entries on or below the diagonal, at (I, J) of the permuted matrix,
    # go to band[I (b + 1) + I − J]. Each lower entry has one block, so nothing is added twice.
    k = wp.tid()
    pr = inv_perm[block_rows[k]]
    pc = inv_perm[block_cols[k]]
    if pr < pc:
        return
    v = values[k]
    for a in range(3):
        for c in range(3):
            i = 3 * pr + a
            j = 3 * pc + c
            if i >= j:
                band_out[i * (b + 1) + i - j] = wp.float64(v[a, c])


# The factorisation's and the solves' loops as C++ (``wp.func_native``): in Warp's Python each band entry's
# read went through a strided, bounds-wrapping index, and one thread's loops ran at ~1.3 ns per multiply-add
# (0.19 ms per factorisation, 29 µs per solve on the beam); here the same sums in the same order run on
# raw pointers with four partial sums (a single running sum waits on each multiply-add's latency).
_LDLT = """
    const int w = b + 1;
    double* B = (double*)band.data;
    int ok = 1;
    for (int j = 0; j < size; ++j) {
        const int lo = j - b > 0 ? j - b : 0;
        double* rj = B + j * w + j;  // rj[-c]: entry (j, c)
        for (int i = lo; i < j; ++i) {
            const double* ri = B + i * w + i;
            int k = i - b > lo ? i - b : lo;
            double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
            for (; k + 3 < i; k += 4) {
                s0 += rj[-k] * ri[-k];
                s1 += rj[-k - 1] * ri[-k - 1];
                s2 += rj[-k - 2] * ri[-k - 2];
                s3 += rj[-k - 3] * ri[-k - 3];
            }
            for (; k < i; ++k) s0 += rj[-k] * ri[-k];
            rj[-i] -= (s0 + s1) + (s2 + s3);
        }
        double d = rj[-j];
        for (int i = lo; i < j; ++i) {
            const double t = rj[-i];
            const double l = t / B[i * w];
            rj[-i] = l;
            d -= t * l;
        }
        rj[-j] = d;
        if (!(d != 0.0 && d - d == 0.0)) ok = 0;  // zero, infinite or NaN
    }
    return ok;
"""

_TRISOLVE = """
    const int w = b + 1;
    const double* B = (const double*)band.data;
    double* x = (double*)work.data;
    for (int j = 0; j < size; ++j) {  // L y = r
        const double* rj = B + j * w + j;
        int k = j - b > 0 ? j - b : 0;
        double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
        for (; k + 3 < j; k += 4) {
            s0 += rj[-k] * x[k];
            s1 += rj[-k - 1] * x[k + 1];
            s2 += rj[-k - 2] * x[k + 2];
            s3 += rj[-k - 3] * x[k + 3];
        }
        for (; k < j; ++k) s0 += rj[-k] * x[k];
        x[j] -= (s0 + s1) + (s2 + s3);
    }
    for (int j = 0; j < size; ++j) x[j] /= B[j * w];  // z = D⁻¹ y
    for (int j = size - 1; j >= 0; --j) {  // Lᵀ x = z: L_ij at B[i w + i − j], i in (j, j + b]
        const int end = j + b + 1 < size ? j + b + 1 : size;
        const double* c = B + (j + 1) * w + 1;
        const int step = w + 1;
        int i = j + 1;
        double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
        for (; i + 3 < end; i += 4, c += 4 * step) {
            s0 += c[0] * x[i];
            s1 += c[step] * x[i + 1];
            s2 += c[2 * step] * x[i + 2];
            s3 += c[3 * step] * x[i + 3];
        }
        for (; i < end; ++i, c += step) s0 += c[0] * x[i];
        x[j] -= (s0 + s1) + (s2 + s3);
    }
    return 0;
"""


@wp.func_native(_LDLT)
def _ldlt(size: int, b: int, band: wp.array(dtype=wp.float64)) -> int:
    """H = L D Lᵀ in place in the band (rows of b + 1 entries, the diagonal last); 1, or 0 after a zero or
    non-finite pivot. Row j in Crout order: t_i = H_ji − Σ_k t_k L_ik for i < j (t_k = L_jk d_k, kept in row
    j's storage until the row is done), then L_ji = t_i / d_i and d_j = H_jj − Σ_i t_i L_ji."""
    ...


@wp.func_native(_TRISOLVE)
def _trisolve(size: int, b: int, band: wp.array(dtype=wp.float64), work: wp.array(dtype=wp.float64)) -> int:
    """work ← (L D Lᵀ)⁻¹ work with :func:`_ldlt`'s factor."""
    ...


@wp.kernel(enable_backward=False)
def _band_factor(
    n: int,
    b: int,
    h: wp.float64,
    band_io: wp.array(dtype=wp.float64),
    counts_io: wp.array(dtype=wp.int32),
    lag_io: wp.array(dtype=wp.float64),
    flags_io: wp.array(dtype=wp.int32),
):
    # One thread: the factorisation and its bookkeeping.
    ok = _ldlt(3 * n, b, band_io)
    counts_io[CG_ITERATIONS] = counts_io[CG_ITERATIONS] + 1
    counts_io[CG_TOTAL] = counts_io[CG_TOTAL] + 1
    if ok == 0:
        counts_io[FAILURES] = counts_io[FAILURES] + 1
    flags_io[SINGULAR] = 1 - ok
    flags_io[HAVE] = 1
    flags_io[REFACTOR] = 0
    lag_io[FACTOR_H] = h


@wp.kernel(enable_backward=False)
def _band_solve(
    perm: wp.array(dtype=wp.int32),
    b: int,
    grad: wp.array(dtype=Any),
    band: wp.array(dtype=wp.float64),
    flags: wp.array(dtype=wp.int32),
    dx_out: wp.array(dtype=Any),
    work_io: wp.array(dtype=wp.float64),
):
    # One thread: Δx = −H⁻¹ g in the band's order; Δx = 0 after a singular factorisation.
    n = perm.shape[0]
    for p in range(n):
        g = grad[perm[p]]
        for a in range(3):
            work_io[3 * p + a] = -wp.float64(g[a])
    _trisolve(3 * n, b, band, work_io)
    ok = flags[SINGULAR] == 0
    for p in range(n):
        v = dx_out[p] * type(dx_out[p][0])(0.0)
        if ok:
            for a in range(3):
                v[a] = type(v[0])(work_io[3 * p + a])
        dx_out[perm[p]] = v


# --------------------------------------------------------------------------- when to factorise (lagging)
@wp.kernel(enable_backward=False)
def _lag_step_begin(
    h: wp.float64, max_lagged: int, lag: wp.array(dtype=wp.float64), flags_io: wp.array(dtype=wp.int32)
):
    # This step's first iteration factorises afresh without a factor, at another h, or when the previous
    # step needed more than ``max_lagged`` iterations.
    r = 0
    if flags_io[HAVE] == 0 or lag[FACTOR_H] != h or flags_io[LAST_ITERATIONS] > max_lagged:
        r = 1
    flags_io[REFACTOR] = r


@wp.kernel(enable_backward=False)
def _lag_iteration_begin(
    state: wp.array(dtype=wp.float64), lag_out: wp.array(dtype=wp.float64), flags_io: wp.array(dtype=wp.int32)
):
    lag_out[G_START] = state[GNORM]
    flags_io[FRESH] = flags_io[REFACTOR]


@wp.kernel(enable_backward=False)
def _lag_decide(
    rate: wp.float64,
    max_iterations: int,
    state: wp.array(dtype=wp.float64),
    counts: wp.array(dtype=wp.int32),
    lag: wp.array(dtype=wp.float64),
    flags_io: wp.array(dtype=wp.int32),
    go_io: wp.array(dtype=wp.int32),
):
    # After the Newton test: factorise afresh for the next iteration when this one lowered the gradient
    # norm by less than ``rate``; where Newton stopped unconverged (a rejected step, stagnation) with a
    # lagged factor, go on with a fresh one instead (a fresh factor's outcome stands, as in Newton).
    it = counts[ITER]
    flags_io[LAST_ITERATIONS] = it
    if counts[CONVERGED] != 0:
        return
    if go_io[0] != 0:
        if state[GNORM] > rate * lag[G_START]:
            flags_io[REFACTOR] = 1
    elif flags_io[FRESH] == 0 and it < max_iterations:
        flags_io[REFACTOR] = 1
        go_io[0] = 1


# ------------------------------------------------------------------------------------------ warm start
@wp.kernel(enable_backward=False)
def _warm_point(
    inv_mass: wp.array(dtype=Any),
    x_tilde: wp.array(dtype=Any),
    correction: wp.array(dtype=Any),
    h: wp.float64,
    lag: wp.array(dtype=wp.float64),
    flags: wp.array(dtype=wp.int32),
    x_out: wp.array(dtype=Any),
):
    # x̃ plus the correction kept from the last steps (at the same h), free particles only.
    i = wp.tid()
    y = x_tilde[i]
    if flags[HAVE_WARM] != 0 and lag[WARM_H] == h and inv_mass[i] != type(inv_mass[i])(0.0):
        y = y + correction[i]
    x_out[i] = y


@wp.kernel(enable_backward=False)
def _warm_decide(
    h: wp.float64,
    h2: wp.float64,
    tstats: wp.array(dtype=Any),
    gstats: wp.array(dtype=Any),
    lag: wp.array(dtype=wp.float64),
    flags_io: wp.array(dtype=wp.int32),
):
    # Take the warm start when there is one and it lowers Φ below Φ(x̃) = h² E(x̃) (L-BFGS's rule).
    take = 0
    if flags_io[HAVE_WARM] != 0 and lag[WARM_H] == h:
        phi_warm = wp.float64(gstats[2]) + h2 * wp.float64(gstats[3])
        if phi_warm < h2 * wp.float64(tstats[1]):
            take = 1
    flags_io[TAKE_WARM] = take
    flags_io[REDO_GRADIENT] = 1 - take


@wp.kernel(enable_backward=False)
def _warm_keep(
    x: wp.array(dtype=Any),
    x_tilde: wp.array(dtype=Any),
    h: wp.float64,
    lag: wp.array(dtype=wp.float64),
    flags: wp.array(dtype=wp.int32),
    correction_out: wp.array(dtype=Any),
    last_out: wp.array(dtype=Any),
):
    # The next step's start: the correction c = x − x̃ extrapolated from the last two, damped by half
    # (1.5 c − 0.5 c_last, as L-BFGS's warm start), or c alone after another h.
    i = wp.tid()
    c = x[i] - x_tilde[i]
    out = c
    if flags[HAVE_WARM] != 0 and lag[WARM_H] == h:
        out = type(c[0])(1.5) * c - type(c[0])(0.5) * last_out[i]
    correction_out[i] = out
    last_out[i] = c


@wp.kernel(enable_backward=False)
def _warm_kept(h: wp.float64, lag_out: wp.array(dtype=wp.float64), flags_out: wp.array(dtype=wp.int32)):
    lag_out[WARM_H] = h
    flags_out[HAVE_WARM] = 1


class BandLDL:
    """Δx = −H⁻¹∇Φ by banded LDLᵀ on the device (see the module), with :class:`~._pcg.DeviceCG`'s
    ``solve`` and ``iterations``, and the factorisation apart (:meth:`factor`) so that it can be lagged.

    Args:
        model: the Model (device, dtype).
        ws: the Newton workspace whose BSR values ``ws.values`` are factorised.
    """

    def __init__(self, model: Model, ws: Workspace) -> None:
        n, d = model.particle_count, model.device
        self.model, self.ws = model, ws
        perm, width = ws.band_order()
        self.b = 3 * width + 2
        inv = np.empty_like(perm)
        inv[perm] = np.arange(n)
        self.perm: wp.array = wp.array(perm.astype(np.int32), dtype=wp.int32, device=d)
        self.inv_perm: wp.array = wp.array(inv.astype(np.int32), dtype=wp.int32, device=d)
        self.band = wp.zeros(3 * n * (self.b + 1), dtype=wp.float64, device=d)
        self.work = wp.zeros(3 * n, dtype=wp.float64, device=d)
        #: int32 counters in the CG's layout (its ITERATIONS slot: factorisations in the step, TOTAL: over
        #: the solver's life) and :data:`FAILURES`.
        self.counts = wp.zeros(COUNT_SLOTS + 1, dtype=wp.int32, device=d)
        #: Lagging state: float64 (:data:`G_START`, :data:`FACTOR_H`) and int32 flags (:data:`REFACTOR`, ...).
        self.lag = wp.zeros(3, dtype=wp.float64, device=d)
        #: The warm start: the next step's correction x − x̃ (extrapolated) and the last step's.
        self.correction = wp.zeros(n, dtype=model.vec3, device=d)
        self.last_correction = wp.zeros(n, dtype=model.vec3, device=d)
        self.flags = wp.zeros(FLAG_SLOTS, dtype=wp.int32, device=d)
        self.take_warm = self.flags[TAKE_WARM : TAKE_WARM + 1]
        self.redo_gradient = self.flags[REDO_GRADIENT : REDO_GRADIENT + 1]
        #: ``flags[REFACTOR]`` as the condition of ``wp.capture_if``.
        self.refactor = self.flags[REFACTOR : REFACTOR + 1]
        #: Where Newton's per-iteration clearing of the stiffness ratio goes: the ratio is the factor's.
        self.ratio_scratch = wp.zeros(1, dtype=model.scalar, device=d)
        self.rate, self.max_lagged = LAG_RATE, LAG_MAX_ITERATIONS

    def take_state(self, cache: MinimizerCache) -> None:
        """Take the state a checkpoint left in ``cache`` (:func:`band_restore_checkpoint_state`), if any."""
        _take_state(self, cache)

    def reset(self) -> None:
        """Forget the factor (the next step factorises afresh, as a new solver's first; in place, so that
        captured graphs stay valid)."""
        self.flags.zero_()
        self.lag.zero_()

    def warm_start(
        self,
        problem: PotentialProblem,
        x_tilde: wp.array,
        x: wp.array,
        h: float,
        gradient: Callable[[wp.array], None],
    ) -> None:
        """Start the step at x̃ + the kept correction when that lowers Φ (:data:`WARM_START`), else at x̃
        (``x`` holds x̃): ``x`` and ``gradient(at)``'s ∇Φ and statistics at the start, on the device."""
        from ._assembly import control_terms

        m, ws, d = self.model, self.ws, self.model.device
        if not WARM_START:
            gradient(x)
            return
        f64 = wp.float64
        ws.tstats.zero_()
        for e in problem.energies:
            e.value(m, x, ws.tstats_e)
        control_terms(problem, ws, x, ws.egrad_scratch, ws.tstats_e)
        args = [m.particle_inv_mass, x_tilde, self.correction, f64(h), self.lag, self.flags, ws.x_trial]
        launch(_warm_point, m.particle_count, args, device=d)
        gradient(ws.x_trial)
        launch(_warm_decide, 1, [f64(h), f64(h * h), ws.tstats, ws.gstats, self.lag, self.flags], device=d)
        wp.capture_if(self.take_warm, lambda: wp.copy(x, ws.x_trial))
        wp.capture_if(self.redo_gradient, lambda: gradient(x))

    def keep_correction(self, x: wp.array, x_tilde: wp.array, h: float) -> None:
        """After the step: the correction the next step's warm start adds to its x̃."""
        if not WARM_START:
            return
        f64, d = wp.float64, self.model.device
        args = [x, x_tilde, f64(h), self.lag, self.flags, self.correction, self.last_correction]
        launch(_warm_keep, self.model.particle_count, args, device=d)
        launch(_warm_kept, 1, [f64(h), self.lag, self.flags], device=d)

    def step_begin(self, h: float) -> None:
        """At a step's start (after the Newton state's): whether its first iteration factorises afresh."""
        args = [wp.float64(h), self.max_lagged, self.lag, self.flags]
        launch(_lag_step_begin, 1, args, device=self.model.device)

    def iteration_begin(self, state: wp.array) -> None:
        """At an iteration's start: the gradient norm it starts from, whether its factor is fresh."""
        launch(_lag_iteration_begin, 1, [state, self.lag, self.flags], device=self.model.device)

    def decide(self, state: wp.array, counts: wp.array, go: wp.array, max_iterations: int) -> None:
        """After Newton's test: factorise afresh for the next iteration, or go on where Newton stopped with
        a lagged factor (see :func:`_lag_decide`)."""
        launch(
            _lag_decide,
            1,
            [wp.float64(self.rate), max_iterations, state, counts, self.lag, self.flags, go],
            device=self.model.device,
        )

    def factor(self, h: float) -> None:
        """Factorise the Hessian in ``ws.values`` (assembled at step h [s]); no host read."""
        ws, d, n = self.ws, self.model.device, self.model.particle_count
        self.band.zero_()
        launch(
            _band_scatter,
            ws.nnz,
            [self.inv_perm, ws.block_rows, ws.block_cols, ws.values, self.b, self.band],
            device=d,
        )
        launch(
            _band_factor,
            1,
            [n, self.b, wp.float64(h), self.band, self.counts, self.lag, self.flags],
            device=d,
        )

    def solve(self, grad: wp.array, x_out: wp.array, tol: float = 0.0, cap: int = 0) -> None:
        """x_out = −H⁻¹ grad with the last factorisation (no host read). ``tol`` and ``cap`` are CG's,
        unused by a direct solve."""
        launch(
            _band_solve,
            1,
            [self.perm, self.b, grad, self.band, self.flags, x_out, self.work],
            device=self.model.device,
        )

    def iterations(self) -> int:
        """Factorisations in the current step (one host read)."""
        return int(self.counts.numpy()[CG_ITERATIONS])

    @property
    def failures(self) -> int:
        """Factorisations over the solver's life that met a zero or non-finite pivot (one host read)."""
        return int(self.counts.numpy()[FAILURES])


# ----------------------------------------------------------------------------------------- checkpoints
# What the band Newton keeps between steps, so that a resumed run continues bit for bit: the lagged factor,
# the stiffness ratio of its Hessian (the tolerance's round-off floor), the lagging and warm-start state and
# the warm start's corrections.
_CKPT_KEYS = (
    "band_factor",
    "band_ratio",
    "band_lag",
    "band_flags",
    "band_correction",
    "band_last_correction",
)


def band_checkpoint_state(cache: MinimizerCache) -> dict[str, np.ndarray]:
    """The band Newton's state between steps kept in ``cache`` (copies; empty without a band Newton)."""
    dn = cache.pcg
    if dn is None or not isinstance(dn.cg, BandLDL):
        return {}
    band = dn.cg
    return {
        "band_factor": band.band.numpy().copy(),
        "band_ratio": band.ws.hstats.numpy().copy(),
        "band_lag": band.lag.numpy().copy(),
        "band_flags": band.flags.numpy().copy(),
        "band_correction": band.correction.numpy().copy(),
        "band_last_correction": band.last_correction.numpy().copy(),
    }


def band_restore_checkpoint_state(problem: PotentialProblem, state: dict[str, np.ndarray]) -> None:
    """Validate :func:`band_checkpoint_state`'s arrays and give them to ``problem``'s band Newton (now, or
    when its first step sets it up).

    Raises:
        ValueError: an unknown or missing key, or an array of the wrong shape or kind, or non-finite.
    """
    unknown = sorted(set(state) - set(_CKPT_KEYS))
    if unknown:
        raise ValueError(f"unknown band-Newton state keys {unknown}")
    cache = problem.minimizer_cache
    if not state:
        cache.band_state = None
        return
    missing = sorted(set(_CKPT_KEYS) - set(state))
    if missing:
        raise ValueError(f"band-Newton state without {missing}: the keys come together (a corrupt file)")
    m = problem.model
    n = m.particle_count
    b = 3 * cache.workspace(m, problem.energies).band_order()[1] + 2
    shapes = {
        "band_factor": ((3 * n * (b + 1),), "f"),
        "band_ratio": ((1,), "f"),
        "band_lag": ((3,), "f"),
        "band_flags": ((FLAG_SLOTS,), "iu"),
        "band_correction": ((n, 3), "f"),
        "band_last_correction": ((n, 3), "f"),
    }
    for key, (shape, kind) in shapes.items():
        a = np.asarray(state[key])
        if a.shape != shape or a.dtype.kind not in kind:
            raise ValueError(f"{key}: expected {shape} of kind {kind!r}, got {a.dtype} {a.shape}")
        if kind == "f" and not np.all(np.isfinite(a)):
            raise ValueError(f"{key}: contains NaN or inf")
    cache.band_state = {k: np.array(state[k]) for k in _CKPT_KEYS}
    if cache.pcg is not None and isinstance(cache.pcg.cg, BandLDL):
        cache.pcg.cg.take_state(cache)


def _take_state(band: BandLDL, cache: MinimizerCache) -> None:
    st = cache.band_state
    if st is None:
        return
    cache.band_state = None
    band.band.assign(st["band_factor"])
    band.ws.hstats.assign(st["band_ratio"].astype(band.ws.np_dtype))
    band.lag.assign(st["band_lag"])
    band.flags.assign(st["band_flags"].astype(np.int32))
    band.correction.assign(st["band_correction"].astype(band.ws.np_dtype))
    band.last_correction.assign(st["band_last_correction"].astype(band.ws.np_dtype))
