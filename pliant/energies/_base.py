"""The Energy contract: value, gradient, Hessian blocks on a fixed sparsity pattern, step bound."""

from __future__ import annotations

import abc
from typing import Any

import numpy as np
import warp as wp

from .._warp import fresh, grad_enabled, launch
from ..model import Model


class Energy(abc.ABC):
    """A potential energy E(x) = Σ_e E_e(x_e) [J] over the particle positions.

    Contract (tested): ``gradient`` equals ∇``value`` and ``hessian`` equals ∇``gradient``, by central
    differences in float64. All methods *add* into their output so that terms can be summed.

    Hessians are written into the values of a block-sparse (3×3) matrix whose pattern the solver fixes
    once: ``hessian_pattern`` lists the (row, col) particle pairs this energy writes, in the order its
    kernel writes them, and the solver hands back ``slots`` — the index of each pair in the matrix values.
    Assembly is then an atomic add per block, with no sorting per Newton iteration.
    """

    #: True for terms that depend on velocity (dissipation), prepared by ``begin_step``.
    dissipative: bool = False

    #: True for terms whose Hessian switches with an active set (contact penalties): the quasi-Newton
    #: minimiser re-evaluates them every step instead of lagging them with the elastic terms.
    hessian_changes_each_step: bool = False

    def begin_step(self, model: Model, x: wp.array, v: wp.array, dt: float) -> None:  # noqa: B027
        """Freeze per-step data (e.g. the dashpot axis) at the start of a step; default: nothing."""

    def step_inputs(self) -> tuple:
        """Arrays this energy reads besides the model and x that may be swapped between steps (moving
        control points): the implicit steps' adjoint captures them when a step runs and puts them back
        while it back-propagates that step. Default: none."""
        return ()

    def set_step_inputs(self, inputs: tuple) -> None:  # noqa: B027
        """Put back what :meth:`step_inputs` returned; default: nothing."""

    @abc.abstractmethod
    def value(self, model: Model, x: wp.array, out: wp.array) -> None:
        """Add E(x) [J] into ``out[0]``."""

    @abc.abstractmethod
    def gradient(self, model: Model, x: wp.array, out: wp.array) -> None:
        """Add ∂E/∂x [N] per particle into ``out``, shape [particle_count] of vec3."""

    def value_and_gradient(self, model: Model, x: wp.array, value_out: wp.array, grad_out: wp.array) -> None:
        """Add E(x) [J] into ``value_out[0]`` and ∂E/∂x [N] into ``grad_out``; override to fuse the passes."""
        self.gradient(model, x, grad_out)
        self.value(model, x, value_out)

    def hessian_pattern(self, model: Model) -> tuple[np.ndarray, np.ndarray]:
        """(rows, cols) of the 3×3 blocks ``hessian`` writes, in write order; default: none."""
        return np.zeros(0, np.int32), np.zeros(0, np.int32)

    def pattern_version(self, model: Model) -> int:
        """A number that changes whenever :meth:`hessian_pattern` does (the minimisers rebuild their matrix
        pattern then); default 0: the pattern is fixed per model."""
        return 0

    def refresh_pattern(self, model: Model, x: wp.array) -> None:  # noqa: B027
        """Update the Hessian pattern for a step starting at x [m] (e.g. contact pairs), before the minimiser
        builds its matrix; default: nothing (a fixed pattern)."""

    def hessian(  # noqa: B027
        self,
        model: Model,
        x: wp.array,
        slots: wp.array,
        values: wp.array,
        *,
        project_psd: bool = True,
        scale: float = 1.0,
    ) -> None:
        """Add ``scale``·∂²E/∂x² [N/m] blocks into ``values[slots[k]]``; PSD-projected per element."""

    def max_step(self, model: Model, x: wp.array, dx: wp.array) -> float:
        """Largest α ≤ 1 such that x + α dx stays admissible (no inversion, barrier); default 1."""
        return 1.0

    def max_step_into(self, model: Model, x: wp.array, dx: wp.array, alpha_io: wp.array) -> bool:
        """Lower ``alpha_io[0]`` (one element of the model's scalar, on its device) to this energy's
        :meth:`max_step` by launches alone, with no host read (the device Newton, ``linear_solver="pcg"``).

        Returns False, launching nothing, when the bound is only known on the host: the caller then uses
        :meth:`max_step`. Default: True (nothing to lower) for an energy with the default :meth:`max_step`,
        False for one that overrides it without overriding this.
        """
        return type(self).max_step is Energy.max_step

    def max_step_radius(self, model: Model, x: wp.array) -> float:
        """Radius r [m] around x: every configuration with all particle displacements |u_i| ≤ r is admissible
        (``max_step`` would return 1 for any step staying inside); default inf (no bound)."""
        return float("inf")

    def force(self, model: Model, x: wp.array, v: wp.array, out: wp.array) -> None:
        """Add the force [N] at (x, v) into ``out``; default −∇E(x) (dissipative terms override)."""
        if grad_enabled(model):
            tmp = fresh(model)  # recorded steps: every evaluation keeps its own gradient for the tape
        else:
            tmp = self._scratch(model)
            tmp.zero_()
        self.gradient(model, x, tmp)
        axpy(out, tmp, -1.0, model)

    def _scratch(self, model: Model) -> wp.array:
        buf = getattr(self, "_scratch_buf", None)
        if buf is None or buf.shape[0] != model.particle_count or buf.device != wp.get_device(model.device):
            buf = wp.zeros(model.particle_count, dtype=model.vec3, device=model.device)
            self._scratch_buf = buf
        return buf


