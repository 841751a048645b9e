"""Hooke springs and dashpots along the spring axis (the lecture's mass-spring forces, corrected)."""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from .._warp import launch
from ..model import SPRING_DAMPING, SPRING_REST_LENGTH, SPRING_STIFFNESS, Model, Parameter, declares
from ._base import Energy, ModalEnergy


@wp.func
def spring_energy(xi: Any, xj: Any, k: Any, rest: Any):
    """E = ½ k (|x_i − x_j| − l)²  [J]."""
    s = wp.length(xi - xj) - rest
    return type(k)(0.5) * k * s * s


@wp.func
def spring_gradient_axis(d: Any, l: Any, k: Any, rest: Any):
    """:func:`spring_gradient` from d = x_i − x_j and l = |d| already computed (fused solvers)."""
    g = d * type(k)(0.0)
    if l > type(k)(0.0):
        g = d * (k * (l - rest) / l)
    return g


@wp.func
def spring_gradient(xi: Any, xj: Any, k: Any, rest: Any):
    """∂E/∂x_i = k (|d| − l) d/|d|, d = x_i − x_j  [N]; zero for coincident endpoints."""
    d = xi - xj
    return spring_gradient_axis(d, wp.length(d), k, rest)


@wp.func
def spring_hessian(xi: Any, xj: Any, k: Any, rest: Any, project: int):
    """∂²E/∂x_i² = k[(1 − l/|d|)(I − d̂d̂ᵀ) + d̂d̂ᵀ]; projection clamps the transverse term at 0."""
    d = xi - xj
    l = wp.length(d)
    one = type(k)(1.0)
    n = d / wp.max(l, type(k)(1.0e-30))
    nn = wp.outer(n, n)
    t = one - rest / wp.max(l, type(k)(1.0e-30))
    if project != 0:
        t = wp.max(t, type(k)(0.0))
    eye = wp.identity(n=3, dtype=type(k))
    return k * (t * (eye - nn) + nn)


