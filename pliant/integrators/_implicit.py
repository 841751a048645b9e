"""Implicit integrators: backward Euler, implicit midpoint and BDF2, by Newton on both paths.

ODE path (NumPy, float64): Newton on the stage equation with the problem's ``rhs_jacobian``.
Physical path (Warp arrays): every step is one minimisation of the incremental potential
Φ(x) = ½‖x − x̃‖²_M + ĥ² E(x) (``system.minimize``), with the integrator's x̃ and ĥ:

=================  =======================================  ==========================================
method             x̃, ĥ                                     velocity
=================  =======================================  ==========================================
BackwardEuler      x + h v, h                               v₁ = (x₁ − x)/h
ImplicitMidpoint   x + (h/2) v, h/2  (then extrapolate)     v₁ = 2 v_½ − v, x₁ = 2 x_½ − x
BDF2               x̂ + ĥ(4v − v₋₁)/3, ĥ = 2h/3              v₁ = (x₁ − x̂)/ĥ, x̂ = (4x − x₋₁)/3
=================  =======================================  ==========================================
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable, Iterable
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any, ClassVar, Union

import numpy as np
import warp as wp

from .._warp import _tape_active, fresh, grad_enabled, launch
from ._base import Integrator, System, first_order
from ._explicit import scale_velocity
from ._ops import lincomb
from ._problems import ODEProblem, SecondOrderODE

if TYPE_CHECKING:
    from ..model import Model


def newton_ode(
    residual_fn: Callable[[np.ndarray], np.ndarray],
    jacobian_fn: Callable[[np.ndarray], np.ndarray],
    y0: np.ndarray,
    *,
    tol: float = 1e-14,
    max_iterations: int = 50,
) -> np.ndarray:
    """Solve G(y) = 0 from ``y0`` by Newton's method (dense; for the small ODE problems of the studies).

    Stops when ‖Δy‖∞ ≤ tol·(1 + ‖y‖∞) or the correction stops shrinking (round-off).
    """
    y = y0.copy()
    last = np.inf
    for _ in range(max_iterations):
        dy = np.linalg.solve(jacobian_fn(y), -residual_fn(y))
        y = y + dy
        size = float(np.max(np.abs(dy))) if dy.size else 0.0
        if size <= tol * (1.0 + float(np.max(np.abs(y)))) or (size >= last and size < 1e-10):
            return y
        last = size
    raise RuntimeError(
        f"Newton did not converge in {max_iterations} iterations (last correction {last:.3g}); "
        "lower dt or check the problem's Jacobian"
    )


def _theta_stage(problem: ODEProblem, t: float, c: float, y_base: np.ndarray) -> np.ndarray:
    """Solve y = y_base + c f(t, y) (one backward-Euler-like stage) by Newton, from y_base."""
    n = y_base.size
    eye = np.eye(n)
    return newton_ode(
        lambda y: y - y_base - c * problem.rhs(t, y),
        lambda y: eye - c * problem.rhs_jacobian(t, y),
        y_base,
    )


#: The implicit solver's own settings (``pl.solvers.MinimizerOptions``, ``ForceSolver(minimizer=...)``), which
#: the implicit integrators took as keywords until issue 40 removed them (they choose how a step is
#: minimised, not what the step is): named here only so that giving one says where it went.
MINIMIZER_SETTINGS = (
    "linear_solver",
    "cg_tol",
    "cg_max_iterations",
    "method",
    "lbfgs_history",
    "lbfgs_max_iterations",
    "lbfgs_refresh",
    "lbfgs_warm_start",
    "lbfgs_h0",
)


@dataclass(frozen=True)
class ImplicitOptions:
    """What an implicit step solves to and how accurately, defined and validated once (integrators and
    minimisers). How it is minimised is the solver's (``pl.solvers.MinimizerOptions``): its settings
    (``method``, ``linear_solver``, ``cg_*``, ``lbfgs_*``) given here are an error saying so
    (:meth:`moved`).

    Attributes:
        newton_tol: tolerance [m/s] on ‖Δx‖∞/h and on max_i |∇Φ_i|/(m_i h) (> 0): a velocity error per
            step. Keep it well below g·h: a looser one accepts the inertial prediction x̃ of a free-fall
            step as converged, and a body at rest under gravity never starts to fall.
        max_newton_iterations: Newton iteration cap per step (≥ 1).
        project_psd: True, False or "auto" (see :class:`BackwardEuler`).
        max_line_search: step halvings allowed per iteration (≥ 0).
    """

    newton_tol: float = 1e-5
    max_newton_iterations: int = 20
    project_psd: bool | str = True
    max_line_search: int = 20

    def __post_init__(self) -> None:
        def positive(name: str, unit: str = "") -> None:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0):
                raise ValueError(f"{name} must be a number > 0{unit}, got {value!r}")

        def count(name: str, low: int) -> None:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")

        positive("newton_tol", " m/s (e.g. 1e-5)")  # NaN fails "> 0" too
        count("max_newton_iterations", 1)
        count("max_line_search", 0)
        if not (self.project_psd is True or self.project_psd is False or self.project_psd == "auto"):
            raise ValueError(f"project_psd must be True, False or 'auto', got {self.project_psd!r}")

    @staticmethod
    def moved(names: Iterable[str]) -> str | None:
        """Where the minimiser settings among ``names`` went (the error for giving them to an integrator),
        or None when there are none."""
        gone = [k for k in names if k in MINIMIZER_SETTINGS]
        if not gone:
            return None
        spelled = ", ".join(f"{k}=..." for k in gone)
        return (
            f"{', '.join(gone)}: the implicit solver's settings, not the integrator's; pass "
            f"ForceSolver(..., minimizer=pl.solvers.MinimizerOptions({spelled})) (in a scene file, "
            "[solver] options = { minimizer = { ... } }, not integrator_options)"
        )

    @classmethod
    def create(cls, owner: str = "the implicit step", **options: Any) -> ImplicitOptions:
        """Options from keyword arguments; an unknown name is a ValueError listing the known ones."""
        moved = cls.moved(options)
        if moved:
            raise ValueError(f"{owner}: {moved}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise ValueError(f"unknown option(s) {unknown} for {owner}; known options: {sorted(known)}")
        return cls(**options)

    @classmethod
    def coerce(cls, options: ImplicitOptionsLike) -> ImplicitOptions:
        """``options`` as ImplicitOptions: None (the defaults), an ImplicitOptions, a dict of some settings,
        or an object with ``options`` (an implicit integrator)."""
        if options is None:
            return _DEFAULT_OPTIONS
        if isinstance(options, cls):
            return options
        if isinstance(options, dict):
            return cls.create("minimize", **options)
        inner = getattr(options, "options", None)
        if isinstance(inner, cls):
            return inner
        raise TypeError(f"options must be ImplicitOptions, a dict or None, got {type(options).__name__}")


_DEFAULT_OPTIONS = ImplicitOptions()

#: What :meth:`ImplicitOptions.coerce` accepts: None (the defaults), the options, a dict of some settings,
#: or an implicit integrator (which holds its options).
ImplicitOptionsLike = Union[ImplicitOptions, "_ImplicitOptions", dict[str, Any], None]
_OPTION_NAMES = frozenset(f.name for f in fields(ImplicitOptions))


class _ImplicitOptions:
    """The implicit integrators' settings: an :class:`ImplicitOptions` handed to ``system.minimize``."""

    #: Gradients through the physical path: the adjoint of each step's minimisation
    #: (``pliant.solvers.minimizers._adjoint``), recorded on an active ``wp.Tape``.
    differentiable: ClassVar[bool] = True
    #: The keyword options ``__init__(**options)`` accepts: the fields of this dataclass (scene files check
    #: ``integrator_options`` against them).
    options_type: ClassVar[type] = ImplicitOptions

    def __init__(self, **options: Any) -> None:
        self.options = ImplicitOptions.create(type(self).__name__, **options)

    def __getattr__(self, name: str) -> Any:
        # Read access to each setting as an attribute (integ.newton_tol), from the one options object.
        if name in _OPTION_NAMES and "options" in self.__dict__:
            return getattr(self.__dict__["options"], name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def _minimize(self, system: System, t, h, x_tilde, x_ref, v_ref, x_out) -> object:
        if _accepts_options(system.minimize):
            return system.minimize(t, h, x_tilde, x_ref, v_ref, x_out, options=self.options)
        return system.minimize(t, h, x_tilde, x_ref, v_ref, x_out)


def _accepts_options(fn: Callable[..., object]) -> bool:
    """Whether a System's ``minimize`` takes ``options`` (the protocol's original form does not)."""
    return _takes_options(getattr(fn, "__func__", fn))


@functools.lru_cache(maxsize=64)
def _takes_options(fn: Callable[..., object]) -> bool:
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False
    return "options" in params or any(p.kind is p.VAR_KEYWORD for p in params.values())


def recording_gradients(model: object) -> bool:
    """Whether a ``wp.Tape`` records while the model was finalised with ``requires_grad=True``: the implicit
    steps then use fresh arrays per step (the tape keeps every step's values) and no in-place updates."""
    return bool(getattr(model, "requires_grad", False)) and _tape_active()


def _fresh(system: System, count: int) -> list[wp.array]:
    """``count`` new particle-sized vec3 arrays with gradients (one step's work arrays when recording)."""
    return [fresh(system.model) for _ in range(count)]


class BackwardEuler(_ImplicitOptions, Integrator):
    """Backward (implicit) Euler: A(y₁ − y₀)/Δt = f(y₁) (first order, L-stable).

    Physical path: x₁ = argmin ½‖x − (x₀ + Δt v₀)‖²_M + Δt² E(x), v₁ = δ(x₁ − x₀)/Δt, by Newton with line
    search (``pliant.solvers.ForceSolver.minimize``). On the undamped oscillator it divides the energy by
    1 + ω²Δt² each step: unconditionally stable, visibly damped.

    Keyword Args:
        newton_tol: Newton tolerance [m/s] on ‖Δx‖∞/Δt and on the mass-scaled gradient.
        max_newton_iterations: Newton iteration cap per step.
        project_psd: PSD-project element Hessians: True (the default: robust; Newton converges only linearly
            where springs are compressed), False (exact; the direct solver copes with indefinite H, CG may
            not) or "auto" (exact until a Newton direction fails to descend, then projected for the step;
            about half the iterations on a falling cloth, but it can stall unconverged on FEM contact).
        max_line_search: step halvings allowed per iteration.

    The minimiser's settings (``method``, ``linear_solver``, ``lbfgs_*``, ...) are the solver's:
    ``ForceSolver(..., minimizer=pl.solvers.MinimizerOptions(...))``; given here they are an error.

    Example::

        solver = pl.solvers.ForceSolver(model, energies=pl.energies.mass_spring(),
                                        integrator=pl.integrators.BackwardEuler(newton_tol=1e-5))
        solver.step(state_0, state_1, control, 1 / 60)
        print(solver.last_stats.iterations)
    """

    order: ClassVar[int] = 1
    explicit: ClassVar[bool] = False

    def step_ode(
        self, problem: ODEProblem | SecondOrderODE, t: float, dt: float, y: np.ndarray
    ) -> np.ndarray:
        """y₁ = y₀ + Δt A⁻¹f(t + Δt, y₁) by Newton."""
        return _theta_stage(first_order(problem), t + dt, dt, y)

    def step_system(self, system: System, t, dt, x_in, v_in, x_out, v_out) -> None:
        """One backward-Euler step: minimise the incremental potential, then v₁ = δ(x₁ − x₀)/Δt."""
        m = system.model
        grad = recording_gradients(m)
        x_tilde, v_raw = _fresh(system, 2) if grad else (*self._buffers(system, 1), v_out)
        lincomb(m, x_tilde, x_in, [(dt, v_in)])
        self._minimize(system, t, dt, x_tilde, x_in, v_in, x_out)
        _velocity_from_positions(m, x_out, x_in, 1.0 / dt, v_raw)
        scale_velocity(system, dt, v_raw, v_out)  # δ from the rate array when recording (∂/∂c)


@wp.kernel
def _velocity_kernel(
    x1: wp.array(dtype=Any), x0: wp.array(dtype=Any), inv_h: Any, v_out: wp.array(dtype=Any)
):
    i = wp.tid()
    v_out[i] = (x1[i] - x0[i]) * inv_h


def _velocity_from_positions(model: Model, x1: wp.array, x0: wp.array, inv_h: float, v_out: wp.array) -> None:
    """v_out = (x1 − x0)/h."""
    launch(_velocity_kernel, model.particle_count, [x1, x0, model.s(inv_h), v_out], device=model.device)


class ImplicitMidpoint(_ImplicitOptions, Integrator):
    """Implicit midpoint: y₁ = y₀ + Δt A⁻¹f((y₀ + y₁)/2) (second order, symplectic, A-stable).

    Computed as half a backward-Euler step followed by extrapolation, y_½ = y₀ + (Δt/2) f(y_½),
    y₁ = 2y_½ − y₀, which is the same method. On a linear oscillator it conserves the energy exactly (its
    amplification is a Cayley transform, a rotation), with a period error of O(Δt²).

    Example::

        integ = pl.integrators.ImplicitMidpoint()
        sol = integ.solve(pl.integrators.harmonic_oscillator(), (1.0, 0.0), t_end=10.0, dt=0.5)
    """

    order: ClassVar[int] = 2
    explicit: ClassVar[bool] = False
    symplectic: ClassVar[bool] = True
    # Forces at x_½ over the whole step; x₁ = x₀ + Δt (v₀ + v₁)/2.
    contact_point: ClassVar[float] = 0.5
    contact_shift: ClassVar[float] = 0.5

    def step_ode(
        self, problem: ODEProblem | SecondOrderODE, t: float, dt: float, y: np.ndarray
    ) -> np.ndarray:
        """Half a backward-Euler step, then y₁ = 2 y_½ − y₀."""
        y_half = _theta_stage(first_order(problem), t + 0.5 * dt, 0.5 * dt, y)
        return 2.0 * y_half - y

    def step_system(self, system: System, t, dt, x_in, v_in, x_out, v_out) -> None:
        """x_½ = argmin Φ with Δt/2; x₁ = 2x_½ − x₀, v₁ = δ(4(x_½ − x₀)/Δt − v₀)."""
        m = system.model
        grad = recording_gradients(m)
        x_tilde, x_half, v_raw = _fresh(system, 3) if grad else (*self._buffers(system, 2), v_out)
        h = 0.5 * dt
        lincomb(m, x_tilde, x_in, [(h, v_in)])
        self._minimize(system, t, h, x_tilde, x_in, v_in, x_half)
        # v_½ = (x_½ − x₀)/h; v₁ = 2v_½ − v₀; x₁ = 2x_½ − x₀.
        lincomb(m, v_raw, v_in, [(-2.0, v_in), (2.0 / h, x_half), (-2.0 / h, x_in)])
        lincomb(m, x_out, x_half, [(1.0, x_half), (-1.0, x_in)])
        scale_velocity(system, dt, v_raw, v_out)  # δ from the rate array when recording (∂/∂c)


class BDF2(_ImplicitOptions, Integrator):
    """Second-order backward differentiation: y₁ − (4/3)y₀ + (1/3)y₋₁ = (2/3)Δt A⁻¹f(y₁) (L-stable).

    A multistep method: the first step (and any step whose history does not match, e.g. after a change of
    Δt or of the input state) is a backward-Euler step. On the ODE path a change of Δt uses the
    variable-step BDF2 formula; :meth:`reset` forgets the history.

    Physical path: ĥ = 2Δt/3, x̂ = (4x₀ − x₋₁)/3, x̃ = x̂ + ĥ(4v₀ − v₋₁)/3, x₁ = argmin Φ with ĥ,
    v₁ = δ(x₁ − x̂)/ĥ.

    Example::

        solver = pl.solvers.ForceSolver(model, integrator=pl.integrators.BDF2())
    """

    order: ClassVar[int] = 2
    explicit: ClassVar[bool] = False
    multistep: ClassVar[bool] = True
    # Forces at x₁ over ĥ = 2Δt/3, x₁ = x̂ + ĥ v₁ (the history steps; the first, backward-Euler step is
    # off by that factor for its contact friction alone).
    contact_impulse: ClassVar[float] = 2.0 / 3.0
    contact_shift: ClassVar[float] = 2.0 / 3.0

    def __init__(self, **options: Any) -> None:
        super().__init__(**options)
        self.reset()

    def reset(self) -> None:
        """Forget the previous step (the next step is backward Euler)."""
        self._ode_prev: tuple[np.ndarray, float, np.ndarray] | None = None  # (y₋₁, h₋₁, y₀ it produced)
        # (model id, dt, x_out pointer) of the last physical step; after a restore, a key for its dt only
        self._sys_key: tuple[int, float, int] | _ResumedKey | None = None
        self._grad_prev: tuple[wp.array, wp.array] | None = None  # (x₋₁, v₋₁) of a recorded step

    def step_ode(
        self, problem: ODEProblem | SecondOrderODE, t: float, dt: float, y: np.ndarray
    ) -> np.ndarray:
        """Variable-step BDF2 by Newton (backward Euler when there is no matching history)."""
        p = first_order(problem)
        prev = self._ode_prev
        if prev is None or prev[2].shape != y.shape or not np.array_equal(prev[2], y):
            y1 = _theta_stage(p, t + dt, dt, y)
        else:
            y_m1, h_m1, _ = prev
            w = dt / h_m1
            # (1+2w)/(1+w) y₁ − (1+w) y₀ + w²/(1+w) y₋₁ = h f(y₁)
            c1 = (1.0 + 2.0 * w) / (1.0 + w)
            base = ((1.0 + w) * y - w * w / (1.0 + w) * y_m1) / c1
            y1 = _theta_stage(p, t + dt, dt / c1, base)
        self._ode_prev = (y.copy(), dt, y1.copy())
        return y1

    def step_system(self, system: System, t, dt, x_in, v_in, x_out, v_out) -> None:
        """One BDF2 step (backward Euler when the history is missing or stale)."""
        m = system.model
        # A requires_grad model takes the recorded form with or without a tape: its solver's post-step
        # stages write fresh arrays (and _buffers hands out fresh ones), so neither the output pointer nor
        # the work buffers can carry the history; the previous step's input arrays do.
        grad = grad_enabled(m)
        x_tilde, x_hat, x_prev, v_prev = self._buffers(system, 4)
        v_raw = v_out
        if grad:
            # Fresh arrays, and the previous step's input state itself as the history (the tape keeps it).
            x_tilde, x_hat, v_raw = _fresh(system, 3)
            if self._grad_prev is not None:
                x_prev, v_prev = self._grad_prev
        key = (id(m), float(dt), x_in.ptr)
        stale = self._sys_key is None or self._sys_key != key
        if grad:
            # A recorded step's output goes through the solver's post-step stages into the next State, so
            # the pointer cannot link the steps: the history is the previous recorded step's input, valid
            # for the next input of the same model and Δt (``solver.reset()`` starts a new rollout).
            prev = self._grad_prev
            stale = not (
                isinstance(self._sys_key, tuple)
                and self._sys_key[:2] == key[:2]
                and prev is not None
                and prev[0].ptr != x_in.ptr
            )
        if stale:
            h = dt
            lincomb(m, x_tilde, x_in, [(h, v_in)])
            wp.copy(x_hat, x_in)
        else:
            h = 2.0 * dt / 3.0
            lincomb(m, x_hat, x_in, [(1.0 / 3.0, x_in), (-1.0 / 3.0, x_prev)])
            lincomb(m, x_tilde, x_hat, [(4.0 * h / 3.0, v_in), (-h / 3.0, v_prev)])
        self._minimize(system, t, h, x_tilde, x_hat, v_in, x_out)
        _velocity_from_positions(m, x_out, x_hat, 1.0 / h, v_raw)
        scale_velocity(system, dt, v_raw, v_out)  # δ from the rate array when recording (∂/∂c)
        if grad:
            self._grad_prev = (x_in, v_in)
        else:
            self._grad_prev = None
            wp.copy(x_prev, x_in)
            wp.copy(v_prev, v_in)
        self._sys_key = (id(m), float(dt), x_out.ptr)

    # ------------------------------------------------------------------ checkpoints
    def checkpoint_state(self) -> dict[str, np.ndarray]:
        """The physical path's history (x₋₁, v₋₁ and the step Δt) as host copies; empty without one."""
        if self._sys_key is None or getattr(self, "_ws", None) is None:
            return {}
        _, _, x_prev, v_prev = self._ws[1]
        key = self._sys_key
        dt_prev = key.dt if isinstance(key, _ResumedKey) else key[1]  # restored and not stepped since
        return {
            "bdf2_x_prev": x_prev.numpy().copy(),
            "bdf2_v_prev": v_prev.numpy().copy(),
            "bdf2_dt": np.array(float(dt_prev)),
        }

    def restore_checkpoint_state(self, state: dict[str, np.ndarray], system: System) -> None:
        """Take back :meth:`checkpoint_state`'s arrays: the next step of ``system`` with the same Δt uses
        them as its history (whatever buffer its input state lives in).

        Raises:
            ValueError: unknown keys, or arrays of the wrong shape, dtype or with non-finite values.
        """
        self.reset()
        if not state:
            return
        keys = {"bdf2_x_prev", "bdf2_v_prev", "bdf2_dt"}
        if set(state) != keys:
            raise ValueError(f"BDF2 history needs exactly the keys {sorted(keys)}, got {sorted(state)}")
        m = system.model
        np_dtype = np.dtype(m.dtype)
        arrays = []
        for k in ("bdf2_x_prev", "bdf2_v_prev"):
            a = np.asarray(state[k])
            if a.shape != (m.particle_count, 3) or a.dtype != np_dtype or not np.all(np.isfinite(a)):
                raise ValueError(
                    f"{k}: expected finite {np_dtype} of shape ({m.particle_count}, 3), "
                    f"got {a.dtype} {a.shape}"
                )
            arrays.append(a)
        dt = np.asarray(state["bdf2_dt"])
        if dt.shape != () or dt.dtype.kind != "f" or not float(dt) > 0 or not np.isfinite(dt):
            raise ValueError(f"bdf2_dt: expected a positive step [s], got {dt!r}")
        _, _, x_prev, v_prev = self._buffers(system, 4)
        x_prev.assign(arrays[0])
        v_prev.assign(arrays[1])
        self._sys_key = _ResumedKey(float(dt))


class _ResumedKey:
    """BDF2's history key after a restore: matches the next step of the same Δt, in any buffer."""

    def __init__(self, dt: float) -> None:
        self.dt = dt

    def __eq__(self, other: object) -> bool:
        return isinstance(other, tuple) and len(other) == 3 and other[1] == self.dt

    def __ne__(self, other: object) -> bool:
        return not self == other

    __hash__ = None  # type: ignore[assignment]
