"""Dormand–Prince 5(4): the embedded Runge–Kutta pair with adaptive step-size control (ODE path)."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from ._base import Solution, System, first_order, initial_state
from ._explicit import ExplicitRK
from ._problems import ODEProblem, SecondOrderODE

_C = [0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0]
_A: list[list[float]] = [
    [0, 0, 0, 0, 0, 0, 0],
    [1 / 5, 0, 0, 0, 0, 0, 0],
    [3 / 40, 9 / 40, 0, 0, 0, 0, 0],
    [44 / 45, -56 / 15, 32 / 9, 0, 0, 0, 0],
    [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729, 0, 0, 0],
    [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656, 0, 0],
    [35 / 384, 0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0],
]
_B5 = [35 / 384, 0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0]
_B4 = [5179 / 57600, 0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100, 1 / 40]
_E = [b5 - b4 for b5, b4 in zip(_B5, _B4, strict=True)]


class DormandPrince(ExplicitRK):
    """Dormand–Prince 5(4) (MATLAB's ode45, SciPy's RK45, diffrax's Dopri5).

    ``step_ode`` is the fixed-step fifth-order solution (order 5); :meth:`solve_adaptive` controls the step
    with the embedded fourth-order error estimate (Hairer, Nørsett, Wanner, "Solving Ordinary Differential
    Equations I", §II.4; J. R. Dormand, P. J. Prince, J. Comput. Appl. Math. 6(1), 1980). FSAL: the last
    stage of an accepted step is the first stage of the next.

    ODE path only: adaptive steps change Δt from step to step, which the Simulator's fixed substeps do not
    allow; for physical models use :class:`RK4` (``step_system`` raises NotImplementedError).

    Example::

        sol = pl.integrators.DormandPrince().solve_adaptive(pl.integrators.harmonic_oscillator(), (1.0, 0.0),
                                                            t_end=10.0, rtol=1e-8, atol=1e-10)
        print(sol.t.size, sol.stats)
    """

    order: ClassVar[int] = 5
    #: False: only the ODE path (``step_ode``, ``solve``, ``solve_adaptive``) is available.
    supports_system: ClassVar[bool] = False

    def __init__(self) -> None:
        # The seventh stage has weight 0 in the fifth-order solution: a fixed step needs six.
        super().__init__([row[:6] for row in _A[:6]], _B5[:6], _C[:6])

    def step_system(self, system: System, t, dt, x_in, v_in, x_out, v_out) -> None:
        """Not available: use RK4 for physical models."""
        raise NotImplementedError(
            "DormandPrince is an adaptive ODE-path integrator (solve_adaptive); a physical model steps with "
            "a fixed dt: use pl.integrators.RK4 (fixed-step, order 4) or an implicit integrator instead"
        )

    def solve_adaptive(
        self,
        problem: ODEProblem | SecondOrderODE,
        y0: ArrayLike | tuple[ArrayLike, ArrayLike],
        t_end: float,
        rtol: float = 1e-6,
        atol: float = 1e-9,
        *,
        t0: float = 0.0,
        dt0: float | None = None,
        max_steps: int = 1_000_000,
    ) -> Solution:
        """Integrate from ``t0`` to ``t_end`` [s] with error control ‖err/(atol + rtol|y|)‖_RMS ≤ 1.

        Returns a :class:`Solution` at the accepted steps, with ``stats`` (accepted, rejected, rhs
        evaluations) attached.
        """
        if not (rtol > 0 and atol >= 0):
            raise ValueError(f"rtol must be > 0 and atol >= 0, got rtol={rtol}, atol={atol}")
        if t_end <= t0:
            raise ValueError(f"t_end ({t_end}) must be after t0 ({t0})")
        second = isinstance(problem, SecondOrderODE)
        y = initial_state(problem, y0)
        p = first_order(problem)
        t = float(t0)
        k0 = p.rhs(t, y)
        nfev = 1

        def norm(e: np.ndarray | float, ya: np.ndarray, yb: np.ndarray) -> float:
            sc = atol + rtol * np.maximum(np.abs(ya), np.abs(yb))
            return float(np.sqrt(np.mean((e / sc) ** 2)))

        if dt0 is None:  # Hairer's starting step (II.4, "automatic step size selection")
            d0 = norm(y, y, y) if np.any(y) else 0.0
            d1 = norm(k0, y, y)
            h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
            y1 = y + h0 * k0
            d2 = norm(p.rhs(t + h0, y1) - k0, y, y) / h0
            nfev += 1
            h1 = max(1e-6, h0 * 1e-3) if max(d1, d2) <= 1e-15 else (0.01 / max(d1, d2)) ** (1 / 5)
            dt = min(100 * h0, h1)
        else:
            dt = float(dt0)
        ts, ys = [t], [y.copy()]
        accepted = rejected = 0
        while t < t_end:
            if accepted + rejected >= max_steps:
                raise RuntimeError(f"solve_adaptive: more than {max_steps} steps; loosen rtol/atol")
            dt = min(dt, t_end - t)
            k = [k0]
            for i in range(1, 7):
                yi = y + dt * sum(_A[i][j] * k[j] for j in range(i) if _A[i][j] != 0.0)
                k.append(p.rhs(t + _C[i] * dt, yi))
            nfev += 6
            y_new = yi  # stage 7 is evaluated at the fifth-order solution (FSAL)
            err = norm(dt * sum(_E[j] * k[j] for j in range(7) if _E[j] != 0.0), y, y_new)
            if err <= 1.0:
                t = t + dt if t_end - t - dt > 1e-12 * abs(t_end) else t_end
                y, k0 = y_new, k[6]
                ts.append(t)
                ys.append(y.copy())
                accepted += 1
                factor = 10.0 if err == 0.0 else min(10.0, max(0.2, 0.9 * err ** (-1 / 5)))
            else:
                rejected += 1
                factor = max(0.2, 0.9 * err ** (-1 / 5))
            dt *= factor
        sol = Solution(np.asarray(ts), np.stack(ys), second)
        sol.stats = {"accepted": accepted, "rejected": rejected, "rhs_evaluations": nfev}  # type: ignore[attr-defined]
        return sol
