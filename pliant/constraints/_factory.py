"""One factory for the projection kernels of fixed-arity constraints, generated from C and ∇C ``@wp.func``s.

Every bilateral XPBD/PBD constraint of k particles is projected the same way — gather the k positions
and inverse masses, (Jacobi) split the masses, Δλ = −(C + α̃λ)/(Σ w|∇C|² + α̃) (or PBD's −k'C/Σ w|∇C|²),
then scatter wΔλ∇C — and only C and ∇C differ. :func:`projection_kernels` builds, for one pair of funcs,

- ``jacobi``: reads ``p_in`` and ``lam_in``, writes ``lam_out`` and accumulates the mass-split corrections
  and their counts atomically (the solver averages them); ``lam_in`` and ``lam_out`` may be one array
  (in place) or two (a fresh array per sweep, so a ``wp.Tape`` can replay it);
- ``gauss_seidel``: one colour's constraints update ``p_io`` and ``lam_io`` in place;
- ``residual``: Σ (C + α̃λ)² and the count of constraints with a movable particle.

The kernels are cached per (name, arity) like FEM's material kernels, generic over float32/float64.
Constraints with ``unit_gradient`` (|∇_i C| = 1, e.g. distance) use Σ w for Σ w|∇C|², which is both
cheaper and the arithmetic the hand-written distance kernels used.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import warp as wp

from ._base import Constraint, ProjectionContext, constraint_delta_lambda


class ProjectionKernels(NamedTuple):
    """The three kernels of one constraint family (see the module docstring for their arguments)."""

    jacobi: Any
    gauss_seidel: Any
    residual: Any


_CACHE: dict[tuple[str, int], ProjectionKernels] = {}


def projection_kernels(
    name: str, c_func: Any, grad_func: Any, arity: int, *, unit_gradient: bool = False
) -> ProjectionKernels:
    """The Jacobi, Gauss–Seidel and residual kernels of a constraint family, built once and cached.

    Args:
        name: a unique family name (the cache key and the kernels' module name).
        c_func: ``@wp.func`` C(x0, …, x_{k−1}, rest) → scalar.
        grad_func: ``@wp.func`` ∇C(x0, …, x_{k−1}) → (∇_0 C, …, ∇_{k−1} C).
        arity: k, 2 or 4 particles per constraint.
        unit_gradient: |∇_i C| = 1 for every point (Σ w|∇C|² = Σ w).

    Returns:
        The family's :class:`ProjectionKernels`.
    """
    key = (name, arity)
    if key not in _CACHE:
        if arity == 2:
            _CACHE[key] = _build2(name, c_func, grad_func, unit_gradient)
        elif arity == 4:
            _CACHE[key] = _build4(name, c_func, grad_func, unit_gradient)
        else:
            raise ValueError(f"projection_kernels: arity must be 2 or 4, got {arity}")
    return _CACHE[key]


def _build2(name: str, c_func: Any, grad_func: Any, unit: bool) -> ProjectionKernels:
    module = wp.get_module(f"pliant.constraints._factory.{name}")

    @wp.kernel(module=module)
    def jacobi(
        indices: wp.array2d(dtype=wp.int32),
        rest: wp.array(dtype=Any),
        compliance: wp.array(dtype=Any),
        split: wp.array(dtype=wp.int32),
        inv_mass: wp.array(dtype=Any),
        inv_dt2: Any,
        pbd_k: Any,
        offset: int,
        omega: Any,
        p_in: wp.array(dtype=Any),
        lam_in: wp.array(dtype=Any),
        lam_out: wp.array(dtype=Any),
        delta_out: wp.array(dtype=Any),
        count_out: wp.array(dtype=wp.int32),
    ):
        s = offset + wp.tid()
        i0 = indices[s, 0]
        i1 = indices[s, 1]
        # Mass splitting: each of the n_i constraints at particle i sees the mass m_i/n_i.
        w0 = inv_mass[i0] * type(omega)(split[i0])
        w1 = inv_mass[i1] * type(omega)(split[i1])
        x0 = p_in[i0]
        x1 = p_in[i1]
        c = c_func(x0, x1, rest[s])
        g0, g1 = grad_func(x0, x1)
        wgs = w0 + w1
        if wp.static(not unit):
            wgs = w0 * wp.dot(g0, g0) + w1 * wp.dot(g1, g1)
        lam = lam_in[s]
        dl = constraint_delta_lambda(c, wgs, compliance[s] * inv_dt2, lam, pbd_k) * omega
        lam_out[s] = lam + dl
        # Scatter written out (not a wp.func taking the arrays): ~15% faster on the CPU, measured.
        wp.atomic_add(delta_out, i0, (w0 * dl) * g0)
        wp.atomic_add(delta_out, i1, (w1 * dl) * g1)
        wp.atomic_add(count_out, i0, 1)
        wp.atomic_add(count_out, i1, 1)

    @wp.kernel(module=module)
    def gauss_seidel(
        indices: wp.array2d(dtype=wp.int32),
        rest: wp.array(dtype=Any),
        compliance: wp.array(dtype=Any),
        inv_mass: wp.array(dtype=Any),
        inv_dt2: Any,
        pbd_k: Any,
        offset: int,
        omega: Any,
        p_io: wp.array(dtype=Any),
        lam_io: wp.array(dtype=Any),
    ):
        s = offset + wp.tid()
        i0 = indices[s, 0]
        i1 = indices[s, 1]
        w0 = inv_mass[i0]
        w1 = inv_mass[i1]
        x0 = p_io[i0]
        x1 = p_io[i1]
        c = c_func(x0, x1, rest[s])
        g0, g1 = grad_func(x0, x1)
        wgs = w0 + w1
        if wp.static(not unit):
            wgs = w0 * wp.dot(g0, g0) + w1 * wp.dot(g1, g1)
        lam = lam_io[s]
        dl = constraint_delta_lambda(c, wgs, compliance[s] * inv_dt2, lam, pbd_k) * omega
        lam_io[s] = lam + dl
        p_io[i0] = x0 + (w0 * dl) * g0
        p_io[i1] = x1 + (w1 * dl) * g1

    @wp.kernel(module=module, enable_backward=False)
    def residual(
        indices: wp.array2d(dtype=wp.int32),
        rest: wp.array(dtype=Any),
        compliance: wp.array(dtype=Any),
        inv_mass: wp.array(dtype=Any),
        inv_dt2: Any,
        p_in: wp.array(dtype=Any),
        lam_in: wp.array(dtype=Any),
        out: wp.array(dtype=Any),
    ):
        s = wp.tid()
        i0 = indices[s, 0]
        i1 = indices[s, 1]
        if inv_mass[i0] + inv_mass[i1] == type(inv_dt2)(0.0):
            return
        r = c_func(p_in[i0], p_in[i1], rest[s]) + compliance[s] * inv_dt2 * lam_in[s]
        wp.atomic_add(out, 0, r * r)
        wp.atomic_add(out, 1, type(r)(1.0))

    return ProjectionKernels(jacobi, gauss_seidel, residual)


def _build4(name: str, c_func: Any, grad_func: Any, unit: bool) -> ProjectionKernels:
    module = wp.get_module(f"pliant.constraints._factory.{name}")

    @wp.kernel(module=module)
    def jacobi(
        indices: wp.array2d(dtype=wp.int32),
        rest: wp.array(dtype=Any),
        compliance: wp.array(dtype=Any),
        split: wp.array(dtype=wp.int32),
        inv_mass: wp.array(dtype=Any),
        inv_dt2: Any,
        pbd_k: Any,
        offset: int,
        omega: Any,
        p_in: wp.array(dtype=Any),
        lam_in: wp.array(dtype=Any),
        lam_out: wp.array(dtype=Any),
        delta_out: wp.array(dtype=Any),
        count_out: wp.array(dtype=wp.int32),
    ):
        s = offset + wp.tid()
        i0 = indices[s, 0]
        i1 = indices[s, 1]
        i2 = indices[s, 2]
        i3 = indices[s, 3]
        x0 = p_in[i0]
        x1 = p_in[i1]
        x2 = p_in[i2]
        x3 = p_in[i3]
        # Mass splitting: each of the n_i constraints at particle i sees the mass m_i/n_i.
        w0 = inv_mass[i0] * type(omega)(split[i0])
        w1 = inv_mass[i1] * type(omega)(split[i1])
        w2 = inv_mass[i2] * type(omega)(split[i2])
        w3 = inv_mass[i3] * type(omega)(split[i3])
        c = c_func(x0, x1, x2, x3, rest[s])
        g0, g1, g2, g3 = grad_func(x0, x1, x2, x3)
        wgs = w0 + w1 + w2 + w3
        if wp.static(not unit):
            wgs = w0 * wp.dot(g0, g0) + w1 * wp.dot(g1, g1) + w2 * wp.dot(g2, g2) + w3 * wp.dot(g3, g3)
        lam = lam_in[s]
        dl = constraint_delta_lambda(c, wgs, compliance[s] * inv_dt2, lam, pbd_k) * omega
        lam_out[s] = lam + dl
        wp.atomic_add(delta_out, i0, (w0 * dl) * g0)
        wp.atomic_add(delta_out, i1, (w1 * dl) * g1)
        wp.atomic_add(delta_out, i2, (w2 * dl) * g2)
        wp.atomic_add(delta_out, i3, (w3 * dl) * g3)
        wp.atomic_add(count_out, i0, 1)
        wp.atomic_add(count_out, i1, 1)
        wp.atomic_add(count_out, i2, 1)
        wp.atomic_add(count_out, i3, 1)

    @wp.kernel(module=module)
    def gauss_seidel(
        indices: wp.array2d(dtype=wp.int32),
        rest: wp.array(dtype=Any),
        compliance: wp.array(dtype=Any),
        inv_mass: wp.array(dtype=Any),
        inv_dt2: Any,
        pbd_k: Any,
        offset: int,
        omega: Any,
        p_io: wp.array(dtype=Any),
        lam_io: wp.array(dtype=Any),
    ):
        s = offset + wp.tid()
        i0 = indices[s, 0]
        i1 = indices[s, 1]
        i2 = indices[s, 2]
        i3 = indices[s, 3]
        x0 = p_io[i0]
        x1 = p_io[i1]
        x2 = p_io[i2]
        x3 = p_io[i3]
        w0 = inv_mass[i0]
        w1 = inv_mass[i1]
        w2 = inv_mass[i2]
        w3 = inv_mass[i3]
        c = c_func(x0, x1, x2, x3, rest[s])
        g0, g1, g2, g3 = grad_func(x0, x1, x2, x3)
        wgs = w0 + w1 + w2 + w3
        if wp.static(not unit):
            wgs = w0 * wp.dot(g0, g0) + w1 * wp.dot(g1, g1) + w2 * wp.dot(g2, g2) + w3 * wp.dot(g3, g3)
        lam = lam_io[s]
        dl = constraint_delta_lambda(c, wgs, compliance[s] * inv_dt2, lam, pbd_k) * omega
        lam_io[s] = lam + dl
        p_io[i0] = x0 + (w0 * dl) * g0
        p_io[i1] = x1 + (w1 * dl) * g1
        p_io[i2] = x2 + (w2 * dl) * g2
        p_io[i3] = x3 + (w3 * dl) * g3

    @wp.kernel(module=module, enable_backward=False)
    def residual(
        indices: wp.array2d(dtype=wp.int32),
        rest: wp.array(dtype=Any),
        compliance: wp.array(dtype=Any),
        inv_mass: wp.array(dtype=Any),
        inv_dt2: Any,
        p_in: wp.array(dtype=Any),
        lam_in: wp.array(dtype=Any),
        out: wp.array(dtype=Any),
    ):
        s = wp.tid()
        i0 = indices[s, 0]
        i1 = indices[s, 1]
        i2 = indices[s, 2]
        i3 = indices[s, 3]
        zero = type(inv_dt2)(0.0)
        if inv_mass[i0] + inv_mass[i1] + inv_mass[i2] + inv_mass[i3] == zero:
            return
        r = c_func(p_in[i0], p_in[i1], p_in[i2], p_in[i3], rest[s]) + compliance[s] * inv_dt2 * lam_in[s]
        wp.atomic_add(out, 0, r * r)
        wp.atomic_add(out, 1, type(r)(1.0))

    return ProjectionKernels(jacobi, gauss_seidel, residual)


class FixedArityConstraint(Constraint):
    """A set of k-particle constraints projected by the kernels :func:`projection_kernels` generates.

    Subclasses set :attr:`kernels` and, in ``bind``, the device arrays ``indices`` [n, k], ``rest`` [n],
    ``compliance_array`` [n], ``split`` [N] (Jacobi mass-splitting counts) and ``lam`` [n], and their
    colour offsets. Differentiable: under a gradient-tracking step each Jacobi sweep writes a fresh λ.
    """

    relaxes_itself = True
    differentiable = True
    kernels: ProjectionKernels

    def project(self, ctx: ProjectionContext, p: wp.array, dt: float) -> None:
        """One sweep: Gauss–Seidel per colour, or Jacobi into ``ctx.delta``."""
        m = self.model
        k = m.s(self.pbd_k(ctx))
        inv_dt2 = m.s(1.0 / (dt * dt))
        omega = m.s(ctx.relaxation)
        common = [self.indices, self.rest, self.compliance_array]
        for off, size in self.color_ranges(ctx.coloring):
            if ctx.coloring:
                args = [*common, m.particle_inv_mass, inv_dt2, k, off, omega, p, self.lam]
                ctx.launch(self.kernels.gauss_seidel, size, args)
                continue
            lam_out = ctx.fresh(self.lam) if ctx.requires_grad else self.lam
            args = [*common, self.split, m.particle_inv_mass, inv_dt2, k, off, omega, p, self.lam, lam_out]
            ctx.launch(self.kernels.jacobi, size, [*args, ctx.delta, ctx.delta_count])
            self.lam = lam_out

    def residual(self, ctx: ProjectionContext, p: wp.array, dt: float, out: wp.array) -> None:
        """Σ (C + α̃λ)² into out[0], count into out[1] (constraints with a movable particle)."""
        m = self.model
        if self.count:
            args = [self.indices, self.rest, self.compliance_array, m.particle_inv_mass]
            wp.launch(
                self.kernels.residual,
                self.count,
                [*args, m.s(1.0 / (dt * dt)), p, self.lam, out],
                device=m.device,
            )

    def _device_arrays(self, idx: np.ndarray, rest: np.ndarray, comp: np.ndarray, coloring: bool) -> None:
        """Colour-sort and copy indices, rest values, compliances, λ and split counts to the device."""
        m = self.model
        n, k = idx.shape
        order, self.color_offsets = self._colors(idx, coloring)
        rg = m.requires_grad
        d, f = m.device, m.scalar
        self.count = n
        self.indices = wp.array(idx[order].astype(np.int32).reshape(-1, k), dtype=wp.int32, device=d)
        self.rest = wp.array(rest[order], dtype=f, device=d, requires_grad=rg)
        self.compliance_array = wp.array(comp[order], dtype=f, device=d, requires_grad=rg)
        self.lam = wp.zeros(n, dtype=f, device=d, requires_grad=rg)
        self.split = wp.array(self._split_counts(idx), dtype=wp.int32, device=d)
        self.order = order
