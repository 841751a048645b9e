"""Static equilibrium: Newton with line search on E(x) − f·x, with Dirichlet (fixed) vertices.

Reuses the implicit solver's machinery (:mod:`pliant.solvers.minimizers`): the fixed BSR(3×3) pattern built
from the energies' ``hessian_pattern``, the atomic block assembly, the projection of fixed rows and columns,
and the linear solvers (SciPy sparse LU on the host, or Jacobi-preconditioned ``warp.optim.linear.cg``).
Only the objective differs: there is no inertia term, so the Hessian is Σ H_e alone, which is singular
wherever the energies leave a direction free (a chain at rest length hanging straight: no transverse
stiffness). A singular factorisation is retried with a Levenberg–Marquardt shift H + μI on the free
components, μ growing from 1e-8·max diag(H) until the factor exists; the shift changes the step, not the
equilibrium (the gradient test decides convergence). Fixed components are a per-vertex or per-component
(per-DOF) mask; loads and gravity can be ramped in ``load_steps`` (each step starts from the last one's
equilibrium).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
import warp as wp

from ..._blas import single_threaded
from ...energies import Energy, Gravity
from ...model import Model
from .._errors import SingularSystemError
from ._assembly import _inverse_diagonal
from ._kernels import _negate, add_step_stats, max_abs
from ._problem import Workspace


@dataclass
class StaticStats:
    """What :func:`solve_static` did.

    Attributes:
        iterations: Newton iterations (linear solves), over all load steps.
        converged: whether the last load step's max_i |∇_i(E − f·x)| over the free components fell below
            ``tol`` times the larger of its initial value and the largest load, or below the round-off floor
            ``force_floor``; or the Newton step below ``tol`` times the model size; or the decrease the
            Newton step promises below the round-off of E − f·x (nothing left that float arithmetic sees).
        stop_reason: why it stopped: "converged", "max_iterations", "line search failed" (no decrease along
            the Newton direction: the round-off floor, or a non-descent direction), or "singular" (no
            regularised factorisation either: an unconstrained rigid motion under load).
        gradient_norm: max over free components of |∇| at the returned positions [N].
        residuals: ``gradient_norm`` at the start of every iteration and at the end [N].
        energy: E(x) − f·x at the returned positions [J].
        line_search_backtracks: total step halvings.
        linear_iterations: total CG iterations (0 for the direct solver).
        linear_solver: "direct" or "cg".
        fixed_count: number of vertices with at least one fixed component.
        fixed_dofs: number of fixed components (3 per fully fixed vertex).
        regularized_steps: Newton steps that needed the Levenberg–Marquardt shift (singular H).
        load_steps: load steps taken (the last one at the full load).
        force_floor: the round-off floor of the residual [N]: no tolerance asks for less (see
            ``solve_static``'s ``tol``).
    """

    iterations: int = 0
    converged: bool = False
    stop_reason: str = ""
    gradient_norm: float = float("nan")
    residuals: list[float] = field(default_factory=list)
    energy: float = float("nan")
    line_search_backtracks: int = 0
    linear_iterations: int = 0
    linear_solver: str = ""
    fixed_count: int = 0
    fixed_dofs: int = 0
    regularized_steps: int = 0
    load_steps: int = 0
    force_floor: float = 0.0


@wp.kernel(enable_backward=False)
def _load_terms(
    f_ext: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    mode: int,
    grad_out: wp.array(dtype=Any),
    value_out: wp.array(dtype=Any),
):
    # The dead loads as the potential −f·x: value (mode 0) or gradient −f (mode 1).
    i = wp.tid()
    if mode == 0:
        wp.atomic_add(value_out, 0, -wp.dot(f_ext[i], x_in[i]))
    else:
        grad_out[i] = grad_out[i] - f_ext[i]


class _DeadLoads(Energy):
    """−Σ f_i·x_i for constant nodal forces f [N]; zero Hessian."""

    def __init__(self, f: wp.array) -> None:
        self.f = f
        self._dummy: dict = {}

    def _d(self, model: Model, key: str, dtype: type) -> wp.array:
        if key not in self._dummy:
            self._dummy[key] = wp.zeros(1, dtype=dtype, device=model.device)
        return self._dummy[key]

    def value(self, model: Model, x: wp.array, out: wp.array) -> None:
        g = self._d(model, "g", model.vec3)
        wp.launch(_load_terms, model.particle_count, [self.f, x, 0, g, out], device=model.device)

    def gradient(self, model: Model, x: wp.array, out: wp.array) -> None:
        v = self._d(model, "v", model.scalar)
        wp.launch(_load_terms, model.particle_count, [self.f, x, 1, out, v], device=model.device)


@wp.kernel(enable_backward=False)
def _free_gradient_stats(
    free: wp.array(dtype=Any), grad_io: wp.array(dtype=Any), stats_out: wp.array(dtype=Any)
):
    # Zero the fixed components; stats[0] = max over free components of |g_ik|.
    i = wp.tid()
    g = wp.cw_mul(grad_io[i], free[i])
    grad_io[i] = g
    wp.atomic_max(stats_out, 0, max_abs(g))


@wp.kernel(enable_backward=False)
def _project_fixed_dofs(
    free: wp.array(dtype=Any),
    block_rows: wp.array(dtype=wp.int32),
    block_cols: wp.array(dtype=wp.int32),
    values_io: wp.array(dtype=Any),
):
    # Rows and columns of fixed components become those of the identity.
    k = wp.tid()
    r = block_rows[k]
    c = block_cols[k]
    fr = free[r]
    fc = free[c]
    m = values_io[k]
    one = type(fr[0])(1.0)
    for a in range(3):
        for b in range(3):
            m[a, b] = m[a, b] * fr[a] * fc[b]
        if r == c:
            m[a, a] = m[a, a] + (one - fr[a])
    values_io[k] = m


@wp.kernel(enable_backward=False)
def _static_step_stats(
    free: wp.array(dtype=Any),
    grad_in: wp.array(dtype=Any),
    dx_io: wp.array(dtype=Any),
    stats_out: wp.array(dtype=Any),
):
    # Zero Δx's fixed components (so that a trial point moves only free ones), then the step's statistics.
    i = wp.tid()
    d = wp.cw_mul(dx_io[i], free[i])
    dx_io[i] = d
    add_step_stats(grad_in[i], d, stats_out)


@wp.kernel(enable_backward=False)
def _static_trial(
    free: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    dx_in: wp.array(dtype=Any),
    alpha: Any,
    x_out: wp.array(dtype=Any),
):
    i = wp.tid()
    x_out[i] = x_in[i] + alpha * wp.cw_mul(dx_in[i], free[i])


def _as_vec3_array(model: Model, a: wp.array | npt.ArrayLike, what: str) -> wp.array:
    if isinstance(a, wp.array):
        if a.shape[0] != model.particle_count:
            raise ValueError(
                f"{what} has {a.shape[0]} entries, expected particle_count = {model.particle_count}"
            )
        a = a.numpy()
    arr = np.asarray(a, dtype=np.float64)
    if arr.shape == (3,):
        arr = np.broadcast_to(arr, (model.particle_count, 3))
    if arr.shape != (model.particle_count, 3):
        raise ValueError(f"{what} must have shape ({model.particle_count}, 3), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} contains NaN/inf")
    np_dtype = np.float32 if model.dtype == "float32" else np.float64
    return wp.array(arr.astype(np_dtype), dtype=model.vec3, device=model.device)


def _fixed_mask(model: Model, fixed: npt.ArrayLike | None) -> np.ndarray:
    """The fixed components as a bool [N, 3] mask: pinned/kinematic vertices plus ``fixed``."""
    n = model.particle_count
    mask = np.repeat((model.particle_inv_mass.numpy() == 0.0)[:, None], 3, axis=1)  # pins, kinematic
    if fixed is None:
        return mask
    f = np.asarray(fixed)
    if f.dtype == bool:
        if f.shape == (n,):
            mask |= f[:, None]
        elif f.shape == (n, 3):
            mask |= f
        else:
            raise ValueError(
                f"a boolean `fixed` mask must have shape ({n},) (vertices) or ({n}, 3) (components), "
                f"got {f.shape}"
            )
        return mask
    if f.size and not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"`fixed` must be vertex indices or a boolean mask, got dtype {f.dtype}")
    idx = f.astype(np.int64).reshape(-1)
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise ValueError(f"fixed indices must lie in [0, {n}), got {idx.min()}..{idx.max()}")
    mask[idx] = True
    return mask


def _regularized_direct_solve(ws: Workspace, model: Model, free_np: np.ndarray, stats: StaticStats) -> bool:
    """Δx = −H⁻¹∇ by SciPy's sparse LU; on a singular H, the smallest Levenberg–Marquardt shift
    H + μI (μ = 1e-8 · 100^k · max diag H, on free components) that factors. Returns False when none does.
    """
    with single_threaded():  # small host BLAS calls inside SuperLU (pliant._blas)
        return _direct_solve(ws, model, free_np, stats)


def _direct_solve(ws: Workspace, model: Model, free_np: np.ndarray, stats: StaticStats) -> bool:
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    n = model.particle_count
    vals = ws.values.numpy()[: ws.nnz].astype(np.float64)
    H = sp.bsr_matrix((vals, ws.indices, ws.indptr), shape=(3 * n, 3 * n)).tocsc()
    g = ws.grad.numpy().astype(np.float64).reshape(-1)
    free = free_np.reshape(-1).astype(np.float64)
    diag = np.abs(H.diagonal()) * free
    top = float(diag.max()) if diag.size else 0.0
    shifts = [0.0] + [1e-8 * top * 100.0**k for k in range(6)] if top > 0 else [0.0, 1.0]
    for mu in shifts:
        A = H if mu == 0.0 else (H + sp.diags(mu * free)).tocsc()
        try:
            # Symmetric (positive semi-)definite: symmetric ordering, no pivoting ("symmetric mode").
            lu = splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        except RuntimeError:  # "Factor is exactly singular"
            continue
        dx = lu.solve(-g)
        if not np.all(np.isfinite(dx)):
            continue
        if mu:
            stats.regularized_steps += 1
        ws.dx.assign(dx.reshape(n, 3).astype(ws.np_dtype))
        return True
    return False


def _roundoff_scales(model: Model, reach: float) -> tuple[float, float]:
    """(force [N], energy [J]) sizes of the elastic terms whose round-off bounds what a minimiser resolves.

    Positions are known to eps·``reach`` (max |x| [m]) only, so one element's force is uncertain by its
    stiffness k_e ≈ (2μ + |λ|)·V^(1/3) (a spring's k) times that, on top of the cancellation of its
    O(k_e·h_e) terms: force scale max_e k_e·(h_e + reach), with h_e = V^(1/3) (a spring's rest length).
    The energy scale Σ_e (2μ + |λ|)·V_e + Σ_s k_s·L_s² is the size of the terms that cancel in an elastic
    energy at small strain. Multiply by ~64·eps for floors. What matters is the coordinates against the
    elements: far from the origin (Cook's membrane: coordinates ~50, elements ~1-3) the floor is ~20x
    what the elements alone give.
    """
    force = energy = 0.0
    if model.tet_count:
        vol = np.abs(model.tet_rest_volume.numpy().astype(np.float64))
        mod = 2.0 * np.abs(model.tet_mu.numpy().astype(np.float64)) + np.abs(model.tet_lam.numpy())
        h = np.cbrt(vol)
        force = max(force, float(np.max(mod * h * (h + reach))))
        energy += float(np.sum(mod * vol))
    if model.spring_count:
        k = np.abs(model.spring_stiffness.numpy().astype(np.float64))
        rest = np.abs(model.spring_rest_length.numpy().astype(np.float64))
        force = max(force, float(np.max(k * (rest + reach))))
        energy += float(np.sum(k * rest * rest))
    return force, energy


def solve_static(
    model: Model,
    energies: Sequence[Energy],
    *,
    fixed: npt.ArrayLike | None = None,
    loads: wp.array | npt.ArrayLike | None = None,
    x0: wp.array | npt.ArrayLike | None = None,
    tol: float = 1e-6,
    max_iterations: int = 50,
    linear_solver: str = "auto",
    project_psd: bool = True,
    cg_tol: float = 1e-10,
    cg_max_iterations: int = 10_000,
    max_line_search: int = 30,
    load_steps: int = 1,
) -> tuple[wp.array, StaticStats]:
    """Static equilibrium x* = argmin E(x) − f·x over the free components, by Newton with line search.

    Dirichlet conditions: components in ``fixed``, and every component of pinned and kinematic vertices
    (inverse mass 0), stay at their values in ``x0`` — move them in ``x0`` to prescribe a displacement.
    Each Newton step solves H Δx = −∇ on the free components (fixed rows and columns replaced by the
    identity), shifted to H + μI when H is singular (see the module notes), then backtracks from
    α = min(1, min_e max_step) until Armijo's condition holds on E − f·x.

    Args:
        model: the Model.
        energies: potential terms, e.g. ``[pl.energies.LinearElastic(), pl.energies.Gravity()]``; no
            dissipative terms. ``Gravity`` is applied as the dead loads m_i g (the same potential), so that
            it is ramped with ``loads``.
        fixed: what is held in place, added to the model's pinned and kinematic vertices: vertex indices, a
            boolean mask over vertices [particle_count], or a boolean mask over components
            [particle_count, 3] (e.g. a roller: only y fixed).
        loads: constant nodal forces f [N], shape [particle_count, 3] (or one vec3 for every vertex).
        x0: initial positions and prescribed positions of the fixed components [m], shape
            [particle_count, 3]; default the model's rest positions.
        tol: relative tolerance: stop when max |∇| ≤ tol · max(|∇(x0)|, |f|) over free components (the
            start's residual or the largest load), or below the round-off floor of the forces (scaled by
            the elements' stiffness and the coordinates' magnitude), or when a full Newton step moves no
            component more than tol · (model size).
        max_iterations: Newton iteration cap per load step.
        linear_solver: "direct" (SciPy sparse LU, on the host, regularised when singular), "cg"
            (Jacobi-preconditioned Warp CG, any device) or "auto" (direct on the CPU, CG on a GPU).
        project_psd: project element Hessians to PSD (keeps Newton a descent method far from equilibrium).
        cg_tol: CG relative residual.
        cg_max_iterations: CG iteration cap.
        max_line_search: step halvings before giving up.
        load_steps: solve at 1/n, 2/n, ..., n/n of the loads and gravity, each from the previous
            equilibrium (large deformations under large loads; default 1: the full load at once).

    Returns:
        ``(x, stats)``: the equilibrium positions (a new Warp array, shape [particle_count] of vec3) and a
        :class:`StaticStats` whose ``stop_reason`` says why it stopped.

    Raises:
        SingularSystemError: (pliant.solvers) H + μI is singular for every shift tried: nothing holds the
            free components against the load (add fixed vertices or a ground).

    Example::

        b = pl.ModelBuilder(gravity=(0, -9.81, 0))
        b.add_soft_box(cells=(20, 2, 2), size=(1.0, 0.1, 0.1), origin=(0.5, 0, 0), E=1e7)
        model = b.finalize(dtype="float64")
        X = model.particle_q_np
        x, stats = pl.solvers.solve_static(model, [pl.energies.NeoHookean(), pl.energies.Gravity()],
                                           fixed=np.flatnonzero(X[:, 0] < 1e-9), load_steps=4)
    """
    energies = list(energies)
    for e in energies:
        if not isinstance(e, Energy):
            raise TypeError(f"energies must be pl.energies.Energy objects, got {type(e).__name__}")
        if e.dissipative:
            raise ValueError(
                f"{type(e).__name__} is dissipative (velocity dependent); statics has no velocity"
            )
    if not tol > 0:
        raise ValueError(f"tol must be > 0, got {tol}")
    if not 1 <= max_iterations:
        raise ValueError(f"max_iterations must be >= 1, got {max_iterations}")
    if not (isinstance(load_steps, (int, np.integer)) and 1 <= load_steps <= 100_000):
        raise ValueError(f"load_steps must be a whole number in [1, 100000], got {load_steps!r}")
    if linear_solver not in ("direct", "cg", "auto"):
        raise ValueError(f"linear_solver must be 'direct', 'cg' or 'auto', got {linear_solver!r}")
    # Static stiffness matrices are far worse conditioned than M + h²K: on the CPU a direct solve wins at
    # every size that fits in memory, so "auto" means direct there and CG on a GPU.
    lin = linear_solver
    if lin == "auto":
        lin = "direct" if wp.get_device(model.device).is_cpu else "cg"
    n = model.particle_count
    dev = model.device
    np_dtype = np.float32 if model.dtype == "float32" else np.float64
    mask = _fixed_mask(model, fixed)
    free_np = (~mask).astype(np_dtype)
    free: wp.array = wp.array(free_np, dtype=model.vec3, device=dev)
    # Dead loads: the given forces plus gravity's m_i g (Gravity's potential −Σ m_i g·x exactly), ramped.
    f_total = np.zeros((n, 3))
    if loads is not None:
        f_total += _as_vec3_array(model, loads, "loads").numpy().astype(np.float64)
    terms = []
    for e in energies:
        if type(e) is Gravity:
            f_total += model.particle_mass_np[:, None] * np.asarray(model.gravity, dtype=np.float64)[None, :]
        else:
            terms.append(e)
    load_arr = wp.zeros(n, dtype=model.vec3, device=dev)
    if np.any(f_total):
        terms.append(_DeadLoads(load_arr))
    x = wp.clone(model.particle_q) if x0 is None else _as_vec3_array(model, x0, "x0")
    x_np = x.numpy().astype(np.float64)
    size = float(np.max(np.ptp(x_np, axis=0))) if n > 1 else 1.0
    eps = float(np.finfo(np_dtype).eps)

    ws = Workspace(model, terms)
    stats = StaticStats(
        linear_solver=lin, fixed_count=int(mask.any(axis=1).sum()), fixed_dofs=int(mask.sum())
    )
    gstat = wp.zeros(1, dtype=model.scalar, device=dev)
    ebuf = wp.zeros(1, dtype=model.scalar, device=dev)
    sstat = wp.zeros(2, dtype=model.scalar, device=dev)

    def energy(y: wp.array) -> float:
        ebuf.zero_()
        for e in terms:
            e.value(model, y, ebuf)
        return float(ebuf.numpy()[0])

    def gradient(y: wp.array) -> float:
        ws.grad.zero_()
        for e in terms:
            e.gradient(model, y, ws.grad)
        gstat.zero_()
        wp.launch(_free_gradient_stats, n, [free, ws.grad, gstat], device=dev)
        return float(gstat.numpy()[0])

    # Round-off: positions are known to eps·max|x| only, so forces carry 64·eps·(element stiffness ×
    # (element size + max|x|)) of noise, and E − f·x that of the terms that cancel in it (_roundoff_scales;
    # Cook's membrane, coordinates ~50 and elements ~1-3, has a floor ~20x its elements' alone).
    force_scale, energy_scale = _roundoff_scales(model, float(np.max(np.abs(x_np))) if n else 0.0)
    force_floor = 64.0 * eps * force_scale
    energy_scale += float(np.sum(np.linalg.norm(f_total, axis=1) * np.linalg.norm(x_np, axis=1)))
    stats.force_floor = force_floor
    g = e0 = float("nan")
    for step in range(1, load_steps + 1):
        f_step = f_total * (step / load_steps)
        load_arr.assign(f_step.astype(np_dtype))
        stats.load_steps = step
        stats.converged, stats.stop_reason = False, "max_iterations"
        g = gradient(x)
        e0 = energy(x)
        stats.residuals.append(g)
        # Relative to the larger of the start's residual and the loads on the free components (a start near
        # equilibrium must not ask for a residual below what the loads' own round-off allows), never below
        # the round-off floor of the forces.
        load = float(np.max(np.abs(f_step) * free_np)) if n else 0.0
        target = max(tol * max(g, load), force_floor)
        for _ in range(max_iterations):
            if g <= target or g == 0.0:
                stats.converged = True
                break
            # H on the fixed pattern; fixed rows/columns become the identity.
            ws.values.zero_()
            for e, slots in zip(terms, ws.slots, strict=True):
                if slots.shape[0]:
                    e.hessian(model, x, slots, ws.values, project_psd=project_psd, scale=1.0)
            wp.launch(
                _project_fixed_dofs, ws.nnz, [free, ws.block_rows, ws.block_cols, ws.values], device=dev
            )
            if lin == "direct":
                if not _regularized_direct_solve(ws, model, free_np, stats):
                    stats.stop_reason = "singular"
                    break
            else:
                wp.launch(_inverse_diagonal, n, [ws.diag_slots, ws.values, ws.inv_diag], device=dev)
                wp.launch(_negate, n, [ws.grad, ws.rhs], device=dev)
                ws.dx.zero_()
                it, _, _ = ws.cg(cg_tol, cg_max_iterations)()
                stats.linear_iterations += int(it)
            stats.iterations += 1
            sstat.zero_()
            wp.launch(_static_step_stats, n, [free, ws.grad, ws.dx, sstat], device=dev)
            dx_max, gdx = (float(v) for v in sstat.numpy())
            if not (np.isfinite(dx_max) and np.isfinite(gdx)):
                stats.stop_reason = "singular"
                break
            alpha = 1.0
            for e in terms:
                alpha = min(alpha, float(e.max_step(model, x, ws.dx)))
            accepted = False
            # Armijo with an allowance for the round-off of E − f·x: of its value, and of the terms that
            # cancel in it (each element's energy is computed from O(μV) terms even at small strain).
            noise = 64.0 * eps * (abs(e0) + energy_scale)
            for _ls in range(max_line_search + 1):
                wp.launch(_static_trial, n, [free, x, ws.dx, model.s(alpha), ws.x_trial], device=dev)
                e1 = energy(ws.x_trial)
                if e1 <= e0 + 1e-4 * alpha * gdx + noise + 64.0 * eps * abs(e1):
                    accepted = True
                    break
                alpha *= 0.5
                stats.line_search_backtracks += 1
            if not accepted:
                # The full Newton step promises a decrease of −½∇·Δx. Below the energy's round-off no line
                # search can see it: the iterate is at the floor of what E − f·x resolves, i.e. converged.
                if gdx < 0.0 and -0.5 * gdx <= noise:
                    stats.converged = True
                    break
                stats.stop_reason = "line search failed"
                break  # no decrease for a tiny step: round-off floor or a non-descent direction
            wp.copy(x, ws.x_trial)
            e0 = e1
            g = gradient(x)
            stats.residuals.append(g)
            if g <= target or (alpha == 1.0 and dx_max <= tol * size):
                stats.converged = True
                break
        if stats.converged:
            stats.stop_reason = "converged"
        elif step < load_steps:
            break  # an intermediate load step failed: the later ones would start from a wrong state
    if stats.stop_reason == "singular":
        raise SingularSystemError(
            "solve_static: the stiffness matrix is singular even with a Levenberg-Marquardt shift "
            f"(load step {stats.load_steps} of {load_steps}, iteration {stats.iterations}): some free "
            "vertices are held by nothing against the load; fix vertices (fixed=...), add a ground or "
            "springs, or check for unconnected particles"
        )
    stats.gradient_norm = g
    stats.energy = e0
    return x, stats
