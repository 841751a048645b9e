"""Dense Newton (a demonstration of a minimiser added to the registry): full Newton steps from x̃, each
linear system solved densely by NumPy. No line search, no step bound: for small, mildly nonlinear steps."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from ._assembly import assemble, gradient
from ._options import step_settings
from ._problem import NewtonStats, workspace_of

if TYPE_CHECKING:
    from ...integrators._implicit import ImplicitOptionsLike
    from ._options import MinimizerLike
    from ._problem import PotentialProblem


def minimize_dense_newton(
    problem: PotentialProblem,
    t: float,
    h: float,
    x_tilde: wp.array,
    x_ref: wp.array,
    v_ref: wp.array,
    x_out: wp.array,
    options: ImplicitOptionsLike = None,
    minimizer: MinimizerLike = None,
) -> NewtonStats:
    """x_out = argmin Φ by full Newton steps with a dense solve (arguments as
    :func:`~pliant.solvers.minimizers.minimize_incremental_potential`)."""
    opts, _ = step_settings(options, minimizer)
    m, ws = problem.model, workspace_of(problem)
    n = m.particle_count
    stats = NewtonStats(linear_solver="dense", tolerance=float(opts.newton_tol), projected=True)
    wp.copy(x_out, x_tilde)
    g = gradient(problem, ws, x_out, x_tilde, h)
    stats.residuals.append(float(g[0]))
    while stats.iterations < opts.max_newton_iterations and not g[0] <= opts.newton_tol:
        assemble(problem, ws, x_out, h, True)
        H = np.zeros((n, 3, n, 3))
        rows = np.repeat(np.arange(n), np.diff(ws.indptr))
        H[rows, :, ws.indices, :] = ws.values.numpy()[: ws.nnz].astype(np.float64)
        dx = np.linalg.solve(H.reshape(3 * n, 3 * n), -ws.grad.numpy().astype(np.float64).reshape(-1))
        x_out.assign((x_out.numpy() + dx.reshape(n, 3)).astype(ws.np_dtype))
        g = gradient(problem, ws, x_out, x_tilde, h)
        stats.iterations += 1
        stats.residuals.append(float(g[0]))
    stats.converged = bool(g[0] <= opts.newton_tol)
    stats.gradient_norm = float(g[0])
    problem.last_stats = stats
    return stats
