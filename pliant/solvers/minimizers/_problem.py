"""The minimisers' bottom module: the types every other module of the package reads, and none it imports.

* :class:`PotentialProblem`: what a minimiser reads from the solver that owns the step (model, energies,
  control) and writes (``last_stats``);
* :class:`Workspace`: the per-problem storage (the Hessian's BSR pattern, Newton and CG vectors) and the
  host linear solves on it; :class:`MinimizerCache`, the declared object that keeps it (and L-BFGS's and
  the device Newton's state) from one step to the next;
* :class:`NewtonStats` and :class:`DeviceNewtonStats`: what one minimisation did.

Who owns what: a problem (``ForceSolver``) declares a ``minimizer_cache`` attribute; the minimisers and the
step adjoint read and fill it through :func:`cache_of`, and nothing else is stored on the problem.
``ForceSolver.reset`` and its checkpoints call the cache's :meth:`MinimizerCache.reset` and the
minimisers' checkpoint functions on it. Below it are only leaves: ``_slots`` (the device Newton's state
slots), ``_pcg_kernels`` (its CG counters) and ``_band_order``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import warp as wp

from ._pcg_kernels import TOTAL as CG_TOTAL
from ._slots import BACKTRACKS, CONVERGED, GNORM, ITER, RESIDUALS, STEP_NORM, STEPS, TOL, TOTAL

if TYPE_CHECKING:
    from warp.optim.linear import CG

    from ...model import Control, Model


def _key(model: Model, energies: list) -> tuple:
    """What a workspace is built for: the model, the energies and their patterns' versions."""
    versions = tuple(e.pattern_version(model) if hasattr(e, "pattern_version") else 0 for e in energies)
    return (id(model), tuple(id(e) for e in energies), versions)


