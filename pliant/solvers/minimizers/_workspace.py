"""The implicit minimisers' per-problem storage: the Hessian pattern and Newton vectors (:class:`_Workspace`),
the linear solves on it, and :class:`MinimizerCache`, the declared object that keeps them (and L-BFGS's
state) from one step to the next.

Who owns what: a problem (``ForceSolver``, see :class:`pliant.solvers.minimizers.PotentialProblem`) declares a
``minimizer_cache`` attribute; Newton, L-BFGS and the step adjoint read and fill it through
:func:`cache_of`, and nothing else is stored on the problem. ``ForceSolver.reset`` and its checkpoints call
the cache's :meth:`MinimizerCache.reset` and L-BFGS's checkpoint functions on it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

if TYPE_CHECKING:
    from warp.optim.linear import CG

    from ...model import Model
    from ._assembly import PotentialProblem
    from ._pcg import _DeviceNewton


def _key(model: Model, energies: list) -> tuple:
    """What a workspace is built for: the model, the energies and their patterns' versions."""
    versions = tuple(e.pattern_version(model) if hasattr(e, "pattern_version") else 0 for e in energies)
    return (id(model), tuple(id(e) for e in energies), versions)


class _Workspace:
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


def _resolve_linear_solver(name: str, model: Model) -> str:
    if name == "auto":
        # The sparse LU stays the CPU default: "scipy-cg" (block-Jacobi CG on the host) is ~3x faster per
        # step on a 4k-DOF FEM box (12 ms vs 72 ms per solve) but its inexact directions stalled Newton just
        # above tolerance on a 1 GPa body, where the exact solve converges.
        return "direct" if wp.get_device(model.device).is_cpu else "cg"
    return name


def _direct_solve(ws: _Workspace, model: Model) -> None:
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


def _host_cg_solve(ws: _Workspace, model: Model, rtol: float, maxiter: int) -> int:
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


class MinimizerCache:
    """What Newton and L-BFGS keep between the steps of one problem.

    Attributes:
        newton: the :class:`_Workspace` (BSR pattern, slots, Newton and CG vectors) of the last
            (model, energies) it was built for, or None before the first implicit step.
        lbfgs: L-BFGS's state for that workspace, ``(workspace, lagged H₀, curvature history, warm-start
            memo)`` (see :mod:`pliant.solvers.minimizers._quasi_newton`), or None before its first step.
    """

    def __init__(self) -> None:
        self.newton: _Workspace | None = None
        self.lbfgs: tuple[Any, Any, Any, dict] | None = None
        #: The device Newton's buffers (``linear_solver="pcg"``, :mod:`._pcg`), or None before its first step.
        self.pcg: _DeviceNewton | None = None
        #: A checkpoint's band-Newton state not yet taken by a band Newton (:mod:`._band`), or None.
        self.band_state: dict[str, np.ndarray] | None = None

    def workspace(self, model: Model, energies: list) -> _Workspace:
        """The workspace of (``model``, ``energies``), built on first use and when either changes."""
        key = _key(model, energies)
        if self.newton is None or self.newton.key != key:
            self.newton = _Workspace(model, energies)
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


def _workspace(problem: PotentialProblem) -> _Workspace:
    """The Newton workspace of ``problem``'s model and energies (kept in its cache)."""
    return cache_of(problem).workspace(problem.model, problem.energies)