class ModalEnergy(Energy):
    """An energy whose value, gradient and Hessian blocks come from one kernel with a ``mode`` switch.

    The kernel takes, last, ``slots_in`` (int32), ``value_out`` (scalar), ``grad_out`` (vec3) and ``hess_out``
    (mat33), and writes only the output of its mode (0 value, 1 gradient, 2 Hessian); the outputs not in
    use are 1-element dummies. Subclasses implement :meth:`_launch_mode` and :meth:`hessian_pattern`.
    """

    def value(self, model: Model, x: wp.array, out: wp.array) -> None:
        """Add E(x) [J] (for a dissipative term, the step's Rayleigh potential R(x)) into ``out[0]``."""
        self._launch_mode(model, x, 0, 1.0, True, self._outputs(model, value=out))

    def gradient(self, model: Model, x: wp.array, out: wp.array) -> None:
        """Add ∂E/∂x [N] per particle into ``out``."""
        self._launch_mode(model, x, 1, 1.0, True, self._outputs(model, grad=out))

    def hessian(self, model, x, slots, values, *, project_psd: bool = True, scale: float = 1.0) -> None:
        """Add ``scale``·∂²E/∂x² [N/m] blocks into ``values[slots[k]]``, PSD-projected if ``project_psd``."""
        self._launch_mode(model, x, 2, scale, project_psd, self._outputs(model, slots=slots, hess=values))

    @abc.abstractmethod
    def _launch_mode(
        self, model: Model, x: wp.array, mode: int, scale: float, project: bool, outputs: list[wp.array]
    ) -> None:
        """Launch the kernel in ``mode`` with ``outputs`` = [slots, value, grad, hess] as its last inputs."""

    def _outputs(
        self,
        model: Model,
        *,
        slots: wp.array | None = None,
        value: wp.array | None = None,
        grad: wp.array | None = None,
        hess: wp.array | None = None,
    ) -> list[wp.array]:
        """[slots, value, grad, hess], each output not given replaced by its dummy."""
        d_slots, d_value, d_grad, d_hess = self._dummies(model)
        return [
            d_slots if slots is None else slots,
            d_value if value is None else value,
            d_grad if grad is None else grad,
            d_hess if hess is None else hess,
        ]

    def _dummies(self, model: Model) -> tuple[wp.array, wp.array, wp.array, wp.array]:
        """1-element (int32, scalar, vec3, mat33) arrays on the model's device and dtype, cached."""
        cache: dict[tuple[str, str], tuple[wp.array, wp.array, wp.array, wp.array]] | None
        cache = getattr(self, "_dummy_cache", None)
        if cache is None:
            cache = {}
            self._dummy_cache = cache
        key = (str(wp.get_device(model.device)), model.dtype)
        if key not in cache:
            i, s, v, m = (
                wp.zeros(1, dtype=t, device=model.device)
                for t in (wp.int32, model.scalar, model.vec3, model.mat33)
            )
            cache[key] = (i, s, v, m)
        return cache[key]


@wp.kernel
def _axpy_kernel(x: wp.array(dtype=Any), a: Any, out: wp.array(dtype=Any)):
    i = wp.tid()
    # An atomic add, not out[i] = out[i] + ...: a read-then-write of the same array cannot be replayed
    # by wp.Tape; the arithmetic (one addition) is the same.
    wp.atomic_add(out, i, a * x[i])


def axpy(out: wp.array, x: wp.array, a: float, model: Model) -> None:
    launch(_axpy_kernel, dim=out.shape[0], inputs=[x, model.s(a), out], device=model.device)
