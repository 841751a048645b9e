"""The minimisers of an implicit step's incremental potential (host Newton, device Newton, L-BFGS), their
settings, problem and workspace types, Hessian assembly, the adjoint of a converged step, and the static
solve. A library the solvers call (``ForceSolver``), not a solver itself.

Modules, bottom to top: ``_problem`` (the problem, workspace, cache and statistics types; below it only the
leaves ``_slots``, ``_pcg_kernels``, ``_band_order``) → ``_options`` (the minimiser's settings) and
``_kernels`` → ``_assembly`` (Hessian assembly, the gradient, the Control's terms) → ``_adjoint`` (gradients
through a step) → one file per minimiser: ``_newton`` (host Newton), ``_pcg`` (device Newton, with
``_band``'s banded LDLᵀ), ``_quasi_newton`` (L-BFGS, its LU order from the leaf ``_dissection``) →
``_minimize`` (their dispatch) / ``_static``.
No minimiser imports another. Other solver families use the names below, never these modules.
"""

from ._adjoint import differentiable
from ._assembly import control_of
from ._band import band_checkpoint_state, band_restore_checkpoint_state
from ._dissection import nested_dissection
from ._minimize import MINIMIZERS, Minimizer, choose, minimize
from ._newton import minimize_incremental_potential
from ._options import MinimizerOptions, device_newton, resolve_method, step_settings
from ._pcg import DeviceCG, minimize_device
from ._pcg import graph_blocker as device_newton_blocker
from ._problem import DeviceNewtonStats, MinimizerCache, NewtonStats, PotentialProblem, cache_of
from ._quasi_newton import lbfgs_checkpoint_state, lbfgs_restore_checkpoint_state, minimize_quasi_newton
from ._static import StaticStats, solve_static

__all__ = [
    "MINIMIZERS",
    "Minimizer",
    "choose",
    "DeviceCG",
    "DeviceNewtonStats",
    "MinimizerCache",
    "MinimizerOptions",
    "NewtonStats",
    "PotentialProblem",
    "band_checkpoint_state",
    "band_restore_checkpoint_state",
    "StaticStats",
    "cache_of",
    "control_of",
    "device_newton",
    "device_newton_blocker",
    "differentiable",
    "lbfgs_checkpoint_state",
    "lbfgs_restore_checkpoint_state",
    "minimize",
    "minimize_device",
    "minimize_incremental_potential",
    "minimize_quasi_newton",
    "nested_dissection",
    "resolve_method",
    "solve_static",
    "step_settings",
]