@wp.kernel
def _spring_value(
    spring_indices: wp.array2d(dtype=wp.int32),
    spring_rest_length: wp.array(dtype=Any),
    spring_stiffness: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    s = wp.tid()
    e = spring_energy(
        x_in[spring_indices[s, 0]], x_in[spring_indices[s, 1]], spring_stiffness[s], spring_rest_length[s]
    )
    wp.atomic_add(out, 0, e)


@wp.kernel
def _spring_gradient(
    spring_indices: wp.array2d(dtype=wp.int32),
    spring_rest_length: wp.array(dtype=Any),
    spring_stiffness: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    grad_out: wp.array(dtype=Any),
):
    s = wp.tid()
    i = spring_indices[s, 0]
    j = spring_indices[s, 1]
    g = spring_gradient(x_in[i], x_in[j], spring_stiffness[s], spring_rest_length[s])
    wp.atomic_add(grad_out, i, g)
    wp.atomic_sub(grad_out, j, g)


@wp.kernel
def _spring_hessian(
    spring_indices: wp.array2d(dtype=wp.int32),
    spring_rest_length: wp.array(dtype=Any),
    spring_stiffness: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    scale: Any,
    project: int,
    slots_in: wp.array(dtype=wp.int32),
    values_out: wp.array(dtype=Any),
):
    s = wp.tid()
    i = spring_indices[s, 0]
    j = spring_indices[s, 1]
    h = scale * spring_hessian(x_in[i], x_in[j], spring_stiffness[s], spring_rest_length[s], project)
    wp.atomic_add(values_out, slots_in[4 * s + 0], h)
    wp.atomic_add(values_out, slots_in[4 * s + 1], h)
    wp.atomic_sub(values_out, slots_in[4 * s + 2], h)
    wp.atomic_sub(values_out, slots_in[4 * s + 3], h)


def _spring_pattern(model: Model) -> tuple[np.ndarray, np.ndarray]:
    idx = model.spring_indices.numpy()
    i, j = idx[:, 0], idx[:, 1]
    rows = np.stack([i, j, i, j], axis=1).ravel()
    cols = np.stack([i, j, j, i], axis=1).ravel()
    return rows.astype(np.int32), cols.astype(np.int32)


@declares
class Springs(Energy):
    """Hooke springs of the model: E = Σ ½ k_s (|x_i − x_j| − l_s)².

    The force on i points toward j when stretched, F_i = k(|x_j − x_i| − l)(x_j − x_i)/|x_j − x_i| (the
    lecture's formula). Per-spring stiffness and rest length come from ``model.spring_stiffness`` and
    ``model.spring_rest_length``; the Hessian is projected to PSD by clamping the compressive transverse
    term (Choi & Ko 2002), which is what keeps Baraff–Witkin implicit steps stable.
    """

    @classmethod
    def parameters(cls) -> tuple[Parameter, ...]:
        """Per-spring stiffness k and rest length l."""
        return (
            SPRING_STIFFNESS,
            SPRING_REST_LENGTH,
        )

    def _inputs(self, model: Model) -> list:
        return [model.spring_indices, model.spring_rest_length, model.spring_stiffness]

    def value(self, model: Model, x: wp.array, out: wp.array) -> None:
        """Add the spring energy [J] into ``out[0]``."""
        if model.spring_count:
            launch(_spring_value, model.spring_count, [*self._inputs(model), x, out], device=model.device)

    def gradient(self, model: Model, x: wp.array, out: wp.array) -> None:
        """Add ∂E/∂x [N] into ``out``."""
        if model.spring_count:
            launch(_spring_gradient, model.spring_count, [*self._inputs(model), x, out], device=model.device)

    def hessian_pattern(self, model: Model) -> tuple[np.ndarray, np.ndarray]:
        """Four blocks per spring: (i,i), (j,j), (i,j), (j,i)."""
        return _spring_pattern(model)

    def hessian(self, model, x, slots, values, *, project_psd: bool = True, scale: float = 1.0) -> None:
        """Add scale·∂²E/∂x² [N/m] blocks into ``values[slots]``."""
        if model.spring_count:
            launch(
                _spring_hessian,
                model.spring_count,
                [*self._inputs(model), x, model.s(scale), int(project_psd), slots, values],
                device=model.device,
            )


@wp.func
def dashpot_force_axis(d: Any, l: Any, vi: Any, vj: Any, gamma: Any):
    """:func:`dashpot_force` from d = x_i − x_j and l = |d| already computed (fused solvers)."""
    f = d * type(gamma)(0.0)
    if l > type(gamma)(0.0):
        n = d / l
        f = -gamma * wp.dot(vi - vj, n) * n
    return f


@wp.func
def dashpot_force(xi: Any, xj: Any, vi: Any, vj: Any, gamma: Any):
    """F_i = −γ((v_i − v_j)·d̂)d̂, d̂ = (x_i − x_j)/|x_i − x_j|  [N] (the lecture's dashpot as a vector)."""
    d = xi - xj
    return dashpot_force_axis(d, wp.length(d), vi, vj, gamma)


@wp.kernel
def _dashpot_force(
    spring_indices: wp.array2d(dtype=wp.int32),
    spring_damping: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    f_out: wp.array(dtype=Any),
):
    s = wp.tid()
    i = spring_indices[s, 0]
    j = spring_indices[s, 1]
    f = dashpot_force(x_in[i], x_in[j], v_in[i], v_in[j], spring_damping[s])
    wp.atomic_add(f_out, i, f)
    wp.atomic_sub(f_out, j, f)


@wp.kernel
def _dashpot_axes(
    spring_indices: wp.array2d(dtype=wp.int32),
    x_in: wp.array(dtype=Any),
    axis_out: wp.array(dtype=Any),
):
    s = wp.tid()
    d = x_in[spring_indices[s, 0]] - x_in[spring_indices[s, 1]]
    l = wp.length(d)
    if l > type(l)(0.0):
        axis_out[s] = d / l
    else:
        axis_out[s] = d


@wp.kernel
def _dashpot_implicit(
    spring_indices: wp.array2d(dtype=wp.int32),
    spring_damping: wp.array(dtype=Any),
    axis: wp.array(dtype=Any),
    x_ref: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    inv_dt: Any,
    mode: int,
    scale: Any,
    slots_in: wp.array(dtype=wp.int32),
    value_out: wp.array(dtype=Any),
    grad_out: wp.array(dtype=Any),
    hess_out: wp.array(dtype=Any),
):
    # R(x) = γ/(2h) (((x_i − x_i^n) − (x_j − x_j^n))·n)², n frozen at x^n: h²∇R = hγ(Δv·n)n reproduces
    # the dashpot force at v_{n+1} = (x − x^n)/h inside the incremental potential.
    s = wp.tid()
    i = spring_indices[s, 0]
    j = spring_indices[s, 1]
    n = axis[s]
    g = spring_damping[s] * inv_dt
    r = wp.dot((x_in[i] - x_ref[i]) - (x_in[j] - x_ref[j]), n)
    if mode == 0:
        wp.atomic_add(value_out, 0, type(g)(0.5) * g * r * r)
    elif mode == 1:
        wp.atomic_add(grad_out, i, g * r * n)
        wp.atomic_sub(grad_out, j, g * r * n)
    else:
        h = scale * g * wp.outer(n, n)
        wp.atomic_add(hess_out, slots_in[4 * s + 0], h)
        wp.atomic_add(hess_out, slots_in[4 * s + 1], h)
        wp.atomic_sub(hess_out, slots_in[4 * s + 2], h)
        wp.atomic_sub(hess_out, slots_in[4 * s + 3], h)


@declares
class Dashpots(ModalEnergy):
    """Dashpots on the model's springs: F_i = −γ((v_i − v_j)·d̂)d̂ (dissipates, conserves momentum).

    Explicit integrators call :meth:`force`. Implicit ones call :meth:`begin_step` and then treat the
    dashpot as the Rayleigh potential R(x) = γ/(2h)(((x_i − x_iⁿ) − (x_j − x_jⁿ))·d̂ⁿ)² with the axis frozen
    at the start of the step, so Newton sees a quadratic term with an exact Hessian.
    """

    dissipative = True

    @classmethod
    def parameters(cls) -> tuple[Parameter, ...]:
        """Per-spring dashpot coefficient γ."""
        return (SPRING_DAMPING,)

    def __init__(self) -> None:
        self._axis: wp.array | None = None
        self._x_ref: wp.array | None = None
        self._inv_dt = 0.0

    def force(self, model: Model, x: wp.array, v: wp.array, out: wp.array) -> None:
        """Add the dashpot forces [N] at (x, v) into ``out``."""
        if model.spring_count:
            launch(
                _dashpot_force,
                model.spring_count,
                [model.spring_indices, model.spring_damping, x, v, out],
                device=model.device,
            )

    def begin_step(self, model: Model, x: wp.array, v: wp.array, dt: float) -> None:
        """Freeze the spring axes and the reference positions xⁿ [m] for the implicit potential."""
        if model.requires_grad:
            # Differentiable: this step's axes in a fresh array, and x itself as the reference.
            self._axis = wp.zeros(
                model.spring_count, dtype=model.vec3, device=model.device, requires_grad=True
            )
            self._x_ref = x
        else:
            axis = self._axis
            if (
                axis is None
                or self._x_ref is None
                or axis.shape[0] != model.spring_count
                or axis.requires_grad
            ):
                self._axis = wp.zeros(model.spring_count, dtype=model.vec3, device=model.device)
                self._x_ref = wp.zeros(model.particle_count, dtype=model.vec3, device=model.device)
            wp.copy(self._x_ref, x)
        self._inv_dt = 1.0 / dt
        if model.spring_count:
            launch(
                _dashpot_axes, model.spring_count, [model.spring_indices, x, self._axis], device=model.device
            )

    def _launch_mode(self, model, x, mode, scale, project, outputs) -> None:
        """The Rayleigh potential R(x) of the current step (PSD by construction: ``project`` is unused)."""
        if not model.spring_count:
            return
        if self._axis is None:
            raise RuntimeError("Dashpots.begin_step must be called before the implicit potential is used")
        launch(
            _dashpot_implicit,
            model.spring_count,
            [
                model.spring_indices,
                model.spring_damping,
                self._axis,
                self._x_ref,
                x,
                model.s(self._inv_dt),
                mode,
                model.s(scale),
                *outputs,
            ],
            device=model.device,
        )

    def hessian_pattern(self, model: Model) -> tuple[np.ndarray, np.ndarray]:
        """Same four blocks per spring as :class:`Springs`."""
        return _spring_pattern(model)
