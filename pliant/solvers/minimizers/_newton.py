"""Newton's method on the incremental potential: the implicit integrators' physics (Baraff–Witkin, IPC).

One implicit step of size h minimises

    Φ(x) = ½ ‖x − x̃‖²_M + h² Σ_e E_e(x)

over the free particles (inverse mass > 0); pinned and kinematic particles stay at x̃. Dissipative terms
(dashpots) are Rayleigh potentials about the reference positions x_ref, prepared by ``begin_step`` with the
same h, so that h²∇R is the dashpot impulse at v = (x − x_ref)/h (see ``pliant.energies.Dashpots``).

The Control's external forces f enter as the potential −f·x and its drag handle as ½k|x − target|², so
implicit and explicit integrators see the same forces.

The Hessian H = M + h² Σ H_e lives on a fixed BSR(3×3) pattern built once per model: the union of every
energy's ``hessian_pattern`` plus the diagonal. Each energy's blocks are mapped once to ``slots`` (positions
in the sorted (row, col) keys), so assembly per Newton iteration is: zero the values, add M, let every
energy atomically add h²·H_e. The linear system is solved by Jacobi-preconditioned ``warp.optim.linear.cg``
(any device) or a SciPy sparse direct solve (CPU).

Host synchronisation: each Newton iteration reads back one small statistics array after the gradient
(convergence test) and one per line-search trial (Φ at the trial point and the directional derivative),
plus, once per step, the largest H_ii/m_i (the round-off floor of the tolerance); CG itself checks its
residual on the host every 10 iterations. The direct solver copies the matrix to the host. Nothing else
leaves the device.

Reference: D. Baraff, A. Witkin, "Large steps in cloth simulation", SIGGRAPH 1998; M. Li et al.,
"Incremental Potential Contact", ACM TOG 39(4), 2020 (Newton with backtracking on Φ, step-size bound).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from ..._warp import launch
from ._adjoint import differentiable
from ._assembly import _inverse_diagonal, assemble, control_terms, gradient, stiffness_ratio
from ._kernels import _negate, _step_stats, _toward, _trial_point
from ._options import step_settings
from ._problem import (
    NewtonStats,
    Workspace,
    direct_solve,
    host_cg_solve,
    needs_feasible_start,
    resolve_linear_solver,
    workspace_of,
)

if TYPE_CHECKING:
    from ...integrators import ImplicitOptionsLike
    from ...model import Model
    from ._options import MinimizerLike
    from ._problem import PotentialProblem


def _feasible_start(
    solver: PotentialProblem, ws: Workspace, x_ref: wp.array, x_tilde: wp.array, x: wp.array
) -> bool:
    """With an energy that needs it, x = x_ref + α(x̃ − x_ref) (free particles; fixed ones at x̃), α ≤ 1 the
    energies' ``max_step`` from x_ref: the start is then as admissible as x_ref (IPC starts from x_ref).
    An energy with ``carried_start`` (barrier contact with moving colliders) may replace x_ref here by
    positions admissible at the step's end. Returns whether it applied (the energies then refresh their
    Hessian patterns at this start)."""
    if not needs_feasible_start(solver):
        return False
    m = solver.model
    n = m.particle_count
    for e in solver.energies:
        carried = getattr(e, "carried_start", None)
        moved = carried(m, x_ref) if carried is not None else None
        if moved is not None:
            x_ref = moved
    launch(_toward, n, [m.particle_inv_mass, x_ref, x_tilde, m.s(0.0), 0, ws.dx, x], device=m.device)
    alpha = 1.0
    for e in solver.energies:
        alpha = min(alpha, float(e.max_step(m, x_ref, ws.dx)))
    if alpha < 1.0:
        launch(_toward, n, [m.particle_inv_mass, x_ref, x_tilde, m.s(alpha), 1, ws.dx, x], device=m.device)
    return True


def _refresh_patterns(solver: PotentialProblem, x: wp.array) -> bool:
    """Let every energy refresh its Hessian pattern at x; returns whether any changed."""
    m = solver.model
    before = [e.pattern_version(m) for e in solver.energies]
    for e in solver.energies:
        e.refresh_pattern(m, x)
    return before != [e.pattern_version(m) for e in solver.energies]


def _stiffness_ratio(ws: Workspace, m: Model) -> float:
    """max_i H_ii/m_i over the free particles of the assembled H = M + h²K [1] (one host read)."""
    ws.hstats.zero_()
    launch(
        stiffness_ratio,
        m.particle_count,
        [m.particle_inv_mass, ws.diag_slots, ws.values, ws.hstats],
        device=m.device,
    )
    return float(ws.hstats.numpy()[0])


def _direction(ws: Workspace, m: Model, lin: str, cg_tol: float, cg_max: int) -> int:
    """The Newton direction H dx = −∇Φ into ``ws.dx`` by the linear solver ``lin`` ("direct", "scipy-cg" or
    Warp's Jacobi-preconditioned CG); returns the CG iterations it took (0 for the direct solve)."""
    n = m.particle_count
    if lin == "direct":
        direct_solve(ws, m)
        return 0
    if lin == "scipy-cg":
        return host_cg_solve(ws, m, cg_tol, cg_max)
    launch(_inverse_diagonal, n, [ws.diag_slots, ws.values, ws.inv_diag], device=m.device)
    launch(_negate, n, [ws.grad, ws.rhs], device=m.device)
    ws.dx.zero_()
    cg_iterations, _, _ = ws.cg(cg_tol, cg_max)()
    return int(cg_iterations)


def _line_search(
    solver: PotentialProblem,
    ws: Workspace,
    x: wp.array,
    x_tilde: wp.array,
    h: float,
    phi0: float,
    eps: float,
    max_ls: int,
    strict: bool,
    stats: NewtonStats,
) -> tuple[bool, bool, float, float]:
    """Line search along ``ws.dx`` from ``x``: α ≤ min over energies of max_step, halved until Armijo holds on
    Φ (at most ``max_ls`` halvings; with ``strict`` it stops at once on a non-descent direction). Returns
    (accepted, descent, α, max |dx| over free particles [m]); the trial point is left in ``ws.x_trial``."""
    m = solver.model
    n = m.particle_count
    h2 = h * h
    alpha = 1.0
    for e in solver.energies:
        alpha = min(alpha, float(e.max_step(m, x, ws.dx)))
    accepted = descent = False
    dx_max = gdx = 0.0
    for ls in range(max_ls + 1):
        if ls == 0:
            ws.tstats.zero_()
            launch(_step_stats, n, [m.particle_inv_mass, ws.grad, ws.dx, ws.tstats_step], device=m.device)
        else:
            ws.tstats_phi.zero_()
        launch(
            _trial_point,
            n,
            [m.particle_inv_mass, m.particle_mass, x, ws.dx, x_tilde, m.s(alpha), ws.x_trial, ws.tstats],
            device=m.device,
        )
        for e in solver.energies:
            e.value(m, ws.x_trial, ws.tstats_e)
        control_terms(solver, ws, ws.x_trial, ws.egrad_scratch, ws.tstats_e)
        s = ws.tstats.numpy().astype(np.float64)
        dx_max, gdx = s[2], s[3]
        descent = bool(np.isfinite(gdx) and gdx < 0.0)
        if not descent and strict:
            break
        phi = s[0] + h2 * s[1]
        # Armijo with an allowance for the round-off of Φ's terms.
        slack = 64.0 * eps * (abs(s[0]) + h2 * abs(s[1]) + abs(phi0))
        if phi <= phi0 + 1e-4 * alpha * gdx + slack:
            accepted = True
            break
        alpha *= 0.5
        stats.line_search_backtracks += 1
    return accepted, descent, alpha, dx_max


@differentiable
def minimize_incremental_potential(
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
    """x_out = argmin_x ½‖x − x̃‖²_M + h² Σ E(x) by Newton with an Armijo line search.

    Args:
        solver: a ForceSolver (``model``, ``energies``); ``solver.last_stats`` receives the statistics.
        t: time at the start of the step [s] (unused by time-independent energies).
        h: the step [s] weighting the energies (and the Rayleigh dissipation's Δt).
        x_tilde: inertial target x̃ [m], shape [particle_count] of vec3; also the initial guess.
        x_ref: positions at the start of the step [m] (dissipation reference).
        v_ref: velocities at the start of the step [m/s].
        x_out: the minimiser [m] (may not alias the inputs).
        options: :class:`pliant.integrators.ImplicitOptions` (an implicit integrator, a dict of some of its
            settings, or None for the defaults): ``newton_tol`` [m/s], ``max_newton_iterations``,
            ``project_psd``, ``max_line_search``.
        minimizer: :class:`~pliant.solvers.MinimizerOptions` (a dict of some of its settings, or None for
            the defaults): ``linear_solver``, ``cg_tol``, ``cg_max_iterations``.

    Returns:
        :class:`NewtonStats`.
    """
    m = solver.model
    ws = workspace_of(solver)
    opts, mz = step_settings(options, minimizer)
    tol_opt = float(opts.newton_tol)
    max_it = int(opts.max_newton_iterations)
    lin = resolve_linear_solver(mz.linear_solver, m)
    cg_tol = max(float(mz.cg_tol), 30.0 * float(np.finfo(ws.np_dtype).eps))
    cg_max = int(mz.cg_max_iterations)
    project_psd = "project" if opts.project_psd is True else opts.project_psd
    max_ls = int(opts.max_line_search)
    eps = float(np.finfo(np.float32 if m.dtype == "float32" else np.float64).eps)
    stats = NewtonStats(linear_solver=lin)

    for e in solver.energies:
        if e.dissipative:
            e.begin_step(m, x_ref, v_ref, h)
    wp.copy(x_out, x_tilde)
    x = x_out
    # Contact energies' patterns follow their pairs: refreshed at the start and after every iterate.
    refresh = _feasible_start(solver, ws, x_ref, x_tilde, x)
    if refresh and _refresh_patterns(solver, x):
        ws = workspace_of(solver)
    h2 = h * h
    g = gradient(solver, ws, x, x_tilde, h)
    # Round-off floor: positions are known to eps·max|x|; one ulp moves ∇Φ_i/(m_i h) by up to
    # eps·max|x|·max_i(H_ii/m_i)/h (the stiffness term dominates in float32). Known after the first assembly.
    tol = max(tol_opt, 8.0 * eps * max(g[1], 1.0) / h)
    stats.tolerance = tol
    stats.residuals.append(float(g[0]))
    # "auto": exact Hessians while they give descent directions, PSD-projected ones from the first failure on
    # (projection keeps H ⪰ M but makes Newton linear where springs are compressed).
    project = project_psd == "project"
    switchable = project_psd == "auto"
    stats.projected = project
    first = True
    while stats.iterations < max_it:
        # The round-off floor only ends iterations after the first: at x̃ the gradient is no noise.
        if g[0] <= (tol if stats.iterations else tol_opt):
            stats.converged = True
            break
        phi0 = g[2] + h2 * g[3]
        assemble(solver, ws, x, h, project)
        if first:
            first = False
            tol = max(tol, eps * max(g[1], 1.0) * _stiffness_ratio(ws, m) / h)
            stats.tolerance = tol
        stats.linear_iterations += _direction(ws, m, lin, cg_tol, cg_max)
        stats.iterations += 1
        strict = switchable and not project  # a non-descent direction ends the search (then projection)
        accepted, descent, alpha, dx_max = _line_search(
            solver, ws, x, x_tilde, h, phi0, eps, max_ls, strict, stats
        )
        if switchable and not project and (not descent or not accepted):
            project = True  # the exact Hessian is indefinite here: redo this iteration with projection
            stats.projected = True
            continue
        stats.step_norm = float(alpha * dx_max / h)
        if not accepted:
            if lin == "scipy-cg":
                lin = "direct"  # an inexact CG direction may not descend on a stiff problem: solve exactly
                stats.linear_solver = "scipy-cg+direct"
                continue
            break  # no decrease even for a tiny step: at the round-off floor (or a non-descent direction)
        wp.copy(x, ws.x_trial)
        if refresh and _refresh_patterns(solver, x):
            ws = workspace_of(solver)
        g = gradient(solver, ws, x, x_tilde, h)
        stats.residuals.append(float(g[0]))
        if g[0] <= tol:
            stats.converged = True
            break
        if stats.step_norm <= 1e-3 * tol:
            if lin == "scipy-cg":
                lin = "direct"  # stagnation from CG's inexact solves (ill-conditioned H): finish exactly
                stats.linear_solver = "scipy-cg+direct"
                continue
            break  # stagnating far below the tolerance on the step: round-off or an inexact Hessian
    stats.gradient_norm = float(g[0])
    solver.last_stats = stats
    return stats
