"""The incremental potential's Hessian assembly and the step's Control terms, shared by the minimisers
(Newton, L-BFGS, the static solve) and the step adjoint.

H = M + h² Σ H_e on the fixed BSR(3×3) pattern of :mod:`.workspace_of` (every energy's blocks atomically added
into their value slots), the drag handle's spring, and fixed particles projected out (m_i·I on their
diagonal, zero elsewhere). The Control's external forces f enter Φ as the potential −f·x and its drag handle
as ½k|x − target|². Here, below both the minimisers and the adjoint, so that each imports it at module top
and neither imports the other.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from ..._warp import launch
from .._post import drag_force, drag_hessian
from ._kernels import _incremental_gradient
from ._problem import Workspace

if TYPE_CHECKING:
    from ...model import Control
    from ._problem import PotentialProblem


@wp.kernel(enable_backward=False)
def _add_mass_diagonal(
    mass: wp.array(dtype=Any),
    diag_slots: wp.array(dtype=wp.int32),
    values_io: wp.array(dtype=Any),
):
    i = wp.tid()
    m = mass[i]
    values_io[diag_slots[i]] = values_io[diag_slots[i]] + m * wp.identity(n=3, dtype=type(m))


@wp.kernel(enable_backward=False)
def _project_fixed(
    inv_mass: wp.array(dtype=Any),
    mass: wp.array(dtype=Any),
    block_rows: wp.array(dtype=wp.int32),
    block_cols: wp.array(dtype=wp.int32),
    values_io: wp.array(dtype=Any),
):
    # Fixed particles: their rows and columns become m_i·I on the diagonal and 0 elsewhere.
    k = wp.tid()
    r = block_rows[k]
    c = block_cols[k]
    m = mass[r]
    zero = type(m)(0.0)
    if inv_mass[r] == zero or inv_mass[c] == zero:
        v = values_io[k] * zero
        if r == c:
            v = m * wp.identity(n=3, dtype=type(m))
        values_io[k] = v


@wp.kernel(enable_backward=False)
def _inverse_diagonal(
    diag_slots: wp.array(dtype=wp.int32),
    values: wp.array(dtype=Any),
    inv_diag_out: wp.array(dtype=Any),
):
    i = wp.tid()
    b = values[diag_slots[i]]
    d = wp.get_diag(b)
    one = type(b[0, 0])(1.0)
    inv_diag_out[i] = wp.cw_div(d * type(one)(0.0) + type(d)(one, one, one), d)


@wp.kernel(enable_backward=False)
def _external_force_terms(
    f_ext: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    grad_out: wp.array(dtype=Any),
    value_out: wp.array(dtype=Any),
):
    # Control forces as the potential −f·x (constant over the step): gradient −f.
    i = wp.tid()
    grad_out[i] = grad_out[i] - f_ext[i]
    wp.atomic_add(value_out, 0, -wp.dot(f_ext[i], x_in[i]))


@wp.kernel(enable_backward=False)
def _drag_terms(
    index: int,
    target: Any,
    stiffness: Any,
    max_force: Any,
    scale: Any,
    diag_slots: wp.array(dtype=wp.int32),
    x_in: wp.array(dtype=Any),
    mode: int,
    grad_out: wp.array(dtype=Any),
    value_out: wp.array(dtype=Any),
    values_out: wp.array(dtype=Any),
):
    # The drag handle's zero-length spring ½k|x − target|², its force capped at max_force (then the energy
    # grows linearly, max_force (|d| − r/2) with r = max_force / k): value and gradient (mode 0) or Hessian
    # (mode 1).
    x = x_in[index]
    if mode == 0:
        d = x - target
        dist = wp.length(d)
        r = max_force / stiffness
        e = type(stiffness)(0.5) * stiffness * wp.dot(d, d)
        if dist > r:
            e = max_force * (dist - type(stiffness)(0.5) * r)
        grad_out[index] = grad_out[index] - drag_force(target, stiffness, max_force, x)
        value_out[0] = value_out[0] + e
    else:
        s = diag_slots[index]
        values_out[s] = values_out[s] + scale * drag_hessian(target, stiffness, max_force, x)


@wp.kernel(enable_backward=False)
def stiffness_ratio(
    inv_mass: wp.array(dtype=Any),
    diag_slots: wp.array(dtype=wp.int32),
    values: wp.array(dtype=Any),
    ratio_out: wp.array(dtype=Any),
):
    # max_i trace(H_ii)/(3 m_i) = 1 + h² K_ii/m_i: how much one ulp of position moves the scaled gradient.
    i = wp.tid()
    if inv_mass[i] == type(inv_mass[i])(0.0):
        return
    b = values[diag_slots[i]]
    wp.atomic_max(ratio_out, 0, (b[0, 0] + b[1, 1] + b[2, 2]) * inv_mass[i] / type(inv_mass[i])(3.0))


def control_of(problem: PotentialProblem) -> Control | None:
    """The Control (external forces, drag handle) of the step ``problem`` is taking, or None."""
    return problem.control


def control_terms(
    solver: PotentialProblem, ws: Workspace, x: wp.array, grad: wp.array, value: wp.array
) -> None:
    """Add the Control's external forces and drag handle (as potentials) into ``grad`` and ``value``."""
    c = control_of(solver)
    if c is None:
        return
    m = solver.model
    launch(_external_force_terms, m.particle_count, [c.particle_f, x, grad, value], device=m.device)
    if c.drag_index >= 0:
        launch(
            _drag_terms,
            1,
            [
                c.drag_index,
                m.vec3(*c.drag_target),
                m.s(c.drag_stiffness),
                m.s(c.drag_max_force),
                m.s(1.0),
                ws.diag_slots,
                x,
                0,
                grad,
                value,
                ws.values,
            ],
            device=m.device,
        )


