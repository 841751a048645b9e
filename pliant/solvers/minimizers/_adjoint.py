"""Gradients through implicit steps: the adjoint of the converged minimisation (implicit function theorem).

An implicit step returns x₁ = argmin_x Φ(x; p) with

    Φ(x; p) = ½ ‖x − x̃‖²_M + h² (Σ_e E_e(x; θ) + R(x; x_ref) − f·x + ½k|x_d − target|²)

over the free particles (fixed ones stay at x̃), where p gathers x̃ (itself a function of the step's input
state), the energies' parameters θ (spring stiffness, rest length, γ, tet μ and λ, ...), the dissipation's
reference state and the Control's forces. At the minimum G(x₁; p) = ∇ₓΦ = 0 on the free rows, so

    dx₁/dp = −H⁻¹ ∂G/∂p,  H = ∂G/∂x = ∇²Φ(x₁)  (exact, not PSD-projected),

and for an upstream cotangent x̄₁ the cotangents of the inputs are p̄ = −wᵀ ∂G/∂p with H w = x̄₁ (H is
symmetric): one linear solve per step, whatever the number of minimiser iterations. The vector-Jacobian
product −wᵀ ∂G/∂p is Warp's own autodiff of the energies' gradient kernels, launched once more at x₁ under
a local ``wp.Tape`` into fresh arrays and back-propagated with the seed −w. Fixed rows: x₁ = x̃ there, and
the free rows' residual depends on them through the energies' coupling, so
x̃̄_fixed = x̄₁_fixed − (wᵀ ∂G/∂x)_fixed.

:func:`differentiable` wraps a minimiser: while a ``wp.Tape`` records and the model was finalised with
``requires_grad=True``, the minimisation runs with the tape paused (its iterations are not differentiated)
and the adjoint above is registered with ``tape.record_func``.

Why not unroll the iterations: the minimiser's iteration count, line search and lagged Hessians are
implementation details; differentiating them costs memory per iteration and gives the derivative of the
iterate, not of the solution. The IFT gives the derivative of the exact minimiser, to the accuracy to which
the step converged (tighten ``newton_tol`` when gradients matter).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from ..._blas import single_threaded
from ..._warp import GradientError, _tape_active, active_tape, launch, tape_paused
from .._post import drag_force
from ._assembly import _inverse_diagonal, assemble, control_of
from ._problem import workspace_of

if TYPE_CHECKING:
    from ...model import Model
    from ._problem import PotentialProblem, Workspace


def _recording(model: Model) -> wp.Tape | None:
    """The active tape when gradients of this model are being recorded, else None."""
    if not (_tape_active() and getattr(model, "requires_grad", False)):
        return None
    return active_tape()


@wp.kernel
def _step_residual(
    mass: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=Any),
    h2: Any,
    x: wp.array(dtype=Any),
    x_tilde: wp.array(dtype=Any),
    egrad: wp.array(dtype=Any),
    f_ext: wp.array(dtype=Any),
    drag_index: int,
    drag_target: Any,
    drag_stiffness: Any,
    drag_max_force: Any,
    out: wp.array(dtype=Any),
):
    # G = ∇Φ = M (x − x̃) + h² (∇E − f + drag), zero on fixed rows (same terms as the minimisers' ∇Φ).
    i = wp.tid()
    e = egrad[i] - f_ext[i]
    if i == drag_index:
        e = e - drag_force(drag_target, drag_stiffness, drag_max_force, x[i])
    g = mass[i] * (x[i] - x_tilde[i]) + h2 * e
    if inv_mass[i] == h2 * type(h2)(0.0):
        g = g * type(h2)(0.0)
    out[i] = g


def differentiable(minimize: Callable[..., Any]) -> Callable[..., Any]:
    """Wrap a minimiser ``minimize(problem, t, h, x_tilde, x_ref, v_ref, x_out, options)`` so that a recording
    ``wp.Tape`` receives the IFT adjoint of the step instead of the minimiser's iterations."""

    @functools.wraps(minimize)
    def wrapper(problem, t, h, x_tilde, x_ref, v_ref, x_out, options=None, **kwargs):
        tape = _recording(problem.model)
        if tape is None:
            return minimize(problem, t, h, x_tilde, x_ref, v_ref, x_out, options, **kwargs)
        adjoint = _StepAdjoint(problem, h, x_tilde, x_ref, v_ref, x_out)
        with tape_paused():
            stats = minimize(problem, t, h, x_tilde, x_ref, v_ref, x_out, options, **kwargs)
        tape.record_func(adjoint.backward, adjoint.arrays())
        return stats

    return wrapper


