"""Static equilibrium: Newton with line search on E(x) − f·x, with Dirichlet (fixed) vertices.

Reuses the implicit solver's machinery (:mod:`pliant.solvers._newton`): the fixed BSR(3×3) pattern built
from the energies' ``hessian_pattern``, the atomic block assembly, the projection of fixed rows and columns,
and the linear solvers (SciPy sparse LU on the host, or Jacobi-preconditioned ``warp.optim.linear.cg``).
Only the objective differs: there is no inertia term, so the Hessian is Σ H_e alone.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import warp as wp

from ..energies import Energy
from ..model import Model
from . import _newton as nw


@dataclass
class StaticStats:
    """What :func:`solve_static` did.

    Attributes:
        iterations: Newton iterations (linear solves).
        converged: whether max_i |∇_i(E − f·x)| over the free vertices fell below ``tol`` times its initial
            value (or the Newton step below ``tol`` times the model size).
        gradient_norm: max_i |∇_i| over free vertices at the returned positions [N].
        residuals: ``gradient_norm`` at the start of every iteration and at the end [N].
        energy: E(x) − f·x at the returned positions [J].
        line_search_backtracks: total step halvings.
        linear_iterations: total CG iterations (0 for the direct solver).
        linear_solver: "direct" or "cg".
        fixed_count: number of fixed vertices.
    """

    iterations: int = 0
    converged: bool = False
    gradient_norm: float = float("nan")
    residuals: list[float] = field(default_factory=list)
    energy: float = float("nan")
    line_search_backtracks: int = 0
    linear_iterations: int = 0
    linear_solver: str = ""
    fixed_count: int = 0


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

    def _d(self, model: Model, key: str, dtype: Any) -> wp.array:
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
def _fixed_gradient_stats(
    free: wp.array(dtype=Any), grad: wp.array(dtype=Any), stats_out: wp.array(dtype=Any)
):
    # Zero the fixed rows; stats[0] = max over free vertices of max_k |g_ik|.
    i = wp.tid()
    if free[i] == type(free[i])(0.0):
        grad[i] = grad[i] * type(free[i])(0.0)
        return
    g = grad[i]
    wp.atomic_max(stats_out, 0, wp.max(wp.max(wp.abs(g[0]), wp.abs(g[1])), wp.abs(g[2])))


@wp.kernel(enable_backward=False)
def _static_trial(
    free: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    dx: wp.array(dtype=Any),
    alpha: Any,
    x_out: wp.array(dtype=Any),
):
    i = wp.tid()
    x = x_in[i]
    if free[i] != type(alpha)(0.0):
        x = x + alpha * dx[i]
    x_out[i] = x


def _as_vec3_array(model: Model, a: Any, what: str) -> wp.array:
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


def _fixed_mask(model: Model, fixed: Any) -> np.ndarray:
    mask = model.particle_inv_mass.numpy() == 0.0  # pins and kinematic particles
    if fixed is not None:
        f = np.asarray(fixed)
        if f.dtype == bool:
            if f.shape != (model.particle_count,):
                raise ValueError(
                    f"a boolean `fixed` mask must have shape ({model.particle_count},), got {f.shape}"
                )
            mask |= f
        else:
            idx = f.astype(np.int64).reshape(-1)
            if idx.size and (idx.min() < 0 or idx.max() >= model.particle_count):
                raise ValueError(
                    f"fixed indices must lie in [0, {model.particle_count}), got {idx.min()}..{idx.max()}"
                )
            mask[idx] = True
    return mask


def solve_static(
    model: Model,
    energies: Sequence[Energy],
    *,
    fixed: Any = None,
    loads: Any = None,
    x0: Any = None,
    tol: float = 1e-6,
    max_iterations: int = 50,
    linear_solver: str = "auto",
    project_psd: bool = True,
    cg_tol: float = 1e-10,
    cg_max_iterations: int = 10_000,
    max_line_search: int = 30,
) -> tuple[wp.array, StaticStats]:
    """Static equilibrium x* = argmin E(x) − f·x over the free vertices, by Newton with line search.

    Dirichlet conditions: vertices in ``fixed``, pinned ones and kinematic ones (inverse mass 0) stay at
    their positions in ``x0`` — move them in ``x0`` to prescribe a displacement. Each Newton step solves
    H Δx = −∇ on the free vertices (fixed rows and columns replaced by the identity), then backtracks from
    α = min(1, min_e max_step) until Armijo's condition holds on E − f·x.

    Args:
        model: the Model.
        energies: potential terms, e.g. ``[pl.energies.LinearElastic(), pl.energies.Gravity()]``; no
            dissipative terms.
        fixed: indices (or a boolean mask over particles) of vertices held in place, added to the model's
            pinned and kinematic ones.
        loads: constant nodal forces f [N], shape [particle_count, 3] (or one vec3 for every vertex).
        x0: initial positions and prescribed positions of the fixed vertices [m], shape [particle_count, 3];
            default the model's rest positions.
        tol: relative tolerance: stop when max_i |∇_i| ≤ tol · max_i |∇_i(x0)| over free vertices (or
            below the round-off floor of the elastic forces), or when a full Newton step moves no vertex
            more than tol · (model size). The free vertices must be held (fixed vertices, or an energy
            such as a ground penalty): otherwise rigid motions make the Hessian singular.
        max_iterations: Newton iteration cap.
        linear_solver: "direct" (SciPy sparse LU, on the host), "cg" (Jacobi-preconditioned Warp CG, any
            device) or "auto" (direct on the CPU, CG on a GPU).
        project_psd: project element Hessians to PSD (keeps Newton a descent method far from equilibrium).
        cg_tol: CG relative residual.
        cg_max_iterations: CG iteration cap.
        max_line_search: step halvings before giving up.

    Returns:
        ``(x, stats)``: the equilibrium positions (a new Warp array, shape [particle_count] of vec3) and a
        :class:`StaticStats`.

    Example::

        b = pl.ModelBuilder(gravity=(0, -9.81, 0))
        b.add_soft_box(cells=(20, 2, 2), size=(1.0, 0.1, 0.1), origin=(0.5, 0, 0), E=1e7)
        model = b.finalize(dtype="float64")
        X = model.particle_q_np
        x, stats = pl.solvers.solve_static(model, [pl.energies.NeoHookean(), pl.energies.Gravity()],
                                           fixed=np.flatnonzero(X[:, 0] < 1e-9))
    """
    energies = list(energies)
    for e in energies:
        if not isinstance(e, Energy):
            raise TypeError(f"energies must be pl.energies.Energy objects, got {type(e).__name__}")
        if e.dissipative:
            raise ValueError(
                f"{type(e).__name__} is dissipative (velocity dependent); statics has no velocity"
            )
    if tol <= 0:
        raise ValueError(f"tol must be > 0, got {tol}")
    if max_iterations < 1:
        raise ValueError(f"max_iterations must be >= 1, got {max_iterations}")
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
    free = wp.array((~mask).astype(np_dtype), dtype=model.scalar, device=dev)
    ones = wp.array(np.ones(n, np_dtype), dtype=model.scalar, device=dev)
    terms = list(energies)
    if loads is not None:
        terms.append(_DeadLoads(_as_vec3_array(model, loads, "loads")))
    x = wp.clone(model.particle_q) if x0 is None else _as_vec3_array(model, x0, "x0")
    x_np = x.numpy().astype(np.float64)
    size = float(np.max(np.ptp(x_np, axis=0))) if n > 1 else 1.0
    eps = float(np.finfo(np_dtype).eps)

    ws = nw._Workspace(model, terms)
    stats = StaticStats(linear_solver=lin, fixed_count=int(mask.sum()))
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
        wp.launch(_fixed_gradient_stats, n, [free, ws.grad, gstat], device=dev)
        return float(gstat.numpy()[0])

    g = gradient(x)
    e0 = energy(x)
    g0 = g
    stats.residuals.append(g)
    # Round-off floor: elastic forces carry ~eps·μ·V^(2/3) of noise per tet, summed over ~20 tets a vertex.
    force_scale = 0.0
    if model.tet_count:
        force_scale = float(
            np.max(model.tet_mu.numpy() * np.abs(model.tet_rest_volume.numpy()) ** (2.0 / 3.0))
        )
    target = max(tol * g0, 64.0 * eps * force_scale)
    for _ in range(max_iterations):
        if g <= target or g == 0.0:
            stats.converged = True
            break
        # H on the fixed pattern; fixed rows/columns become the identity (free = 0 → 1·I).
        ws.values.zero_()
        for e, slots in zip(terms, ws.slots, strict=True):
            if slots.shape[0]:
                e.hessian(model, x, slots, ws.values, project_psd=project_psd, scale=1.0)
        wp.launch(
            nw._project_fixed, ws.nnz, [free, ones, ws.block_rows, ws.block_cols, ws.values], device=dev
        )
        if lin == "direct":
            nw._direct_solve(ws, model)
        else:
            wp.launch(nw._inverse_diagonal, n, [ws.diag_slots, ws.values, ws.inv_diag], device=dev)
            wp.launch(nw._negate, n, [ws.grad, ws.rhs], device=dev)
            ws.dx.zero_()
            it, _, _ = ws.cg(cg_tol, cg_max_iterations)()
            stats.linear_iterations += int(it)
        stats.iterations += 1
        sstat.zero_()
        wp.launch(nw._step_stats, n, [free, ws.grad, ws.dx, sstat], device=dev)
        dx_max, gdx = (float(v) for v in sstat.numpy())
        alpha = 1.0
        for e in terms:
            alpha = min(alpha, float(e.max_step(model, x, ws.dx)))
        accepted = False
        for _ls in range(max_line_search + 1):
            wp.launch(_static_trial, n, [free, x, ws.dx, model.s(alpha), ws.x_trial], device=dev)
            e1 = energy(ws.x_trial)
            slack = 64.0 * eps * (abs(e0) + abs(e1))
            if e1 <= e0 + 1e-4 * alpha * gdx + slack:
                accepted = True
                break
            alpha *= 0.5
            stats.line_search_backtracks += 1
        if not accepted:
            break  # no decrease for a tiny step: round-off floor or a non-descent direction
        wp.copy(x, ws.x_trial)
        e0 = e1
        g = gradient(x)
        stats.residuals.append(g)
        if g <= target or (alpha == 1.0 and dx_max <= tol * size):
            stats.converged = True
            break
    stats.gradient_norm = g
    stats.energy = e0
    return x, stats
