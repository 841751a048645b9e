"""One implicit step's minimiser, chosen by the options' ``method``: Newton or L-BFGS."""

from __future__ import annotations

from typing import TYPE_CHECKING

import warp as wp

from ..._blas import single_threaded
from ._newton import minimize_incremental_potential
from ._options import device_newton, resolve_method, step_settings
from ._pcg import minimize_device
from ._problem import needs_feasible_start
from ._quasi_newton import minimize_quasi_newton

if TYPE_CHECKING:
    from ...integrators._implicit import ImplicitOptionsLike
    from ._options import MinimizerLike
    from ._problem import DeviceNewtonStats, NewtonStats, PotentialProblem


def minimize(
    problem: PotentialProblem,
    t: float,
    h: float,
    x_tilde: wp.array,
    x_ref: wp.array,
    v_ref: wp.array,
    x_out: wp.array,
    options: ImplicitOptionsLike = None,
    minimizer: MinimizerLike = None,
) -> NewtonStats | DeviceNewtonStats:
    """x_out = argmin Φ by :func:`minimize_quasi_newton` when the minimiser's ``method`` is "lbfgs" ("auto"
    on the CPU), else by
    :func:`minimize_incremental_potential` (or its device form, :func:`minimize_device`, with
    ``linear_solver="pcg"``, or "auto" on CUDA; arguments as there), with host BLAS on one thread: many small
    calls, for which a thread pool's wake-up costs more than it saves. Problems with barrier contact (an
    energy with ``feasible_start``) always take the host Newton: it starts from the CCD-bounded advance
    from x_ref and bounds every step by the energies' continuous collision detection."""
    _, mz = step_settings(options, minimizer)
    with single_threaded():
        # Barrier contact's start and step bound are the host Newton's (see needs_feasible_start).
        if needs_feasible_start(problem):
            return minimize_incremental_potential(
                problem, t, h, x_tilde, x_ref, v_ref, x_out, options, minimizer=mz
            )
        if resolve_method(mz, problem.model.device, problem) == "lbfgs":
            return minimize_quasi_newton(problem, t, h, x_tilde, x_ref, v_ref, x_out, options, minimizer=mz)
        if device_newton(mz, problem.model.device, problem):
            return minimize_device(problem, t, h, x_tilde, x_ref, v_ref, x_out, options, minimizer=mz)
        return minimize_incremental_potential(
            problem, t, h, x_tilde, x_ref, v_ref, x_out, options, minimizer=mz
        )
