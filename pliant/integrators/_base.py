"""Integrator base class: one object advances a NumPy ODE and a physical model on Warp arrays."""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Protocol

import numpy as np
import warp as wp
from numpy.typing import ArrayLike

from .._warp import fresh, grad_enabled
from ._problems import ODEProblem, SecondOrderODE

if TYPE_CHECKING:
    from ..model import Model
    from ._implicit import ImplicitOptions


class System(Protocol):
    """What a physical solver exposes to an integrator: M x'' = F(t, x, v) on Warp arrays.

    ``model`` is used for allocation only (particle_count, vec3, device, s()); integrators never look at
    meshes. Implicit integrators additionally call ``minimize`` (Newton on the incremental potential).
    """

    model: Model

    def acceleration(self, t: float, x: wp.array, v: wp.array, out: wp.array) -> None:
        """Write a = M⁻¹F(t, x, v) [m/s²] into ``out`` (zero for pinned particles)."""

    def velocity_damping(self, dt: float) -> float:
        """Factor δ ∈ (0, 1] that scales velocities each step (the lecture's δ); 1 = none."""

    def minimize(
        self,
        t: float,
        h: float,
        x_tilde: wp.array,
        x_ref: wp.array,
        v_ref: wp.array,
        x_out: wp.array,
        options: ImplicitOptions | None = None,
    ) -> object:
        """x_out = argmin ½‖x − x̃‖²_M + h² E(x) (+ dissipation about x_ref); returns solver statistics."""


@dataclass
class Solution:
    """Result of :meth:`Integrator.solve`: times [s] and states, one row per time."""

    t: np.ndarray
    y: np.ndarray
    second_order: bool = False

    @property
    def x(self) -> np.ndarray:
        """Positions (second-order problems: the second half of y)."""
        return self.y[:, self.y.shape[1] // 2 :] if self.second_order else self.y

    @property
    def v(self) -> np.ndarray:
        """Velocities (second-order problems: the first half of y)."""
        if not self.second_order:
            raise AttributeError("a first-order ODE has no separate velocity")
        return self.y[:, : self.y.shape[1] // 2]


class Integrator(abc.ABC):
    """A time integrator with a declared order, usable on ODEs and on physical models.

    Subclasses implement :meth:`step_ode` (NumPy, float64) and :meth:`step_system` (Warp arrays); the order
    is asserted by the test suite from a dt sweep.
    """

    order: ClassVar[int]
    explicit: ClassVar[bool] = True
    symplectic: ClassVar[bool] = False
    #: True when ``step_system`` needs the previous step (multistep methods such as BDF2).
    multistep: ClassVar[bool] = False
    #: How a step's forces enter x₁ and v₁, for the contact response after it (ground-penalty friction,
    #: :func:`pliant.collision.respond_to_ground`): the forces act at x₀ + θ(x₁ − x₀) (θ =
    #: ``contact_point``) over ``contact_impulse``·Δt, and x₁ moves by ``contact_shift``·Δt per unit change
    #: of v₁ (∂x₁/∂v₁ / Δt), which is how far friction's velocity change moves a particle. Backward Euler's
    #: (1, 1, 1) stands for the explicit methods too (x₁ ≈ x₀ + Δt v₁).
    contact_point: ClassVar[float] = 1.0
    contact_impulse: ClassVar[float] = 1.0
    contact_shift: ClassVar[float] = 1.0

    @property
    def name(self) -> str:
        """Class name, used in tables and figures."""
        return type(self).__name__

    # -------------------------------------------------------------- ODE path
    @abc.abstractmethod
    def step_ode(
        self, problem: ODEProblem | SecondOrderODE, t: float, dt: float, y: np.ndarray
    ) -> np.ndarray:
        """Advance y (for SecondOrderODE: concat(v, x)) from t to t + dt [s]."""

    def solve(
        self,
        problem: ODEProblem | SecondOrderODE,
        y0: ArrayLike | tuple[ArrayLike, ArrayLike],
        t_end: float,
        dt: float,
        t0: float = 0.0,
    ) -> Solution:
        """Integrate with a fixed step ``dt`` [s] from ``t0`` to ``t_end``.

        ``y0`` is an array for an ODEProblem and ``(x0, v0)`` for a SecondOrderODE.
        """
        second = isinstance(problem, SecondOrderODE)
        y = initial_state(problem, y0)
        n = int(round((t_end - t0) / dt))
        if n < 1 or not np.isclose(t0 + n * dt, t_end, rtol=1e-9, atol=1e-12):
            raise ValueError(f"t_end − t0 = {t_end - t0} is not a whole number of steps of dt = {dt}")
        ts = t0 + dt * np.arange(n + 1)
        ys = np.empty((n + 1, y.size))
        ys[0] = y
        self.reset()
        for k in range(n):
            y = self.step_ode(problem, ts[k], dt, y)
            ys[k + 1] = y
        return Solution(ts, ys, second)

    def reset(self) -> None:  # noqa: B027
        """Forget history (multistep methods); called at the start of :meth:`solve`."""

    # -------------------------------------------------------------- physical path
    @abc.abstractmethod
    def step_system(
        self,
        system: System,
        t: float,
        dt: float,
        x_in: wp.array,
        v_in: wp.array,
        x_out: wp.array,
        v_out: wp.array,
    ) -> None:
        """Advance positions [m] and velocities [m/s] by ``dt`` [s]; never writes ``x_in``/``v_in``."""

    def _buffers(self, system: System, count: int) -> list[wp.array]:
        """``count`` particle-sized vec3 work arrays, allocated once per model (no allocation per step).

        When the model requires gradients every call returns fresh arrays (with ``requires_grad``): a
        ``wp.Tape`` replays each stage backwards and needs every intermediate that stage wrote intact.
        """
        model = system.model
        if grad_enabled(model):
            return [fresh(model) for _ in range(count)]
        key = (id(model), count)
        cache = getattr(self, "_ws", None)
        if cache is None or cache[0] != key:
            bufs = [
                wp.zeros(model.particle_count, dtype=model.vec3, device=model.device) for _ in range(count)
            ]
            self._ws = (key, bufs)
        return self._ws[1]


def damping_rate_array(system: System) -> wp.array | None:
    """The 1-element array holding the damping rate c [1/s] that recorded steps read (δ = exp(−cΔt)), so
    that ``tape.backward`` gives ∂loss/∂c in its ``.grad``; None when gradients are off or the system has
    no ``damping_rate_array`` (then δ = ``system.velocity_damping(dt)``, a constant)."""
    if not grad_enabled(system.model):
        return None
    return getattr(system, "damping_rate_array", None)


def initial_state(
    problem: ODEProblem | SecondOrderODE, y0: ArrayLike | tuple[ArrayLike, ArrayLike]
) -> np.ndarray:
    """``y0`` as a float64 vector: concat(v0, x0) for a SecondOrderODE (``y0`` = (x0, v0)), else a copy."""
    if isinstance(problem, SecondOrderODE):
        x0, v0 = (np.atleast_1d(np.asarray(a, dtype=np.float64)) for a in y0)  # type: ignore[union-attr]
        return np.concatenate([v0, x0])
    return np.atleast_1d(np.asarray(y0, dtype=np.float64)).copy()


def second_order_split(problem: ODEProblem | SecondOrderODE, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x, v) halves of y = concat(v, x)."""
    n = y.size // 2
    return y[n:], y[:n]


def first_order(problem: ODEProblem | SecondOrderODE) -> ODEProblem:
    """The problem as a first-order ODE (SecondOrderODE converted with y = (v, x))."""
    return problem.as_first_order() if isinstance(problem, SecondOrderODE) else problem
