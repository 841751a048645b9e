"""L-BFGS on the incremental potential with a prefactored, lagged Hessian (Liu, Bouaziz, Kavan 2017).

Same problem as :mod:`pliant.solvers.minimizers._newton` — one implicit step minimises

    Φ(x) = ½ ‖x − x̃‖²_M + h² Σ_e E_e(x)

— but without assembling and factorising the Hessian every iteration. The initial inverse-Hessian
approximation of L-BFGS is H₀⁻¹ with

    H₀ = M + h² (K_lagged + K_contact),

split by coordinate axis: H₀ keeps, for each axis d, the n×n matrix of the (d, d) entries of every 3×3 block
and drops the coupling between axes, so it is three scalar sparse matrices of n×n instead of one of 3n×3n
(a factorisation ~10× cheaper and triangular solves ~4× cheaper; Liu et al. use one isotropic Laplacian for
all axes, which cannot hold a contact stiffness that acts along one axis only).

* ``K_lagged``: the PSD-projected Hessian of the energies at the configuration where it was last assembled
  (the first step, and again after a step that needed more than ``lbfgs_refresh`` iterations or when h
  changes). Elastic Hessians change slowly; L-BFGS corrects the difference from the curvature pairs it sees.
* ``K_contact``: energies whose Hessian switches on and off with an active set (``Energy.
  hessian_changes_each_step``: ground and collider penalties) are re-evaluated at the start of every step;
  an axis is refactorised only when its values changed (at rest the contact set is constant, so nothing is).

Each iteration costs one gradient (with Φ, for the Armijo test), three sparse triangular solves and the
two-loop recursion on the host; the full step α = 1 is accepted almost always, so the trial point's
gradient is the next iteration's. The step bound of the energies (``max_step``: no inversion) applies as in
Newton. Convergence is the same test as Newton's: max_i |∇Φ_i|/(m_i h) below the tolerance [m/s].

Reference: T. Liu, S. Bouaziz, L. Kavan, "Quasi-Newton methods for real-time simulation of hyperelastic
materials", ACM TOG 36(3), 2017; J. Nocedal, S. Wright, *Numerical Optimization*, Alg. 7.4 (two-loop).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from ..._warp import launch
from .._errors import SingularSystemError
from ._adjoint import differentiable
from ._assembly import assemble, control_terms, gradient
from ._dissection import nested_dissection
from ._kernels import _trial_point
from ._options import step_settings
from ._problem import MinimizerCache, NewtonStats, Workspace, cache_of

if TYPE_CHECKING:
    import scipy.sparse
    from scipy.sparse.linalg import SuperLU

    from ...integrators import ImplicitOptionsLike
    from ...model import Model
    from ._options import MinimizerLike
    from ._problem import PotentialProblem


class _LaggedHessian:
    """H₀ per axis: lagged energy Hessians + per-step contact terms, factorised by SciPy's SuperLU."""

    def __init__(self, ws: Workspace, model: Model, energies: list) -> None:
        n = model.particle_count
        self.n = n
        self.rows = np.repeat(np.arange(n, dtype=np.int32), np.diff(ws.indptr))
        self.cols = ws.indices
        self.diag_slots = ws.diag_slots.numpy().astype(np.int64)
        # Factor P H₀ Pᵀ in a nested-dissection order P (fewer nonzeros than SuperLU's own ordering).
        self.perm = nested_dissection(model.particle_q_np.astype(np.float64), self.rows, self.cols)
        self.inv_perm = np.empty_like(self.perm)
        self.inv_perm[self.perm] = np.arange(n)
        self.volatile = [
            (k, e) for k, e in enumerate(energies) if getattr(e, "hessian_changes_each_step", False)
        ]
        free = model.particle_inv_mass.numpy() > 0.0
        self.free = free
        self.mass = model.particle_mass_np.astype(np.float64)
        # Each contact term writes its blocks into a compact buffer of its own (slot j → entry j); the blocks
        # are then added at their places in the pattern. Blocks with a fixed row or column stay out of H₀
        # (those rows are m_i·I).
        self.volatile_buffers = []
        for k, _ in self.volatile:
            s = ws.slots[k].numpy().astype(np.int64)
            keep = free[self.rows[s]] & free[self.cols[s]]
            compact: wp.array = wp.array(
                np.arange(s.size, dtype=np.int32), dtype=wp.int32, device=model.device
            )
            scratch = wp.zeros(max(s.size, 1), dtype=model.mat33, device=model.device)
            self.volatile_buffers.append((compact, scratch, keep, s[keep]))
        self.base: np.ndarray | None = None  # (3, nnz) lagged axis values
        self.h: float | None = None
        self.values: list[np.ndarray | None] = [None, None, None]
        self.lu: list[Any] = [None, None, None]
        #: How H₀⁻¹ is applied: "lu" (SuperLU) or "amg" (a PyAMG V-cycle); ``set_method`` switches.
        self.method = "lu"
        self.factorizations = 0
        self._ratio: float | None = None

    def refresh(self, solver: PotentialProblem, ws: Workspace, x: wp.array, h: float) -> None:
        """Assemble M + h² Σ_lagged H_e at x (PSD-projected, fixed rows m_i·I) and keep its axis values."""
        # The drag handle, like contact, switches on and off: L-BFGS learns it rather than H₀ lagging it.
        assemble(solver, ws, x, h, True, skip=frozenset(k for k, _ in self.volatile), control=False)
        vals = ws.values.numpy()[: ws.nnz]
        self.base = np.stack([vals[:, d, d].astype(np.float64) for d in range(3)])
        self.h = h
        self._ratio = None
        self.values = [None, None, None]  # the next update factorises every axis afresh
        self.lu = [None, None, None]

    def update(self, solver: PotentialProblem, ws: Workspace, x: wp.array, h: float) -> int:
        """Add the contact terms at x; refactorise an axis when its contact stiffness is not covered.

        Returns the number of factorisations. An axis keeps its factor while no entry of the new H₀ exceeds
        the factored one; otherwise it is refactorised with the entrywise maximum of both, so the contact
        set in H₀ only grows until the next :meth:`refresh`. An H₀ a little too stiff for a particle that
        lifted off costs L-BFGS a few pairs, one missing a new contact's stiffness overshoots it, and a
        factorisation costs about as much as six iterations (a bouncing box's contact set changes in most
        steps). At rest the contact set is constant and nothing is refactorised.
        """
        assert self.base is not None
        axis_values = [self.base[d] for d in range(3)]
        if self.volatile:
            m = solver.model
            extra = np.zeros_like(self.base)
            for (_, e), buffers in zip(self.volatile, self.volatile_buffers, strict=True):
                compact, scratch, keep, slots = buffers
                scratch.zero_()
                e.hessian(m, x, compact, scratch, project_psd=True, scale=h * h)
                blocks = scratch.numpy()[: keep.size][keep]
                for d in range(3):
                    np.add.at(extra[d], slots, blocks[:, d, d])
            axis_values = [self.base[d] + extra[d] if extra[d].any() else self.base[d] for d in range(3)]
        count = 0
        for d in range(3):
            v = axis_values[d]
            old = self.values[d]
            if self.lu[d] is not None and old is not None:
                if not (v > old + 1e-12 * float(np.abs(old).max())).any():
                    continue
                # Grow the contact set, never shrink it: a bouncing body's contacts flicker every step.
                v = np.maximum(v, old)
            self.lu[d] = self.factor(v, d)
            self.values[d] = v
            self._ratio = None
            count += 1
        self.factorizations += count
        return count

    def set_method(self, method: str) -> None:
        """Apply H₀⁻¹ by ``method`` ("lu" or "amg") from now on; the current H₀ values are factored again
        the new way (so a checkpoint restored with one method resumes bit for bit with the other)."""
        if method == self.method:
            return
        self.method = method
        for d, v in enumerate(self.values):
            if v is not None:
                self.lu[d] = self.factor(v, d)

    def factor(self, v: np.ndarray, axis: int) -> SuperLU | _VCycle:
        """The solver of axis ``axis``'s H₀ with values ``v`` (the pattern's entries, in our order): a
        SuperLU factor, or with :attr:`method` "amg" a smoothed-aggregation hierarchy whose ``solve`` is one
        V-cycle (a fixed SPD operator, as L-BFGS's H₀⁻¹ must be).

        Raises:
            SingularSystemError: H₀ is singular in float64 (the masses are lost next to h²K).
        """
        import scipy.sparse as sp
        from scipy.sparse.linalg import splu

        ip = self.inv_perm
        mat = sp.csc_matrix((v, (ip[self.rows], ip[self.cols])), shape=(self.n, self.n))
        if self.method == "amg":
            return _VCycle(mat)
        try:
            # Symmetric positive definite: our symmetric ordering, no pivoting (SuperLU's "symmetric mode").
            return splu(mat, permc_spec="NATURAL", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        except RuntimeError as exc:  # SciPy: "Factor is exactly singular"
            raise SingularSystemError(
                f"L-BFGS: the initial Hessian M + h^2 K of axis {'xyz'[axis]} is singular ({exc}) at step "
                f"h = {self.h:.3g} s: the masses vanish next to h^2 times the stiffness (or h^2 K "
                "overflows the model's dtype); lower dt or raise substeps (h below ~1 s for any physical "
                "body), or use method='newton'"
            ) from None

    def solve(self, r: np.ndarray) -> np.ndarray:
        """H₀⁻¹ r for r of shape (n, 3)."""
        rp = r[self.perm]
        out = np.empty_like(r)
        for d in range(3):
            out[self.perm, d] = self.lu[d].solve(rp[:, d])
        return out

    def stiffness_ratio(self) -> float:
        """max_i trace(H₀_ii)/(3 m_i) over free particles, contact terms included (the round-off floor's
        amplification, as Newton's from its assembled Hessian)."""
        values = [v for v in self.values if v is not None]
        assert len(values) == 3
        if self._ratio is None:
            s = self.diag_slots
            diag = (values[0][s] + values[1][s] + values[2][s]) / 3.0
            ratio = diag[self.free] / self.mass[self.free]
            self._ratio = float(ratio.max()) if ratio.size else 1.0
        return self._ratio


class _VCycle:
    """H₀⁻¹ b ≈ one V-cycle of PyAMG's smoothed aggregation (symmetric Gauss–Seidel smoothing: an SPD
    operator). Building the hierarchy costs about one sparse LU of the same axis at 10³ cells and less above;
    a V-cycle costs a few sparse products, linear in the particles."""

    def __init__(self, mat: scipy.sparse.spmatrix) -> None:
        import pyamg

        hierarchy = pyamg.smoothed_aggregation_solver(mat.tocsr(), symmetry="symmetric", max_coarse=500)
        self._apply = hierarchy.aspreconditioner(cycle="V")

    def solve(self, b: np.ndarray) -> np.ndarray:
        return self._apply.matvec(np.ascontiguousarray(b, dtype=np.float64))


class _History:
    """The last ``size`` curvature pairs (s, y) with ρ = 1/(yᵀs)."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.s: list[np.ndarray] = []
        self.y: list[np.ndarray] = []
        self.rho: list[float] = []

    def clear(self) -> None:
        self.s.clear()
        self.y.clear()
        self.rho.clear()

    def push(self, s: np.ndarray, y: np.ndarray) -> None:
        sy = float(np.vdot(s, y))
        # Keep only pairs with positive curvature (Φ is not convex everywhere, H₀⁻¹ must stay SPD).
        if sy <= 1e-12 * float(np.sqrt(np.vdot(s, s) * np.vdot(y, y))):
            return
        self.s.append(s)
        self.y.append(y)
        self.rho.append(1.0 / sy)
        if len(self.s) > self.size:
            self.s.pop(0)
            self.y.pop(0)
            self.rho.pop(0)

    def direction(self, g: np.ndarray, h0: _LaggedHessian) -> np.ndarray:
        """−H⁻¹g by the two-loop recursion with H₀⁻¹ = ``h0.solve``."""
        q = g.copy()
        alphas = []
        for s, y, rho in zip(reversed(self.s), reversed(self.y), reversed(self.rho), strict=True):
            a = rho * float(np.vdot(s, q))
            alphas.append(a)
            q -= a * y
        r = h0.solve(q)
        for s, y, rho, a in zip(self.s, self.y, self.rho, reversed(alphas), strict=True):
            b = rho * float(np.vdot(y, r))
            r += (a - b) * s
        return -r


def _state(cache: MinimizerCache, ws: Workspace, model: Model, energies: list):
    """L-BFGS's (lagged H₀, history, warm-start memo) in ``cache``, new when the workspace changed."""
    st = cache.lbfgs
    if st is None or st[0] is not ws:
        st = (ws, _LaggedHessian(ws, model, energies), _History(5), {})
        cache.lbfgs = st
    return st[1], st[2], st[3]


def _energy(solver: PotentialProblem, ws: Workspace, x: wp.array) -> float:
    """Σ E(x) [J] with the Control's potentials (one host read)."""
    m = solver.model
    ws.tstats.zero_()
    for e in solver.energies:
        e.value(m, x, ws.tstats_e)
    control_terms(solver, ws, x, ws.egrad_scratch, ws.tstats_e)
    return float(ws.tstats.numpy()[1])


def _phi(g: np.ndarray, h2: float) -> float:
    return float(g[2] + h2 * g[3])


@differentiable
def minimize_quasi_newton(
    solver: PotentialProblem,
    t: float,
    h: float,
    x_tilde: wp.array,
    x_ref: wp.array,
    v_ref: wp.array,
    x_out: wp.array,
    options: ImplicitOptionsLike = None,
    minimizer: MinimizerLike = None,
) -> NewtonStats:
    """x_out = argmin_x ½‖x − x̃‖²_M + h² Σ E(x) by L-BFGS with a lagged, prefactored Hessian.

    Arguments as :func:`pliant.solvers.minimizers.minimize_incremental_potential`; ``minimizer`` also names
    ``lbfgs_history`` (curvature pairs kept, default 8), ``lbfgs_max_iterations`` (default 200),
    ``lbfgs_refresh`` (re-assemble the lagged Hessian after a step that took more iterations than this,
    default 40) and ``lbfgs_warm_start`` (start from x̃ plus the correction x − x̃ extrapolated from the
    last two steps when that lowers Φ; default True) and ``lbfgs_h0`` ("lu" or "amg": how H₀⁻¹ is applied).
    ``stats.linear_iterations`` counts the steps that refactorised H₀.

    Curvature pairs are kept from one step to the next while H₀ is unchanged: y = ∇Φ(x + s) − ∇Φ(x) does
    not depend on x̃, so a pair stays exact for the energy when the step's target moves.
    """
    m = solver.model
    n = m.particle_count
    cache = cache_of(solver)
    ws = cache.workspace(m, solver.energies)
    h0, hist, memo = _state(cache, ws, m, solver.energies)
    opts, mz = step_settings(options, minimizer)
    hist.size = int(mz.lbfgs_history)
    max_it = int(mz.lbfgs_max_iterations)
    refresh_after = int(mz.lbfgs_refresh)
    warm = bool(mz.lbfgs_warm_start)
    tol_opt = float(opts.newton_tol)
    max_ls = int(opts.max_line_search)
    eps = float(np.finfo(ws.np_dtype).eps)
    h2 = h * h
    stats = NewtonStats(linear_solver="lbfgs", projected=True)

    for e in solver.energies:
        if e.dissipative:
            e.begin_step(m, x_ref, v_ref, h)
    wp.copy(x_out, x_tilde)
    x = x_out
    g = _start(solver, ws, memo, x, x_tilde, h, warm, stats)
    stats.residuals.append(float(g[0]))
    if g[0] <= tol_opt:
        return _finish(solver, stats, memo, x, x_tilde, g, h)
    h0.set_method(mz.lbfgs_h0)
    if h0.base is None or h0.h != h or memo.get("refresh", False):
        h0.refresh(solver, ws, x, h)
        memo["refresh"] = False
    if h0.update(solver, ws, x, h):
        stats.linear_iterations += 1
        hist.clear()  # pairs measured against another H₀ would mix two approximations
    # Round-off floor as in Newton: one ulp of position moves ∇Φ_i/(m_i h) by eps·max|x|·max(H_ii/m_i)/h.
    tol = max(tol_opt, 8.0 * eps * max(g[1], 1.0) / h, eps * max(g[1], 1.0) * h0.stiffness_ratio() / h)
    stats.tolerance = tol
    grad = ws.grad.numpy().astype(np.float64).reshape(n, 3)
    # Steps that stay within every energy's admissible radius of the start need no max_step pass.
    radius = min((e.max_step_radius(m, x) for e in solver.energies), default=float("inf"))
    x_start = x.numpy().astype(np.float64)
    x_host = x_start.copy()
    restarted = False
    while stats.iterations < max_it:
        phi0 = _phi(g, h2)
        dx = hist.direction(grad, h0)
        gdx = float(np.vdot(grad, dx))
        if not gdx < 0.0:
            hist.clear()
            dx = -h0.solve(grad)
            gdx = float(np.vdot(grad, dx))
        ws.dx.assign(dx.astype(ws.np_dtype, copy=False))
        alpha = 1.0
        u = x_host + dx - x_start
        if not float(np.sqrt(np.einsum("ij,ij->i", u, u).max())) <= radius:
            for e in solver.energies:
                alpha = min(alpha, float(e.max_step(m, x, ws.dx)))
        stats.iterations += 1
        accepted, alpha, g_new = _line_search(solver, ws, x, x_tilde, h, alpha, g, phi0, gdx, max_ls, stats)
        if not accepted:
            # ws.grad holds a rejected trial's gradient: recompute it at x before trying again.
            g = gradient(solver, ws, x, x_tilde, h)
            grad = ws.grad.numpy().astype(np.float64).reshape(n, 3)
            if restarted or not hist.s:
                break  # no decrease along H₀'s own direction: at the round-off floor
            hist.clear()
            restarted = True
            continue
        restarted = False
        wp.copy(x, ws.x_trial)
        x_host += alpha * dx
        g = g_new
        grad_new = ws.grad.numpy().astype(np.float64).reshape(n, 3)
        hist.push(alpha * dx, grad_new - grad)
        grad = grad_new
        stats.step_norm = float(alpha * np.abs(dx).max() / h)
        stats.residuals.append(float(g[0]))
        if g[0] <= tol:
            stats.converged = True
            break
    if stats.iterations > refresh_after or not stats.converged:
        memo["refresh"] = True
    return _finish(solver, stats, memo, x, x_tilde, g, h)


def _start(
    solver: PotentialProblem,
    ws: Workspace,
    memo: dict,
    x: wp.array,
    x_tilde: wp.array,
    h: float,
    warm: bool,
    stats: NewtonStats,
) -> np.ndarray:
    """Φ's gradient statistics at the step's start ``x`` (= x̃ on entry [m]); with ``warm``, ``x`` becomes
    x̃ plus the last step's correction when that lowers Φ (``stats.warm_started``)."""
    h2 = h * h
    correction = memo.get("correction")
    if warm and correction is not None and memo.get("h") == h:
        # Near rest the correction x − x̃ (elastic and contact response) barely changes between steps.
        # Φ(x̃) = h² E(x̃) needs no gradient; the warm start is kept when it lowers Φ.
        phi_tilde = h2 * _energy(solver, ws, x)
        ws.x_trial.assign((x.numpy() + correction).astype(ws.np_dtype, copy=False))
        g = gradient(solver, ws, ws.x_trial, x_tilde, h)
        if _phi(g, h2) < phi_tilde:
            wp.copy(x, ws.x_trial)
            stats.warm_started = True
            return g
    return gradient(solver, ws, x, x_tilde, h)


def _line_search(
    solver: PotentialProblem,
    ws: Workspace,
    x: wp.array,
    x_tilde: wp.array,
    h: float,
    alpha: float,
    g: np.ndarray,
    phi0: float,
    gdx: float,
    max_ls: int,
    stats: NewtonStats,
) -> tuple[bool, float, np.ndarray]:
    """Backtracking (Armijo) along ``ws.dx`` from ``x``, from step ``alpha``, at most ``max_ls`` halvings:
    (accepted, the step taken, the gradient statistics at the trial point ``ws.x_trial``)."""
    m = solver.model
    h2 = h * h
    eps = float(np.finfo(ws.np_dtype).eps)
    g_new = g
    for _ in range(max_ls + 1):
        ws.tstats.zero_()
        launch(
            _trial_point,
            m.particle_count,
            [m.particle_inv_mass, m.particle_mass, x, ws.dx, x_tilde, m.s(alpha), ws.x_trial, ws.tstats],
            device=m.device,
        )
        g_new = gradient(solver, ws, ws.x_trial, x_tilde, h)
        phi = _phi(g_new, h2)
        size = abs(g_new[2]) + h2 * abs(g_new[3]) + abs(phi0)
        if phi <= phi0 + 1e-4 * alpha * gdx + 64.0 * eps * size:
            return True, alpha, g_new
        # Near the solution of a very stiff body (1 GPa) the decrease L-BFGS predicts (~1e-14 J) is below
        # the cancellation error of E's sum, so Φ cannot confirm it; a full step that lowers the gradient
        # and leaves Φ unchanged to 1e-6 of its size is taken (Newton's exact steps do not need this).
        if alpha == 1.0 and g_new[0] < g[0] and phi - phi0 <= 1e-6 * size:
            return True, alpha, g_new
        alpha *= 0.5
        stats.line_search_backtracks += 1
    return False, alpha, g_new


def _finish(
    solver: PotentialProblem, stats: NewtonStats, memo: dict, x: wp.array, x_tilde: wp.array, g, h: float
):
    if not stats.iterations:
        stats.converged = True
    c = x.numpy().astype(np.float64) - x_tilde.numpy().astype(np.float64)
    prev = memo.get("last_correction")
    # Next step's start: the correction extrapolated from the last two, damped by half (measured on the
    # 10³ box: 3.92 → 3.58 iterations per step; the full linear extrapolation gave 3.72).
    memo["correction"] = c if prev is None or memo.get("h") != h else 1.5 * c - 0.5 * prev
    memo["last_correction"] = c
    memo["h"] = h
    stats.gradient_norm = float(g[0])
    solver.last_stats = stats
    return stats


# ----------------------------------------------------------------------------------------- checkpoints
# What L-BFGS keeps between steps, as host arrays, so a resumed run continues bit for bit: the curvature
# pairs, the warm start's corrections, and the lagged H₀ (its values: the factors are rebuilt from them,
# and SuperLU is deterministic for the same matrix and ordering).
_CKPT_KEYS = (
    "lbfgs_s",
    "lbfgs_y",
    "lbfgs_rho",
    "lbfgs_correction",
    "lbfgs_last_correction",
    "lbfgs_h",
    "lbfgs_refresh",
    "lbfgs_h0_base",
    "lbfgs_h0_h",
    "lbfgs_h0_values",
    "lbfgs_h0_factorizations",
)


def lbfgs_checkpoint_state(cache: MinimizerCache) -> dict[str, np.ndarray]:
    """L-BFGS's state between steps kept in ``cache`` (copies; empty before its first step)."""
    st = cache.lbfgs
    if st is None:
        return {}
    _, h0, hist, memo = st
    out: dict[str, np.ndarray] = {}
    if hist.s:
        out["lbfgs_s"] = np.stack(hist.s)
        out["lbfgs_y"] = np.stack(hist.y)
        out["lbfgs_rho"] = np.asarray(hist.rho, dtype=np.float64)
    for key in ("correction", "last_correction"):
        if memo.get(key) is not None:
            out[f"lbfgs_{key}"] = np.array(memo[key], dtype=np.float64)
    if "h" in memo:
        out["lbfgs_h"] = np.array(float(memo["h"]))
    if "refresh" in memo:
        out["lbfgs_refresh"] = np.array(bool(memo["refresh"]))
    if h0.base is not None:
        out["lbfgs_h0_base"] = h0.base.copy()
        out["lbfgs_h0_h"] = np.array(float(h0.h))
        if all(v is not None for v in h0.values):
            out["lbfgs_h0_values"] = np.stack(h0.values)
    out["lbfgs_h0_factorizations"] = np.array(int(h0.factorizations))
    return out


def _ck_array(state: dict, key: str, shape: tuple[int, ...], kind: str = "f") -> np.ndarray:
    a = np.asarray(state[key])
    if a.shape != shape or a.dtype.kind not in kind:
        raise ValueError(f"{key}: expected {shape} of kind {kind!r}, got {a.dtype} {a.shape}")
    if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        raise ValueError(f"{key}: contains NaN or inf")
    return a


def lbfgs_restore_checkpoint_state(solver: PotentialProblem, state: dict[str, np.ndarray]) -> None:
    """Set L-BFGS's state in ``solver.minimizer_cache`` from :func:`lbfgs_checkpoint_state`'s arrays
    (validated first); ``solver`` is a PotentialProblem that declares a cache.

    Raises:
        ValueError: an unknown key, or an array of the wrong shape, dtype or with non-finite values.
    """
    unknown = sorted(set(state) - set(_CKPT_KEYS))
    if unknown:
        raise ValueError(f"unknown L-BFGS state keys {unknown}")
    cache = solver.minimizer_cache
    if not state:
        cache.reset()
        return
    n = solver.model.particle_count
    ws = cache.workspace(solver.model, solver.energies)
    h0, hist, memo = _state(cache, ws, solver.model, solver.energies)
    nnz = h0.rows.size
    # Validate everything before changing anything.
    pairs = 0
    if "lbfgs_s" in state or "lbfgs_y" in state or "lbfgs_rho" in state:
        pairs = int(np.asarray(state.get("lbfgs_rho", np.zeros(0))).shape[0]) if "lbfgs_rho" in state else -1
        if pairs < 0 or "lbfgs_s" not in state or "lbfgs_y" not in state:
            raise ValueError("lbfgs_s, lbfgs_y and lbfgs_rho come together")
        s = _ck_array(state, "lbfgs_s", (pairs, n, 3))
        y = _ck_array(state, "lbfgs_y", (pairs, n, 3))
        rho = _ck_array(state, "lbfgs_rho", (pairs,))
        for k in range(pairs):
            # ρ is 1/(sᵀy) > 0 by construction (_History.push), computed the same way here: bit-equal.
            sy = float(np.vdot(s[k], y[k]))
            if not (sy > 0.0 and float(rho[k]) == 1.0 / sy):
                raise ValueError(f"lbfgs_rho[{k}]: not 1/(s.y) of its curvature pair (a corrupt file)")
    corr = {
        k: _ck_array(state, f"lbfgs_{k}", (n, 3))
        for k in ("correction", "last_correction")
        if f"lbfgs_{k}" in state
    }
    h = float(_ck_array(state, "lbfgs_h", ())) if "lbfgs_h" in state else None
    if h is not None and not h > 0.0:
        raise ValueError(f"lbfgs_h: the last step must be > 0 s, got {h}")
    refresh = bool(_ck_array(state, "lbfgs_refresh", (), "b")) if "lbfgs_refresh" in state else None
    base = _ck_array(state, "lbfgs_h0_base", (3, nnz)) if "lbfgs_h0_base" in state else None
    h0_h = float(_ck_array(state, "lbfgs_h0_h", ())) if "lbfgs_h0_h" in state else None
    if h0_h is not None and not h0_h > 0.0:
        raise ValueError(f"lbfgs_h0_h: the step of H0 must be > 0 s, got {h0_h}")
    values = _ck_array(state, "lbfgs_h0_values", (3, nnz)) if "lbfgs_h0_values" in state else None
    if (base is None) != (h0_h is None) or (values is not None and base is None):
        raise ValueError("lbfgs_h0_values needs lbfgs_h0_base and lbfgs_h0_h")
    # H₀ is SPD with the masses on its diagonal, and contact terms only add to it (PSD blocks).
    diag = h0.diag_slots
    if base is not None and not np.all(base[:, diag] > 0.0):
        raise ValueError("lbfgs_h0_base: H0's diagonal must be positive (a corrupt file)")
    if values is not None and base is not None and not np.all(values[:, diag] >= base[:, diag]):
        raise ValueError("lbfgs_h0_values: H0's diagonal is below its lagged part's (a corrupt file)")
    facts = 0
    if "lbfgs_h0_factorizations" in state:
        facts = int(_ck_array(state, "lbfgs_h0_factorizations", (), "iu"))
    hist.clear()
    for k in range(pairs):
        hist.s.append(np.array(s[k], dtype=np.float64))
        hist.y.append(np.array(y[k], dtype=np.float64))
        hist.rho.append(float(rho[k]))
    memo.clear()
    for name, a in corr.items():
        memo[name] = np.array(a, dtype=np.float64)
    if h is not None:
        memo["h"] = h
    if refresh is not None:
        memo["refresh"] = refresh
    h0.base, h0.h = (None, None) if base is None else (np.array(base, dtype=np.float64), h0_h)
    h0.values, h0.lu, h0._ratio = [None, None, None], [None, None, None], None
    if values is not None:
        h0.h = h0_h
        for d in range(3):
            v = np.array(values[d], dtype=np.float64)
            h0.lu[d] = h0.factor(v, d)
            h0.values[d] = v
    h0.factorizations = facts
