"""Explicit Runge–Kutta methods from Butcher tableaus: forward Euler, the lecture's RK2 family, RK4."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import warp as wp

from .._warp import grad_enabled, launch
from ._base import Integrator, System, damping_rate_array, first_order
from ._ops import lincomb
from ._problems import ODEProblem, SecondOrderODE


class ExplicitRK(Integrator):
    """An explicit Runge–Kutta method given by its Butcher tableau (a, b, c).

    On a physical model y = (x, v) and f(y) = (v, a(x, v)); stage i evaluates the acceleration at
    X_i = x + dt Σ_j a_ij V_j, V_i = v + dt Σ_j a_ij A_j.
    """

    explicit: ClassVar[bool] = True

    def __init__(self, a: list[list[float]], b: list[float], c: list[float] | None = None) -> None:
        self.a = [list(map(float, row)) for row in a]
        self.b = [float(x) for x in b]
        s = len(self.b)
        if len(self.a) != s or any(len(row) != s for row in self.a):
            raise ValueError(f"Butcher tableau: a must be {s}x{s} for {s} weights b")
        if any(self.a[i][j] != 0.0 for i in range(s) for j in range(i, s)):
            raise ValueError("explicit Runge–Kutta needs a strictly lower-triangular tableau a")
        self.c = [sum(row) for row in self.a] if c is None else [float(x) for x in c]

    @property
    def stages(self) -> int:
        """Number of right-hand-side evaluations per step."""
        return len(self.b)

    def step_ode(
        self, problem: ODEProblem | SecondOrderODE, t: float, dt: float, y: np.ndarray
    ) -> np.ndarray:
        """One explicit RK step of dy/dt = A⁻¹f(t, y)."""
        p = first_order(problem)
        k: list[np.ndarray] = []
        for i in range(self.stages):
            yi = y.copy()
            for j in range(i):
                if self.a[i][j] != 0.0:
                    yi += dt * self.a[i][j] * k[j]
            k.append(p.rhs(t + self.c[i] * dt, yi))
        out = y.copy()
        for j in range(self.stages):
            if self.b[j] != 0.0:
                out += dt * self.b[j] * k[j]
        return out

    def step_system(self, system: System, t, dt, x_in, v_in, x_out, v_out) -> None:
        """One explicit RK step of x' = v, v' = a(x, v) on Warp arrays."""
        s = self.stages
        m = system.model
        # Buffers: stage velocities V_1..V_s (V_0 = v_in), accelerations A_0..A_s-1, one stage position.
        bufs = self._buffers(system, 2 * s + 1)
        V = [v_in] + bufs[: s - 1]
        A = bufs[s - 1 : 2 * s - 1]
        X = bufs[2 * s - 1]
        # Recorded steps keep every stage position (the tape re-reads them backwards).
        stage_x = self._buffers(system, s) if grad_enabled(m) else [X] * s
        system.acceleration(t, x_in, v_in, A[0])
        for i in range(1, s):
            row = self.a[i]
            X = stage_x[i]
            lincomb(m, X, x_in, [(dt * row[j], V[j]) for j in range(i)])
            lincomb(m, V[i], v_in, [(dt * row[j], A[j]) for j in range(i)])
            system.acceleration(t + self.c[i] * dt, X, V[i], A[i])
        lincomb(m, x_out, x_in, [(dt * self.b[j], V[j]) for j in range(s)])
        damped = is_damped(system, dt)
        # Recorded steps scale δ out of place (a tape cannot replay v ← δv).
        v_end = self._buffers(system, 1)[0] if damped and grad_enabled(m) else v_out
        lincomb(m, v_end, v_in, [(dt * self.b[j], A[j]) for j in range(s)])
        scale_velocity(system, dt, v_end, v_out)


@wp.kernel
def _scale_by_rate(rate: wp.array(dtype=Any), dt: Any, v_in: wp.array(dtype=Any), v_out: wp.array(dtype=Any)):
    # Recorded steps: δ = exp(−cΔt) read from an array so that the tape carries ∂/∂c.
    i = wp.tid()
    v_out[i] = v_in[i] * wp.exp(-rate[0] * dt)


def is_damped(system: System, dt: float) -> bool:
    """True when the step scales velocities: δ ≠ 1, or a recorded step reads δ from the rate array."""
    return system.velocity_damping(dt) != 1.0 or damping_rate_array(system) is not None


def scale_velocity(system: System, dt: float, v_in: wp.array, v_out: wp.array) -> None:
    """v_out = δ v_in with δ = ``system.velocity_damping(dt)`` (v_out may alias v_in without gradients).

    Computed as v + (δ − 1) v, the form the golden trajectories were recorded with. Recorded steps whose
    system holds a ``damping_rate_array`` compute δ = exp(−cΔt) in the kernel from that array instead.
    """
    rate = damping_rate_array(system)
    if rate is not None:
        m = system.model
        launch(_scale_by_rate, m.particle_count, [rate, m.s(dt), v_in, v_out], device=m.device)
        return
    delta = system.velocity_damping(dt)
    if delta != 1.0:
        lincomb(system.model, v_out, v_in, [(delta - 1.0, v_in)])
    elif v_out.ptr != v_in.ptr:
        wp.copy(v_out, v_in)


class ForwardEuler(ExplicitRK):
    """y_{t+1} = y_t + Δt A⁻¹ f(y_t): first order, unstable on the undamped oscillator for every Δt."""

    order: ClassVar[int] = 1

    def __init__(self) -> None:
        super().__init__([[0.0]], [1.0])


class RK2(ExplicitRK):
    """The lecture's two-stage Runge–Kutta: y_{t+1} = y_t + Δt A⁻¹(α f(y_{t+a}) + β f(ỹ_{t+b})).

    With a = 0 (the first slope is the current one) and ỹ_{t+b} = y_t + bΔt A⁻¹f(y_t), this is the
    tableau [[0, 0], [b, 0]], weights (α, β). Second order when α + β = 1 and βb = ½ (Heun: α = β = ½, b = 1;
    explicit midpoint: α = 0, β = 1, b = ½); otherwise first order.
    """

    def __init__(self, alpha: float = 0.5, beta: float = 0.5, a: float = 0.0, b: float = 1.0) -> None:
        if a != 0.0:
            raise ValueError(
                "RK2 with a != 0 would need the slope at a past or future time that an explicit one-step "
                "method does not have; the lecture uses a = 0 (current slope)"
            )
        if abs(alpha + beta - 1.0) > 1e-12:
            raise ValueError(f"RK2 is inconsistent unless alpha + beta = 1 (got {alpha} + {beta})")
        super().__init__([[0.0, 0.0], [b, 0.0]], [alpha, beta], [0.0, b])
        self.alpha, self.beta, self.a_, self.b_ = alpha, beta, a, b
        self.order = 2 if abs(beta * b - 0.5) < 1e-12 else 1  # type: ignore[misc]


class Heun(RK2):
    """Heun's method: average of the current slope and the forward-Euler estimate of the next (order 2)."""

    order: ClassVar[int] = 2

    def __init__(self) -> None:
        super().__init__(0.5, 0.5, 0.0, 1.0)


class Midpoint(RK2):
    """Explicit midpoint method, RK2(α=0, β=1, b=½) (order 2)."""

    order: ClassVar[int] = 2

    def __init__(self) -> None:
        super().__init__(0.0, 1.0, 0.0, 0.5)


class RK4(ExplicitRK):
    """Classical fourth-order Runge–Kutta, κ1..κ4 weighted (1, 2, 2, 1)/6 (stable to ωΔt ≈ 2.83)."""

    order: ClassVar[int] = 4

    def __init__(self) -> None:
        super().__init__(
            [[0, 0, 0, 0], [0.5, 0, 0, 0], [0, 0.5, 0, 0], [0, 0, 1.0, 0]], [1 / 6, 1 / 3, 1 / 3, 1 / 6]
        )