class _StepAdjoint:
    """What one implicit step's adjoint needs, captured when the step runs; :meth:`backward` applies it."""

    def __init__(self, problem: PotentialProblem, h: float, x_tilde, x_ref, v_ref, x_out) -> None:
        for name, a in (("x_tilde", x_tilde), ("x_out", x_out)):
            if not a.requires_grad:
                raise GradientError(
                    f"implicit step under a recording wp.Tape: its {name} array has no gradient; allocate "
                    "the step's states with requires_grad=True (model.state() after "
                    "finalize(requires_grad=True))"
                )
        if x_out.ptr in (x_tilde.ptr, x_ref.ptr):
            raise GradientError("implicit step adjoint: x_out must not alias x_tilde or x_ref")
        self.problem = problem
        self.model = problem.model
        self.energies = list(problem.energies)
        # What each energy reads besides x that may be swapped before the next step (moving control points).
        self.inputs = [e.step_inputs() for e in self.energies]
        self.h = float(h)
        self.x_tilde, self.x_ref, self.v_ref, self.x_out = x_tilde, x_ref, v_ref, x_out
        c = control_of(problem)
        # The Control as it is now: a later step may hand the solver another one.
        self.f_ext = None if c is None else c.particle_f
        self.drag = None
        if c is not None and c.drag_index >= 0:
            self.drag = (
                int(c.drag_index),
                tuple(c.drag_target),
                float(c.drag_stiffness),
                float(c.drag_max_force),
            )

    def arrays(self) -> list[wp.array]:
        """Arrays whose gradients the adjoint writes (for ``Tape.zero``)."""
        out = [self.x_tilde, self.x_out]
        out += [a for a in (self.x_ref, self.v_ref, self.f_ext) if a is not None and a.requires_grad]
        return out

    def backward(self) -> None:
        """x̄₁ (in ``x_out.grad``) → cotangents of x̃, the dissipation's reference state, θ and f."""
        now = [e.step_inputs() for e in self.energies]
        try:
            for e, inputs in zip(self.energies, self.inputs, strict=True):
                e.set_step_inputs(inputs)  # this step's control points, not the latest
            self._backward()
        finally:
            for e, inputs in zip(self.energies, now, strict=True):
                e.set_step_inputs(inputs)

    def _backward(self) -> None:
        m = self.model
        n = m.particle_count
        xbar = self.x_out.grad.numpy().astype(np.float64)
        free = m.particle_inv_mass.numpy() > 0.0
        local = wp.Tape()
        with local:
            # The dissipation's per-step data (e.g. the dashpots' frozen axes) of this step, recorded so that
            # the reference state gets its share.
            for e in self.energies:
                if e.dissipative:
                    e.begin_step(m, self.x_ref, self.v_ref, self.h)
        with tape_paused():
            ws = workspace_of(self.problem)
            assemble(self.problem, ws, self.x_out, self.h, False, control=self.drag is not None)
            rhs = np.where(free[:, None], xbar, 0.0)
            w = self._solve(ws, rhs)
            x_c = wp.clone(self.x_out, requires_grad=True)
            x_c.grad.zero_()  # wp.clone copies the gradient too
            egrad = wp.zeros(n, dtype=m.vec3, device=m.device, requires_grad=True)
            residual = wp.zeros(n, dtype=m.vec3, device=m.device, requires_grad=True)
            f_ext = self.f_ext if self.f_ext is not None else wp.zeros(n, dtype=m.vec3, device=m.device)
        spans = []
        with local:
            for e in self.energies:
                start = len(local.launches)
                e.gradient(m, x_c, egrad)
                spans.append((e, start, len(local.launches)))
            di, dtarget, dk, dcap = self.drag if self.drag is not None else (-1, (0.0, 0.0, 0.0), 0.0, 0.0)
            launch(
                _step_residual,
                n,
                [m.particle_mass, m.particle_inv_mass, m.s(self.h * self.h), x_c, self.x_tilde, egrad, f_ext]
                + [di, m.vec3(*dtarget), m.s(dk), m.s(dcap), residual],
                device=m.device,
            )
        _check_adjoints(local, spans)
        seed: wp.array = wp.array((-w).astype(ws.np_dtype), dtype=m.vec3, device=m.device)
        local.backward(grads={residual: seed})
        # Fixed rows: x₁ = x̃ there; add x̄₁ and the free rows' dependence on them through the energies.
        fixed = ~free
        if fixed.any():
            g = self.x_tilde.grad.numpy()
            g[fixed] += (xbar[fixed] + x_c.grad.numpy()[fixed].astype(np.float64)).astype(g.dtype)
            self.x_tilde.grad.assign(g)

    def _solve(self, ws: Workspace, rhs: np.ndarray) -> np.ndarray:
        """w = H⁻¹ rhs with the exact Hessian in ``ws`` (SciPy sparse LU on the CPU, Warp CG on a GPU)."""
        m = self.model
        n = m.particle_count
        if wp.get_device(m.device).is_cpu:
            import scipy.sparse as sp
            from scipy.sparse.linalg import splu

            vals = ws.values.numpy()[: ws.nnz].astype(np.float64)
            H = sp.bsr_matrix((vals, ws.indices, ws.indptr), shape=(3 * n, 3 * n)).tocsc()
            try:
                with single_threaded():
                    return splu(H).solve(rhs.reshape(-1)).reshape(n, 3)
            except RuntimeError as exc:
                raise GradientError(
                    f"implicit step adjoint: the Hessian at the step's solution is singular ({exc}); the "
                    "step did not end at a strict minimum (raise max_newton_iterations, lower newton_tol "
                    "or dt)"
                ) from None
        ws.rhs.assign(rhs.astype(ws.np_dtype))
        ws.dx.zero_()
        launch(_inverse_diagonal, n, [ws.diag_slots, ws.values, ws.inv_diag], device=m.device)
        eps = float(np.finfo(ws.np_dtype).eps)
        ws.cg(max(1e-12, 30.0 * eps), max(2000, 3 * n))()
        return ws.dx.numpy().astype(np.float64)


def _check_adjoints(tape: wp.Tape, spans: list[tuple[Any, int, int]]) -> None:
    """Raise when a recorded energy kernel has no adjoint (its parameters would silently get zero)."""
    for e, start, stop in spans:
        for rec in tape.launches[start:stop]:
            kernel = rec[0] if isinstance(rec, (list, tuple)) and rec else None
            options = getattr(kernel, "options", None) or {}
            if options.get("enable_backward", True) is False:
                raise GradientError(
                    f"{type(e).__name__}: its gradient kernel {getattr(kernel, 'key', kernel)!r} has no "
                    "adjoint (enable_backward=False), so gradients through implicit steps with this energy "
                    "are not available; run without requires_grad or use an energy with a differentiable "
                    "gradient kernel"
                )
