"""The minimisers of an implicit step, as a registry (:data:`MINIMIZERS`), and :func:`minimize`, which gives
a step to the one its settings choose.

Each minimiser is one file (``_newton``: Newton with host decisions; ``_pcg``: Newton with every decision on
the device, CG or banded LDLᵀ; ``_quasi_newton``: L-BFGS) with the signature of :data:`MinimizeFn`, and one
line here. tests/test_minimizers.py walks the registry: every entry reaches the same minimum on the same
problems, exactly one entry is chosen for any settings, and an entry that says it keeps its decisions on
the device reads nothing back in a step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import warp as wp

from ..._blas import single_threaded
from ._newton import minimize_incremental_potential
from ._options import MinimizerOptions, device_newton, resolve_method, step_settings
from ._pcg import minimize_device
from ._problem import needs_feasible_start
from ._quasi_newton import minimize_quasi_newton

if TYPE_CHECKING:
    from ...integrators import ImplicitOptionsLike
    from ._options import MinimizerLike
    from ._problem import DeviceNewtonStats, NewtonStats, PotentialProblem

#: ``minimize(problem, t, h, x_tilde, x_ref, v_ref, x_out, options, minimizer=...) -> stats``: x_out = argmin
#: Φ of one step (arguments as :func:`~pliant.solvers.minimizers.minimize_incremental_potential`).
MinimizeFn = Callable[..., Any]


@dataclass(frozen=True)
class Minimizer:
    """One minimiser of an implicit step's incremental potential, as :data:`MINIMIZERS` lists it.

    Attributes:
        minimize: the minimiser (:data:`MinimizeFn`).
        chosen: ``chosen(problem, minimizer) -> bool``: whether :func:`minimize` gives it a step of
            ``problem`` (a PotentialProblem) under ``minimizer`` (:class:`MinimizerOptions`); for a problem
            without barrier contact exactly one entry's holds.
        barrier: whether it takes barrier contact (energies with ``feasible_start``: a CCD-bounded start
            and step); such problems go to the first entry that does, whatever the settings.
        device_decisions: every decision on the device: no host read inside a step, so a Simulator
            replays its steps as graphs.
    """

    minimize: MinimizeFn
    chosen: Callable[[Any, MinimizerOptions], bool]
    barrier: bool = False
    device_decisions: bool = False


def _method(problem: PotentialProblem, mz: MinimizerOptions) -> str:
    return resolve_method(mz, problem.model.device, problem)


def _on_device(problem: PotentialProblem, mz: MinimizerOptions) -> bool:
    return device_newton(mz, problem.model.device, problem)


#: The minimisers, in the order :func:`minimize` asks them (name → :class:`Minimizer`).
MINIMIZERS: dict[str, Minimizer] = {
    "lbfgs": Minimizer(minimize_quasi_newton, lambda p, mz: _method(p, mz) == "lbfgs"),
    "device_newton": Minimizer(minimize_device, _on_device, device_decisions=True),
    "newton": Minimizer(
        minimize_incremental_potential,
        lambda p, mz: _method(p, mz) == "newton" and not _on_device(p, mz),
        barrier=True,
    ),
}


def choose(problem: PotentialProblem, minimizer: MinimizerOptions) -> str:
    """The name in :data:`MINIMIZERS` of the minimiser that takes a step of ``problem`` (a PotentialProblem)
    under ``minimizer``: with barrier contact the first that takes it, else the first whose ``chosen``
    holds."""
    if needs_feasible_start(problem):
        return next(name for name, m in MINIMIZERS.items() if m.barrier)
    return next(name for name, m in MINIMIZERS.items() if m.chosen(problem, minimizer))


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
    """x_out = argmin Φ by the minimiser :func:`choose` picks (arguments as
    :func:`~pliant.solvers.minimizers.minimize_incremental_potential`): L-BFGS for ``method="lbfgs"``
    ("auto" on the CPU for all but small bodies), the device Newton for ``linear_solver="pcg"`` or "band"
    (and "auto" on CUDA), else the host Newton. Host BLAS runs on one thread: many small calls, for which a
    thread pool's wake-up costs more than it saves. Problems with barrier contact always take the host
    Newton: it starts from the CCD-bounded advance from x_ref and bounds every step by the energies'
    continuous collision detection."""
    _, mz = step_settings(options, minimizer)
    with single_threaded():
        entry = MINIMIZERS[choose(problem, mz)]
        return entry.minimize(problem, t, h, x_tilde, x_ref, v_ref, x_out, options, minimizer=mz)
