"""The implicit solver's own settings: which minimiser solves a step and its linear algebra.

The integrator decides what a step solves and how accurately (:class:`pliant.integrators.ImplicitOptions`:
``newton_tol``, ``max_newton_iterations``, ``project_psd``, ``max_line_search``); the solver decides how
(:class:`MinimizerOptions`: Newton or L-BFGS, the linear solver, L-BFGS's history and initial Hessian).
The minimiser settings used to be integrator keywords (``BackwardEuler(method="lbfgs")``); that spelling is
an error now that says where they went (:meth:`pliant.integrators.ImplicitOptions.moved`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from ...integrators import ImplicitOptions
from ._band_order import band_work
from ._problem import cache_of

if TYPE_CHECKING:
    from ...integrators import ImplicitOptionsLike
    from ._problem import PotentialProblem

#: The linear solvers of Newton's steps.
LINEAR_SOLVERS = ("cg", "scipy-cg", "direct", "auto", "pcg", "band")

#: The largest banded LDLᵀ factorisation (multiply-adds, :func:`._band_order.band_work`) for
#: which ``method="auto"`` takes the device Newton with the band solve on the CPU rather than L-BFGS.
#: Measured (float32 beams 0.6 x 0.1 x 0.1 m of c0 x c1 x c1 cells, 4 substeps of 1/120 s, ms per substep
#: over frames 3-22 (10 from 12x5x5), band / L-BFGS, one core): 12x2x2 (191k multiply-adds) 0.50 / 1.12,
#: 24x2x2 (368k) 0.60 / 1.25, 8x3x3 (630k) 0.54 / 1.13, 12x3x3 (910k) 0.71 / 1.35, 16x3x3 (2.3M)
#: 0.98 / 1.50, 12x4x4 (6.0M) 1.27 / 1.61, 12x5x5 (9.1M) 2.46 / 2.16, 12x6x6 (41M) 5.28 / 3.08: the
#: crossover is near 7M. Set far lower, at 350k, so that the built-in FEM scenes (``fem_embedded`` 413k,
#: ``soft_box_fem`` 1.2M, ``cantilever`` 2.3M) keep L-BFGS and their golden trajectories; raising it to ~7M
#: would move them to the band Newton (1.5x faster on the 16x3x3 beam above) and change their goldens (to
#: the scenes' tolerance, not bit for bit).
SMALL_BAND_WORK = 350_000


@dataclass(frozen=True)
class MinimizerOptions:
    """How an implicit step's incremental potential is minimised (``ForceSolver(minimizer=...)``).

    Attributes:
        method: "newton" (the default: exact PSD-projected Hessians, a linear solve per iteration),
            "lbfgs" (L-BFGS whose initial Hessian is the per-axis, lagged, prefactorised one: no assembly or
            factorisation per iteration; the fast choice for FEM bodies on the CPU, not for spring cloth,
            whose Hessian changes too much between steps for a lagged one) or "auto": "newton" on a GPU
            (where the default linear solver is the device Newton, and L-BFGS's lagged H₀ is a host
            factorisation); on the CPU "newton" with the band solve for a small body (at most
            :data:`SMALL_BAND_WORK` multiply-adds per factorisation: its steps replay as CPU graphs), else
            "lbfgs"; the FEM scenes ask for it (:func:`resolve_method`).
        linear_solver: Newton's linear solver: "cg" (warp.optim.linear.cg, any device), "scipy-cg" (SciPy
            CG, block-Jacobi, host; falls back to the direct solve when a step stalls), "direct" (SciPy
            sparse LU, host), "pcg" (Newton with every decision on the device: block-Jacobi CG, line search
            and stopping tests; no host read inside a step, so a Simulator replays its frames as graphs;
            :mod:`pliant.solvers.minimizers._pcg`), "band" (the same device Newton with a banded LDLᵀ
            direct solve, refactorised only when convergence slows: for small bodies, whose steps it
            replays as graphs on the CPU too; :mod:`pliant.solvers.minimizers._band`) or "auto": the direct
            solve on the CPU ("band" with ``method="auto"`` on a small body), "pcg" on a GPU (32x one CPU
            core at 30³ cells on an H100, where Warp's CG with host decisions was slower than one core;
            :func:`device_newton`).
        cg_tol: relative residual of CG, in (0, 1) (raised to 30 eps of the model's dtype).
        cg_max_iterations: CG iteration cap per linear solve (≥ 1).
        lbfgs_history: curvature pairs L-BFGS keeps (≥ 0; 0 is descent preconditioned by the lagged H₀).
        lbfgs_max_iterations: L-BFGS iteration cap per step (≥ 1).
        lbfgs_refresh: re-assemble L-BFGS's lagged Hessian after a step that needed more iterations (≥ 1).
        lbfgs_warm_start: start each L-BFGS step from x̃ plus the previous step's correction when that lowers
            the potential.
        lbfgs_h0: how L-BFGS applies its initial Hessian H₀⁻¹ per axis: "lu" (SciPy's sparse LU, exact;
            the default) or "amg" (one V-cycle of PyAMG's smoothed aggregation: about as many iterations,
            its cost linear in the particles, where the LU's triangular solves fill in as n^(4/3); 2× faster
            on a 20³-cell box, 2.3× at 30³).

    Example::

        solver = pl.solvers.ForceSolver(model, energies, pl.integrators.BackwardEuler(newton_tol=1e-4),
                                        minimizer=pl.solvers.MinimizerOptions(method="lbfgs"))
    """

    method: str = "newton"
    linear_solver: str = "auto"
    cg_tol: float = 1e-6
    cg_max_iterations: int = 2000
    lbfgs_history: int = 8
    lbfgs_max_iterations: int = 200
    lbfgs_refresh: int = 40
    lbfgs_warm_start: bool = True
    lbfgs_h0: str = "lu"

    def __post_init__(self) -> None:
        def count(name: str, low: int) -> None:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")

        if self.method not in ("newton", "lbfgs", "auto"):
            raise ValueError(f"method must be 'newton', 'lbfgs' or 'auto', got {self.method!r}")
        if self.linear_solver not in LINEAR_SOLVERS:
            raise ValueError(
                "linear_solver must be 'cg', 'scipy-cg', 'direct' or 'auto' (host decisions), or 'pcg' or "
                f"'band' (the device Newton), got {self.linear_solver!r}"
            )
        ok = isinstance(self.cg_tol, (int, float)) and not isinstance(self.cg_tol, bool)
        if not (ok and 0.0 < self.cg_tol < 1.0):  # NaN fails too
            raise ValueError(f"cg_tol must be in (0, 1), got {self.cg_tol!r}")
        for name in ("cg_max_iterations", "lbfgs_max_iterations", "lbfgs_refresh"):
            count(name, 1)
        count("lbfgs_history", 0)  # 0: gradient descent preconditioned by the lagged H₀ (tested, kept)
        if not isinstance(self.lbfgs_warm_start, bool):
            raise ValueError(f"lbfgs_warm_start must be True or False, got {self.lbfgs_warm_start!r}")
        if self.lbfgs_h0 not in ("lu", "amg"):
            raise ValueError(f"lbfgs_h0 must be 'lu' or 'amg', got {self.lbfgs_h0!r}")

    @classmethod
    def create(cls, owner: str = "the implicit solver", **options: Any) -> MinimizerOptions:
        """Options from keyword arguments; an unknown name is a ValueError listing the known ones."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise ValueError(f"unknown minimizer option(s) {unknown} for {owner}; known: {sorted(known)}")
        return cls(**options) if options else _DEFAULT

    @classmethod
    def coerce(cls, minimizer: MinimizerLike, owner: str = "the implicit solver") -> MinimizerOptions:
        """``minimizer`` as MinimizerOptions: None (the defaults), a MinimizerOptions or a dict of some
        settings."""
        if minimizer is None:
            return _DEFAULT
        if isinstance(minimizer, cls):
            return minimizer
        if isinstance(minimizer, dict):
            return cls.create(owner, **minimizer)
        raise TypeError(f"minimizer must be MinimizerOptions, a dict or None, got {type(minimizer).__name__}")


_DEFAULT = MinimizerOptions()

#: What :meth:`MinimizerOptions.coerce` accepts: None (the defaults), the options, or a dict of some settings.
MinimizerLike = MinimizerOptions | dict[str, Any] | None


def step_settings(
    options: ImplicitOptionsLike, minimizer: MinimizerLike = None
) -> tuple[ImplicitOptions, MinimizerOptions]:
    """An implicit step's settings: the integrator's and the minimiser's.

    Args:
        options: None, an :class:`~pliant.integrators.ImplicitOptions`, an implicit integrator, or a dict of
            its settings (the minimisers' direct callers).
        minimizer: None, a :class:`MinimizerOptions` or a dict of its settings.

    Raises:
        ValueError: invalid values, or minimiser settings in ``options`` (they go in ``minimizer``).
    """
    return ImplicitOptions.coerce(options), MinimizerOptions.coerce(minimizer)


def device_newton(
    minimizer: MinimizerOptions, device: wp.DeviceLike, problem: PotentialProblem | None = None
) -> bool:
    """Whether ``minimizer``'s Newton runs with every decision on the device: ``linear_solver="pcg"`` or
    "band", "auto" on a CUDA device (where a host decision per iteration costs a synchronisation), or
    ``method="auto"`` on the CPU for a small ``problem`` (:func:`resolve_method`)."""
    if resolve_method(minimizer, device, problem) != "newton":
        return False
    lin = minimizer.linear_solver
    if lin in ("pcg", "band"):
        return True
    return lin == "auto" and (wp.get_device(device).is_cuda or minimizer.method == "auto")


def band_solve(minimizer: MinimizerOptions, device: wp.DeviceLike) -> bool:
    """Whether the device Newton solves its linear systems by the banded LDLᵀ (``linear_solver="band"``,
    or "auto" on the CPU, where only ``method="auto"`` on a small problem takes the device Newton) rather
    than by block-Jacobi CG."""
    lin = minimizer.linear_solver
    return lin == "band" or (lin == "auto" and not wp.get_device(device).is_cuda)


def resolve_method(
    minimizer: MinimizerOptions, device: wp.DeviceLike, problem: PotentialProblem | None = None
) -> str:
    """``minimizer.method`` on ``device``: "newton" or "lbfgs".

    "auto": Newton on CUDA; on the CPU Newton for a small ``problem`` (a PotentialProblem: ``model``,
    ``energies``; :func:`small_problem`), whose steps the device Newton with the band solve takes as
    replayed CPU graphs, else L-BFGS (also when no problem is given).
    """
    if minimizer.method != "auto":
        return minimizer.method
    if wp.get_device(device).is_cuda:
        return "newton"
    return "newton" if problem is not None and small_problem(problem) else "lbfgs"


def small_problem(problem: PotentialProblem) -> bool:
    """Whether ``problem``'s Newton system is small enough for the banded LDLᵀ on the CPU: its factorisation
    at most :data:`SMALL_BAND_WORK` multiply-adds (the bandwidth from the Hessian pattern, computed once per
    workspace)."""
    ws = cache_of(problem).workspace(problem.model, problem.energies)
    _, width = ws.band_order()
    return band_work(problem.model.particle_count, width) <= SMALL_BAND_WORK
