"""Implicit steps and static equilibria: minimisers of the incremental potential (Newton, L-BFGS), their
settings, workspace and assembly, the adjoint of a converged step, and the static solve.

Modules, bottom to top: ``_options`` (the minimiser's settings) and ``_workspace`` (the BSR pattern, linear
solvers, the per-problem cache) → ``_assembly`` (Hessian assembly, the Control's terms) → ``_adjoint``
(gradients through a step) → ``_newton`` → ``_pcg_kernels``, ``_slots`` and ``_band`` (its banded LDLᵀ
solve for small bodies) / ``_pcg`` (Newton on the device) →
``_quasi_newton`` → ``_minimize`` / ``_static``. Other solver families use the names below, never these
modules.
"""

from ._adjoint import differentiable
from ._assembly import PotentialProblem, control_of
from ._band import band_checkpoint_state, band_restore_checkpoint_state
from ._minimize import minimize
from ._newton import NewtonStats, minimize_incremental_potential
from ._options import MinimizerOptions, device_newton, resolve_method, step_settings
from ._pcg import DeviceCG, DeviceNewtonStats, minimize_device
from ._pcg import graph_blocker as device_newton_blocker
from ._quasi_newton import (
    lbfgs_checkpoint_state,
    lbfgs_restore_checkpoint_state,
    minimize_quasi_newton,
    nested_dissection,
)
from ._static import StaticStats, solve_static
from ._workspace import MinimizerCache, cache_of

__all__ = [
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
