"""Problems the integrators advance: a first-order ODE A dy/dt = f(t, y) in NumPy, and its 2nd-order form."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass
class ODEProblem:
    """A first-order ODE ``A dy/dt = f(t, y)`` in float64 NumPy (the lecture's form).

    Args:
        f: right-hand side f(t, y) -> array like y.
        A: constant mass matrix: None (identity), a vector (diagonal) or a square matrix.
        jac: optional ∂f/∂y(t, y) -> [n, n]; implicit integrators fall back to finite differences.
        energy: optional E(y) [J], used by studies to plot energy behaviour.
    """

    f: Callable[[float, np.ndarray], np.ndarray]
    A: np.ndarray | None = None
    jac: Callable[[float, np.ndarray], np.ndarray] | None = None
    energy: Callable[[np.ndarray], float] | None = None

    def rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        """dy/dt = A⁻¹ f(t, y)."""
        f = np.asarray(self.f(t, y), dtype=np.float64)
        if self.A is None:
            return f
        A = np.asarray(self.A, dtype=np.float64)
        return f / A if A.ndim == 1 else np.linalg.solve(A, f)

    def rhs_jacobian(self, t: float, y: np.ndarray) -> np.ndarray:
        """∂(A⁻¹f)/∂y, analytic when ``jac`` is given, else central differences."""
        if self.jac is not None:
            J = np.asarray(self.jac(t, y), dtype=np.float64)
        else:
            n = y.size
            J = np.empty((n, n))
            for c in range(n):  # tiny toy problems only; physical models use their own Hessians
                h = 1e-7 * max(1.0, abs(y[c]))
                e = np.zeros(n)
                e[c] = h
                J[:, c] = (np.asarray(self.f(t, y + e)) - np.asarray(self.f(t, y - e))) / (2 * h)
        if self.A is None:
            return J
        A = np.asarray(self.A, dtype=np.float64)
        return J / A[:, None] if A.ndim == 1 else np.linalg.solve(A, J)


@dataclass
class SecondOrderODE:
    """``M x'' = F(t, x, v)`` as ``acceleration(t, x, v)``; the natural input of symplectic integrators.

    ``as_first_order()`` gives the lecture's first-order form with y = (v, x), A = diag(M, 1).
    """

    acceleration: Callable[[float, np.ndarray, np.ndarray], np.ndarray]
    energy: Callable[[np.ndarray, np.ndarray], float] | None = None
    acceleration_jacobian: Callable[[float, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None = (
        None
    )

    def as_first_order(self) -> ODEProblem:
        """The equivalent ODEProblem on y = concat(v, x)."""

        def f(t: float, y: np.ndarray) -> np.ndarray:
            n = y.size // 2
            v, x = y[:n], y[n:]
            return np.concatenate([self.acceleration(t, x, v), v])

        jac: Callable[[float, np.ndarray], np.ndarray] | None = None
        if (acceleration_jacobian := self.acceleration_jacobian) is not None:

            def jac(t: float, y: np.ndarray) -> np.ndarray:
                n = y.size // 2
                v, x = y[:n], y[n:]
                dadx, dadv = acceleration_jacobian(t, x, v)
                return np.block([[dadv, dadx], [np.eye(n), np.zeros((n, n))]])

        energy: Callable[[np.ndarray], float] | None = None
        if (energy_xv := self.energy) is not None:

            def energy(y: np.ndarray) -> float:
                n = y.size // 2
                return energy_xv(y[n:], y[:n])

        return ODEProblem(f=f, jac=jac, energy=energy)


def harmonic_oscillator(m: float = 1.0, k: float = 1.0, gamma: float = 0.0) -> SecondOrderODE:
    """The lecture's spring to a wall: m x'' = −k x − γ v (rest length 0); energy ½mv² + ½kx² [J]."""
    return SecondOrderODE(
        acceleration=lambda t, x, v: (-k * x - gamma * v) / m,
        energy=lambda x, v: float(0.5 * m * np.sum(v * v) + 0.5 * k * np.sum(x * x)),
        acceleration_jacobian=lambda t, x, v: (-k / m * np.eye(x.size), -gamma / m * np.eye(x.size)),
    )


def lecture_oscillator(m: float = 1.0, k: float = 1.0) -> ODEProblem:
    """The lecture's matrix form: diag(m, 1) d/dt (v, x) = [[0, −k], [1, 0]] (v, x)."""
    B = np.array([[0.0, -k], [1.0, 0.0]])
    return ODEProblem(
        f=lambda t, y: B @ y,
        A=np.array([m, 1.0]),
        jac=lambda t, y: B,
        energy=lambda y: float(0.5 * m * y[0] ** 2 + 0.5 * k * y[1] ** 2),
    )
