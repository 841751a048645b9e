"""A constraint given only C(x): ∇C by Warp's reverse-mode automatic differentiation."""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp
from numpy.typing import ArrayLike

from ..model import Model
from ._base import Constraint, ProjectionContext, constraint_delta_lambda


@wp.kernel(enable_backward=False)
def _gather(
    indices: wp.array2d(dtype=wp.int32),
    p_in: wp.array(dtype=Any),
    xg_out: wp.array2d(dtype=Any),
    grad_out: wp.array2d(dtype=Any),
):
    s, j = wp.tid()
    xg_out[s, j] = p_in[indices[s, j]]
    grad_out[s, j] = p_in[0] * type(p_in[0][0])(0.0)


@wp.kernel(enable_backward=False)
def _project_generic(
    indices: wp.array2d(dtype=wp.int32),
    arity: int,
    compliance: wp.array(dtype=Any),
    split: wp.array(dtype=wp.int32),
    inv_mass: wp.array(dtype=Any),
    inv_dt2: Any,
    pbd_k: Any,
    unilateral: int,
    c_in: wp.array(dtype=Any),
    grad_in: wp.array2d(dtype=Any),
    lam_io: wp.array(dtype=Any),
    delta_out: wp.array(dtype=Any),
    count_out: wp.array(dtype=wp.int32),
):
    s = wp.tid()
    c = c_in[s]
    zero = type(c)(0.0)
    if unilateral != 0 and c >= zero:
        return
    wgs = zero
    for j in range(arity):
        i = indices[s, j]
        g = grad_in[s, j]
        wgs = wgs + inv_mass[i] * type(c)(split[i]) * wp.dot(g, g)
    lam = lam_io[s]
    dl = constraint_delta_lambda(c, wgs, compliance[s] * inv_dt2, lam, pbd_k)
    lam_io[s] = lam + dl
    for j in range(arity):
        i = indices[s, j]
        # Mass splitting, as in the other Jacobi kernels: the average of the copies is Σ w Δλ ∇C.
        wp.atomic_add(delta_out, i, (inv_mass[i] * type(c)(split[i]) * dl) * grad_in[s, j])
        wp.atomic_add(count_out, i, 1)


def _make_eval(c_func: Any) -> wp.Kernel:
    """A kernel evaluating ``c_func`` per constraint; its adjoint gives ∇C per constraint copy."""

    # A Warp kernel built by wp.kernel below, not by a decorator: its annotations are Warp's, not types.
    def eval_c(
        xg: wp.array2d(dtype=Any),  # type: ignore[valid-type]
        params: wp.array(dtype=Any),  # type: ignore[valid-type]
        c_out: wp.array(dtype=Any),  # type: ignore[valid-type]
    ):
        s = wp.tid()
        c_out[s] = c_func(xg[s, 0], xg[s, 1], xg[s, 2], xg[s, 3], params[s])

    eval_c.__name__ = eval_c.__qualname__ = f"generic_c_{c_func.key}"
    return wp.kernel(module="unique")(eval_c)