class Workspace:
    """Everything allocated once per (model, energies): the BSR pattern, slots, Newton vectors, CG state."""

    def __init__(self, model: Model, energies: list) -> None:
        from warp.sparse import bsr_from_triplets

        n = model.particle_count
        d = model.device
        self.key = _key(model, energies)
        patterns = [e.hessian_pattern(model) for e in energies]
        diag = np.arange(n, dtype=np.int64)
        rows = np.concatenate([diag] + [np.asarray(p[0], np.int64) for p in patterns])
        cols = np.concatenate([diag] + [np.asarray(p[1], np.int64) for p in patterns])
        keys = np.unique(rows * n + cols)  # sorted by (row, col): BSR order
        self.nnz = keys.size
        brow = (keys // n).astype(np.int32)
        bcol = (keys % n).astype(np.int32)
        self.indptr = np.searchsorted(brow, np.arange(n + 1)).astype(np.int32)
        self.indices = bcol
        mat = model.mat33
        zeros = wp.zeros(self.nnz, dtype=mat, device=d)
        self.A = bsr_from_triplets(
            n,
            n,
            wp.array(brow, dtype=wp.int32, device=d),
            wp.array(bcol, dtype=wp.int32, device=d),
            zeros,
            prune_numerical_zeros=False,
        )
        # The value order must be our sorted key order (checked once, at build time).
        if not (
            np.array_equal(self.A.offsets.numpy()[: n + 1], self.indptr)
            and np.array_equal(self.A.columns.numpy()[: self.nnz], bcol)
        ):
            raise RuntimeError(
                "warp.sparse built a BSR layout that differs from the sorted (row, col) pattern"
            )
        self.values = self.A.values
        self.block_rows: wp.array = wp.array(brow, dtype=wp.int32, device=d)
        self.block_cols: wp.array = wp.array(bcol, dtype=wp.int32, device=d)
        self.diag_slots: wp.array = wp.array(
            np.searchsorted(keys, diag * n + diag).astype(np.int32), dtype=wp.int32, device=d
        )
        self.slots: list[wp.array] = []
        for r, c in patterns:
            k = np.asarray(r, np.int64) * n + np.asarray(c, np.int64)
            self.slots.append(wp.array(np.searchsorted(keys, k).astype(np.int32), dtype=wp.int32, device=d))
        v3 = model.vec3
        self.grad = wp.zeros(n, dtype=v3, device=d)
        self.egrad = wp.zeros(n, dtype=v3, device=d)
        self.egrad_scratch = wp.zeros(n, dtype=v3, device=d)  # gradient nobody reads (line-search values)
        self.rhs = wp.zeros(n, dtype=v3, device=d)
        self.dx = wp.zeros(n, dtype=v3, device=d)
        self.x_trial = wp.zeros(n, dtype=v3, device=d)
        self.inv_diag = wp.zeros(n, dtype=v3, device=d)
        self.hstats = wp.zeros(1, dtype=model.scalar, device=d)  # max_i H_ii/m_i
        self.gstats = wp.zeros(4, dtype=model.scalar, device=d)  # max|g|/mh, max|x|, inertia, E
        self.tstats = wp.zeros(4, dtype=model.scalar, device=d)  # inertia(trial), E(trial), max|dx|, g·dx
        # Views made once (Energy.value adds into out[0]).
        self.gstats_e = self.gstats[3:4]
        self.tstats_phi = self.tstats[0:2]
        self.tstats_e = self.tstats[1:2]
        self.tstats_step = self.tstats[2:4]
        self.np_dtype = np.float32 if model.dtype == "float32" else np.float64
        self._cg: CG | None = None
        self._cg_key: tuple[float, int] | None = None
        self._band: tuple[np.ndarray, int] | None = None

    def band_order(self) -> tuple[np.ndarray, int]:
        """The particles' bandwidth-reducing order and its half-bandwidth in particles (computed once; see
        :func:`pliant.solvers.minimizers._band.band_order`)."""
        if self._band is None:
            from ._band_order import band_order

            n = self.indptr.size - 1
            rows = np.repeat(np.arange(n, dtype=np.int64), np.diff(self.indptr))
            self._band = band_order(n, rows, self.indices.astype(np.int64))
        return self._band

    def cg(self, tol: float, maxiter: int) -> CG:
        """The pre-allocated CG functor (Jacobi preconditioner on ``inv_diag``)."""
        from warp.optim.linear import CG, aslinearoperator, cg

        key = (tol, maxiter)
        if self._cg is None or self._cg_key != key:
            solver = cg(
                self.A,
                self.rhs,
                self.dx,
                tol=tol,
                atol=0.0,  # Warp takes atol = tol when unset; the residual must be relative to ‖b‖ only
                maxiter=maxiter,
                M=aslinearoperator(self.inv_diag),
                run=False,
            )
            assert isinstance(solver, CG)  # run=False returns the functor, not a result
            self._cg, self._cg_key = solver, key
        return self._cg


def resolve_linear_solver(name: str, model: Model) -> str:
    if name == "auto":
        # The sparse LU stays the CPU default: "scipy-cg" (block-Jacobi CG on the host) is ~3x faster per
        # step on a 4k-DOF FEM box (12 ms vs 72 ms per solve) but its inexact directions stalled Newton just
        # above tolerance on a 1 GPa body, where the exact solve converges.
        return "direct" if wp.get_device(model.device).is_cpu else "cg"
    return name


def direct_solve(ws: Workspace, model: Model) -> None:
    """Δx = −H⁻¹∇Φ by a SciPy sparse LU (float64 on the host; one copy each way)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    n = model.particle_count
    vals = ws.values.numpy()[: ws.nnz].astype(np.float64)
    H = sp.bsr_matrix((vals, ws.indices, ws.indptr), shape=(3 * n, 3 * n)).tocsc()
    g = ws.grad.numpy().astype(np.float64).reshape(-1)
    # H is symmetric positive definite: symmetric ordering, no pivoting (SuperLU's "symmetric mode").
    lu = splu(H, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    dx = lu.solve(-g)
    ws.dx.assign(dx.reshape(n, 3).astype(ws.np_dtype))


def host_cg_solve(ws: Workspace, model: Model, rtol: float, maxiter: int) -> int:
    """Δx = −H⁻¹∇Φ by SciPy CG with a 3×3 block-Jacobi preconditioner (float64, host); returns iterations."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import LinearOperator, cg

    n = model.particle_count
    vals = ws.values.numpy()[: ws.nnz].astype(np.float64)
    H = sp.bsr_matrix((vals, ws.indices, ws.indptr), shape=(3 * n, 3 * n)).tocsr()
    d_inv = np.linalg.inv(vals[ws.diag_slots.numpy()])
    precond = LinearOperator(
        H.shape,
        matvec=lambda r: np.einsum("nij,nj->ni", d_inv, r.reshape(n, 3)).reshape(-1),
        dtype=np.float64,
    )
    g = ws.grad.numpy().astype(np.float64).reshape(-1)
    count = [0]

    def tick(_: np.ndarray) -> None:
        count[0] += 1

    dx, _ = cg(H, -g, rtol=rtol, atol=0.0, maxiter=maxiter, M=precond, callback=tick)
    ws.dx.assign(dx.reshape(n, 3).astype(ws.np_dtype))
    return count[0]


class LinearSolve(Protocol):
    """What the stats read of the device Newton's linear solver (a CG or the band LDLᵀ)."""

    counts: wp.array

    def iterations(self) -> int: ...


class DeviceNewtonBuffers(Protocol):
    """What the cache and :class:`DeviceNewtonStats` read of the device Newton's buffers (``_pcg``'s
    ``_DeviceNewton``): its key, linear solver, float64 scalars, int32 counters and residuals."""

    key: tuple
    band: bool

    @property
    def cg(self) -> LinearSolve:  # the linear solver: a BandLDL (band) or the device CG
        ...

    state: wp.array
    counts: wp.array
    residuals: wp.array

    def reset(self) -> None: ...


class MinimizerCache:
    """What Newton and L-BFGS keep between the steps of one problem.

    Attributes:
        newton: the :class:`Workspace` (BSR pattern, slots, Newton and CG vectors) of the last
            (model, energies) it was built for, or None before the first implicit step.
        lbfgs: L-BFGS's state for that workspace, ``(workspace, lagged H₀, curvature history, warm-start
            memo)`` (see :mod:`pliant.solvers.minimizers._quasi_newton`), or None before its first step.
    """

    def __init__(self) -> None:
        self.newton: Workspace | None = None
        self.lbfgs: tuple[Any, Any, Any, dict] | None = None
        #: The device Newton's buffers (``linear_solver="pcg"``, :mod:`._pcg`), or None before its first step.
        self.pcg: DeviceNewtonBuffers | None = None
        #: A checkpoint's band-Newton state not yet taken by a band Newton (:mod:`._band`), or None.
        self.band_state: dict[str, np.ndarray] | None = None

    def workspace(self, model: Model, energies: list) -> Workspace:
        """The workspace of (``model``, ``energies``), built on first use and when either changes."""
        key = _key(model, energies)
        if self.newton is None or self.newton.key != key:
            self.newton = Workspace(model, energies)
        return self.newton

    def reset(self) -> None:
        """Forget what one step leaves for the next (L-BFGS's curvature pairs and warm start, the device
        Newton's lagged band factor); keep what depends only on the model (the Hessian pattern, L-BFGS's
        lagged H₀ and its factorisation)."""
        if self.lbfgs is not None:
            _, _, history, memo = self.lbfgs
            history.clear()
            memo.clear()
        if self.pcg is not None:
            self.pcg.reset()  # the band solve's lagged factor: a restarted run factorises as a new one


def cache_of(problem: object) -> MinimizerCache:
    """The problem's declared ``minimizer_cache``; a problem without one gets a fresh cache for this call
    (correct, but nothing is reused from one step to the next)."""
    cache = getattr(problem, "minimizer_cache", None)
    return cache if cache is not None else MinimizerCache()


def workspace_of(problem: PotentialProblem) -> Workspace:
    """The Newton workspace of ``problem``'s model and energies (kept in its cache)."""
    return cache_of(problem).workspace(problem.model, problem.energies)


class PotentialProblem(Protocol):
    """What the minimisers (Newton, L-BFGS) and the step adjoint read from the solver that owns the step.

    ``model`` (masses, device, dtype), ``energies`` (the terms of Φ; their ``dissipative`` ones get
    ``begin_step``) and ``control`` (the step's Control: external forces as −f·x, the drag handle as
    ½k|x − target|², or None). Results go to ``last_stats``.
    """

    model: Model
    energies: list
    last_stats: NewtonStats | DeviceNewtonStats | None
    #: Optional: where the minimisers keep their workspace and L-BFGS's state between steps
    #: (:class:`~pliant.solvers.minimizers.MinimizerCache`); without it nothing is reused.
    minimizer_cache: MinimizerCache

    @property
    def control(self) -> Control | None: ...


def needs_feasible_start(problem: PotentialProblem) -> bool:
    """Whether an energy of ``problem`` asks to start from the step's start positions (``feasible_start``:
    barrier contact, infinite where x̃ may intersect) rather than from x̃."""
    return any(getattr(e, "feasible_start", False) for e in problem.energies)


@dataclass
class NewtonStats:
    """What one minimisation did (``solver.last_stats`` after an implicit step).

    Attributes:
        iterations: Newton iterations (linear solves) performed.
        converged: whether the step (or the gradient) fell below ``newton_tol``.
        step_norm: ‖Δx‖∞/h of the last Newton step [m/s] (0 when none was taken).
        gradient_norm: max_i |∇Φ_i|/(m_i h) at the returned positions [m/s] (free particles).
        residuals: ``gradient_norm`` at the start of every iteration and at the end [m/s].
        line_search_backtracks: total step halvings in the Armijo line search.
        linear_iterations: total CG iterations (0 for the direct solver; for L-BFGS, the steps that
            refactorised its initial Hessian).
        linear_solver: "cg" or "direct".
        tolerance: the tolerance used [m/s] (``newton_tol``, raised to the round-off floor of the dtype).
        projected: whether PSD-projected Hessians were used (always with ``project_psd=True``; with "auto"
            after an exact Hessian failed to give a descent direction).
    """

    iterations: int = 0
    converged: bool = False
    step_norm: float = 0.0
    gradient_norm: float = float("nan")
    residuals: list[float] = field(default_factory=list)
    line_search_backtracks: int = 0
    linear_iterations: int = 0
    linear_solver: str = ""
    tolerance: float = 0.0
    projected: bool = False
    warm_started: bool = False


class DeviceNewtonStats:
    """:class:`~pliant.solvers.minimizers.NewtonStats` of the latest device-Newton step, read from the device
    when an attribute is asked for (one host read each; a replayed graph updates them too)."""

    def __init__(self, dn: DeviceNewtonBuffers, projected: bool) -> None:
        self._dn = dn
        self.projected = projected
        self.warm_started = False
        #: "pcg" (block-Jacobi CG) or "band" (the banded LDLᵀ of :mod:`._band`).
        self.linear_solver = "band" if dn.band else "pcg"

    def _counts(self) -> np.ndarray:
        return self._dn.counts.numpy()

    def totals(self) -> tuple[int, int, int]:
        """(steps, Newton iterations, CG iterations) over the solver's life, replayed steps included (two
        host reads)."""
        c = self._counts()
        return int(c[STEPS]), int(c[TOTAL]), int(self._dn.cg.counts.numpy()[CG_TOTAL])

    @property
    def iterations(self) -> int:
        """Newton iterations (linear solves) of the step."""
        return int(self._counts()[ITER])

    @property
    def converged(self) -> bool:
        """Whether the gradient fell below the tolerance."""
        return bool(self._counts()[CONVERGED])

    @property
    def line_search_backtracks(self) -> int:
        """Total step halvings of the line search."""
        return int(self._counts()[BACKTRACKS])

    @property
    def linear_iterations(self) -> int:
        """Total CG iterations of the step (0 for the direct band solve)."""
        return self._dn.cg.iterations()

    @property
    def residuals(self) -> list[float]:
        """max_i |∇Φ_i|/(m_i h) at the start and after every accepted iteration [m/s]."""
        count = int(self._counts()[RESIDUALS])
        return [float(v) for v in self._dn.residuals.numpy()[:count]]

    @property
    def tolerance(self) -> float:
        """The tolerance used [m/s] (``newton_tol`` raised to the round-off floor)."""
        return float(self._dn.state.numpy()[TOL])

    @property
    def step_norm(self) -> float:
        """‖Δx‖∞/h of the last Newton step [m/s]."""
        return float(self._dn.state.numpy()[STEP_NORM])

    @property
    def gradient_norm(self) -> float:
        """max_i |∇Φ_i|/(m_i h) at the returned positions [m/s]."""
        return float(self._dn.state.numpy()[GNORM])