def assemble(
    solver: PotentialProblem,
    ws: Workspace,
    x: wp.array,
    h: float,
    project_psd: bool,
    *,
    skip: frozenset[int] = frozenset(),
    control: bool = True,
) -> None:
    """H = M + h² Σ H_e on the fixed pattern, fixed particles projected out.

    ``skip``: indices of energies left out; ``control``: include the drag handle's spring.
    """
    m = solver.model
    ws.values.zero_()
    launch(_add_mass_diagonal, m.particle_count, [m.particle_mass, ws.diag_slots, ws.values], device=m.device)
    for k, (e, slots) in enumerate(zip(solver.energies, ws.slots, strict=True)):
        if k in skip or slots.shape[0] == 0:
            continue  # left out, or no Hessian (e.g. gravity)
        e.hessian(m, x, slots, ws.values, project_psd=project_psd, scale=h * h)
    c = control_of(solver)
    if control and c is not None and c.drag_index >= 0:
        launch(
            _drag_terms,
            1,
            [
                c.drag_index,
                m.vec3(*c.drag_target),
                m.s(c.drag_stiffness),
                m.s(c.drag_max_force),
                m.s(h * h),
                ws.diag_slots,
                x,
                1,
                ws.egrad,
                ws.gstats_e,
                ws.values,
            ],
            device=m.device,
        )
    launch(
        _project_fixed,
        ws.nnz,
        [m.particle_inv_mass, m.particle_mass, ws.block_rows, ws.block_cols, ws.values],
        device=m.device,
    )


def gradient(solver: PotentialProblem, ws: Workspace, x: wp.array, x_tilde: wp.array, h: float) -> np.ndarray:
    """∇Φ(x) into ws.grad (fixed rows zeroed); returns [max|g|/(m h), max|x|, inertia, E] (one host read)."""
    launch_gradient(solver, ws, x, x_tilde, h)
    return ws.gstats.numpy().astype(np.float64)


def launch_gradient(
    solver: PotentialProblem, ws: Workspace, x: wp.array, x_tilde: wp.array, h: float
) -> None:
    """∇Φ(x) into ws.grad (fixed rows zeroed) and [max|g|/(m h), max|x|, inertia, E] into ws.gstats."""
    m = solver.model
    n = m.particle_count
    ws.egrad.zero_()
    ws.gstats.zero_()
    for e in solver.energies:
        e.value_and_gradient(m, x, ws.gstats_e, ws.egrad)
    control_terms(solver, ws, x, ws.egrad, ws.gstats_e)
    launch(
        _incremental_gradient,
        n,
        [m.particle_mass, m.particle_inv_mass, x, x_tilde, ws.egrad, m.s(h * h), m.s(1.0 / h), ws.grad]
        + [ws.gstats],
        device=m.device,
    )