class GenericConstraint(Constraint):
    """Any constraint of up to four particles from C alone; ∇C comes from Warp's reverse-mode autodiff.

    ``c_func`` is a ``@wp.func`` ``C(x0, x1, x2, x3, param)`` (generic over the scalar type, with ``Any``
    annotations); constraints of fewer particles ignore the trailing points (pad their indices with any
    particle of the constraint). Each sweep gathers every constraint's points into its own copy, evaluates
    C, and runs the adjoint kernel with ∂L/∂C = 1 so that each copy receives exactly ∇C of its
    constraint; corrections are then averaged per particle with mass splitting (Jacobi, any schedule).

    Args:
        c_func: the constraint function.
        indices: [n, k] particle indices, k ≤ 4.
        params: [n] or scalar per-constraint parameter passed to ``c_func`` (e.g. a rest value).
        compliance: α (scalar or [n]).
        unilateral: project only where C < 0 (C ≥ 0 constraints).
        stiffness: PBD stiffness k in [0, 1].

    Example::

        @wp.func
        def height_c(x0: Any, x1: Any, x2: Any, x3: Any, h: Any):
            return x0[1] - h
        floor = pl.constraints.GenericConstraint(height_c, [[i] for i in range(n)], unilateral=True)
    """

    always_jacobi = True

    def __init__(
        self,
        c_func: Any,
        indices: ArrayLike,
        *,
        params: Any = 0.0,
        compliance: Any = 0.0,
        unilateral: bool = False,
        stiffness: float = 1.0,
    ) -> None:
        super().__init__(compliance=None if np.ndim(compliance) else float(compliance), stiffness=stiffness)
        idx = np.asarray(indices, np.int64)
        if idx.ndim != 2 or not 1 <= idx.shape[1] <= 4:
            raise ValueError(f"GenericConstraint: indices must have shape [n, k], k <= 4; got {idx.shape}")
        self.arity = idx.shape[1]
        self._indices = np.concatenate([idx, np.repeat(idx[:, :1], 4 - self.arity, axis=1)], axis=1)
        self._params = params
        self._compliance_arg = compliance
        self.unilateral = bool(unilateral)
        self.is_contact = self.unilateral
        self._eval = _make_eval(c_func)

    def bind(self, model: Model, coloring: bool) -> None:
        """Copy indices and parameters; allocate the per-constraint copies and their gradients."""
        self.model = model
        idx = self._indices
        n = idx.shape[0]
        if idx.size and (idx.min() < 0 or idx.max() >= model.particle_count):
            raise ValueError(f"GenericConstraint: indices out of range [0, {model.particle_count})")
        d, f, v = model.device, model.scalar, model.vec3
        self.count = n
        self.indices: wp.array = wp.array(idx.astype(np.int32), dtype=wp.int32, device=d)
        self.params: wp.array = wp.array(
            np.broadcast_to(np.asarray(self._params, float), (n,)), dtype=f, device=d
        )
        comp = np.broadcast_to(np.asarray(self._compliance_arg, float), (n,))
        self.compliance_array: wp.array = wp.array(comp, dtype=f, device=d)
        self.lam = wp.zeros(n, dtype=f, device=d)
        self.split: wp.array = wp.array(self._split_counts(idx[:, : self.arity]), dtype=wp.int32, device=d)
        self.xg = wp.zeros((n, 4), dtype=v, device=d)
        self.grad = wp.zeros((n, 4), dtype=v, device=d)
        self.c = wp.zeros(n, dtype=f, device=d)
        self.c_adj = wp.ones(n, dtype=f, device=d)
        self.params_adj = wp.zeros(n, dtype=f, device=d)

    def evaluate(self, x: wp.array) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """C [n], indices [n, k] and the autodiff ∇C [n, k, 3] at positions ``x``."""
        self._evaluate_into(x)
        k = self.arity
        return self.c.numpy(), self.indices.numpy()[:, :k], self.grad.numpy()[:, :k]

    def _evaluate_into(self, p: wp.array) -> None:
        """C into :attr:`c` and ∇C into :attr:`grad` ([n, 4]) at positions ``p`` (launches only)."""
        m = self.model
        wp.launch(_gather, (self.count, 4), [self.indices, p, self.xg, self.grad], device=m.device)
        wp.launch(self._eval, self.count, [self.xg, self.params, self.c], device=m.device)
        wp.launch(
            self._eval,
            self.count,
            inputs=[self.xg, self.params, self.c],
            adj_inputs=[self.grad, self.params_adj, self.c_adj],
            adj_outputs=[],
            adjoint=True,
            device=m.device,
        )

    def _sweep(self, ctx: ProjectionContext, p: wp.array, dt: float) -> None:
        m = self.model
        self._evaluate_into(p)
        wp.launch(
            _project_generic,
            self.count,
            [
                self.indices,
                self.arity,
                self.compliance_array,
                self.split,
                m.particle_inv_mass,
                m.s(1.0 / (dt * dt)),
                m.s(self.pbd_k(ctx)),
                int(self.unilateral),
                self.c,
                self.grad,
                self.lam,
                ctx.delta,
                ctx.delta_count,
            ],
            device=m.device,
        )

    def project(self, ctx: ProjectionContext, p: wp.array, dt: float) -> None:
        """Evaluate C and ∇C (adjoint launch), then accumulate the corrections into ``ctx.delta``."""
        if self.count:
            ctx.call(self._sweep, ctx, p, dt)
