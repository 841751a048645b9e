"""Gradients through FastMassSpring's implicit step (Baraff–Witkin), by the adjoint of its linear solve.

The step solves A(p) Δv = b(p) with A = M + hD + h²K and b = h(f(xⁿ, vⁿ) − hK vⁿ), then
v₁ = δ(vⁿ + Δv), x₁ = xⁿ + h v₁ (``_solver``). With the residual R(p, Δv) = b(p) − A(p) Δv = 0,
dΔv/dp = A⁻¹ ∂R/∂p, so for an upstream cotangent Δv̄ the inputs get p̄ = λᵀ ∂R/∂p with A λ = Δv̄ (A is
symmetric): one extra linear solve per step, as for the implicit integrators
(:mod:`pliant.solvers.minimizers._adjoint`), not a differentiation of the CG iterations. λᵀ ∂R/∂p is Warp's
autodiff of the residual kernels below, launched under a local tape at the step's Δv and back-propagated
with the seed λ. The parameters p are the
step's input state, the springs' rest length, stiffness and dashpot γ, the masses, gravity and
``Control.particle_f``.

The gradient is that of the exact linear solve. The forward step stops CG at ``cg_tol``; where gradients
are checked against finite differences, converge CG tightly (``cg_tol=1e-12``, enough ``cg_iterations``).
The adjoint solve runs the forward step's own block-Jacobi CG (same kernels, same tolerance) on A.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import warp as wp

from ..._warp import GradientError, active_tape, capturing, fresh, graph_safe, launch, untaped_in_place
from ...energies import dashpot_force_axis, spring_gradient_axis
from ...integrators import Integrator, lincomb, scale_velocity
from ._system import BaraffWitkinSystem, _bw_assemble, _spring_blocks

if TYPE_CHECKING:
    from ...integrators import ODEProblem, SecondOrderODE


@wp.kernel
def _bw_residual_diagonal(
    particle_mass: wp.array(dtype=Any),
    particle_inv_mass: wp.array(dtype=Any),
    gravity: wp.array(dtype=Any),
    f_ext: wp.array(dtype=Any),
    dv: wp.array(dtype=Any),
    h: Any,
    r_out: wp.array(dtype=Any),
):
    # R_i's per-particle terms: h(m_i g + f_i) − m_i Δv_i (zero on pinned rows).
    i = wp.tid()
    m = particle_mass[i]
    r = h * (m * gravity[0] + f_ext[i]) - m * dv[i]
    if particle_inv_mass[i] == h * type(h)(0.0):
        r = r * (h * type(h)(0.0))
    r_out[i] = r


@wp.kernel
def _bw_residual_springs(
    adj_row: wp.array(dtype=wp.int32),
    adj_neighbor: wp.array(dtype=wp.int32),
    adj_spring: wp.array(dtype=wp.int32),
    spring_rest_length: wp.array(dtype=Any),
    spring_stiffness: wp.array(dtype=Any),
    spring_damping: wp.array(dtype=Any),
    particle_inv_mass: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    dv_in: wp.array(dtype=Any),
    h: Any,
    r_out: wp.array(dtype=Any),
):
    # One adjacency entry (spring s seen from particle i): its share of h(f − hKv) − (h²K_s + hD_s)
    # (Δv_i − Δv_j), the terms _bw_assemble and _bw_apply sum in a loop (carried sums: no adjoint)
    e = wp.tid()
    i = adj_row[e]
    if particle_inv_mass[i] == h * type(h)(0.0):
        return
    j = adj_neighbor[e]
    s = adj_spring[e]
    xi = x_in[i]
    vi = v_in[i]
    d = xi - x_in[j]
    l = wp.length(d)
    f = dashpot_force_axis(d, l, vi, v_in[j], spring_damping[s])
    f = f - spring_gradient_axis(d, l, spring_stiffness[s], spring_rest_length[s])
    K, H = _spring_blocks(xi, x_in[j], spring_rest_length[s], spring_stiffness[s], spring_damping[s], h)
    kv = -(K * (v_in[j] - vi))
    wp.atomic_add(r_out, i, h * (f - h * kv) - H * (dv_in[i] - dv_in[j]))


@wp.kernel
def _weight_plus_force(
    particle_mass: wp.array(dtype=Any),
    gravity: wp.array(dtype=Any),
    f_ext: wp.array(dtype=Any),
    f_out: wp.array(dtype=Any),
):
    # m_i g + f_i, the external load _bw_assemble adds (g from the 1-element array a recorded step reads).
    i = wp.tid()
    f_out[i] = particle_mass[i] * gravity[0] + f_ext[i]


@wp.kernel
def _cg_start(
    precond: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=Any),
    rhs: wp.array(dtype=Any),
    r_out: wp.array(dtype=Any),
    z_out: wp.array(dtype=Any),
    p_out: wp.array(dtype=Any),
    x_out: wp.array(dtype=Any),
    rz_out: wp.array(dtype=Any),
):
    # CG's start for A x = rhs from x = 0, in the layout _bw_assemble leaves (r, z = P r, p = z, r·z).
    i = wp.tid()
    r = rhs[i]
    zero = r[0] * type(r[0])(0.0)
    if inv_mass[i] == zero:
        r = r * zero
    z = precond[i] * r
    r_out[i] = r
    z_out[i] = z
    p_out[i] = z
    x_out[i] = r * zero
    wp.atomic_add(rz_out, 0, wp.dot(r, z))


class BaraffWitkinStep(Integrator):
    """FastMassSpring's implicit step as an integrator of ForceSolver's recorded path (``requires_grad``
    models): the same Δv (the same kernels: assemble, block-Jacobi CG), with the adjoint above on the tape.

    ``explicit`` is True in ForceSolver's sense: no minimisation, and the ground is the post-step projection
    (as FastMassSpring's own step does it), not a penalty energy.
    """

    explicit: ClassVar[bool] = True
    differentiable: ClassVar[bool] = True
    order: ClassVar[int] = 1

    def __init__(self, system: BaraffWitkinSystem) -> None:
        self.system = system  # FastMassSpring's (adjacency, CG settings, work buffers)
        row = np.repeat(np.arange(system.model.particle_count), np.diff(system.adj_offsets.numpy()))
        self.adj_row: wp.array = wp.array(row.astype(np.int32), dtype=wp.int32, device=system.model.device)
        m = system.model
        self._forces = wp.zeros(m.particle_count, dtype=m.vec3, device=m.device)  # m_i g + f_i (scratch)

    def step_ode(
        self, problem: ODEProblem | SecondOrderODE, t: float, dt: float, y: np.ndarray
    ) -> np.ndarray:
        """Not an ODE method: only FastMassSpring's physical path uses it."""
        raise NotImplementedError("BaraffWitkinStep integrates FastMassSpring's model only")

    def step_system(self, system: Any, t, dt, x_in, v_in, x_out, v_out) -> None:
        """Δv by the forward CG (tape paused), its adjoint recorded; then v₁ = δ(vⁿ + Δv), x₁ = xⁿ + h v₁."""
        m = system.model
        control = system.control
        f_ext = control.particle_f if control is not None else wp.zeros_like(x_in)
        gravity = system.gravity
        dv = fresh(m)
        with untaped_in_place():
            self._solve(m, gravity, f_ext, x_in, v_in, float(dt), dv)
        tape = active_tape()
        if tape is not None:
            adjoint = _Adjoint(self, m, gravity, f_ext, x_in, v_in, float(dt), dv)
            tape.record_func(adjoint.backward, adjoint.arrays())
        v_raw = fresh(m)
        lincomb(m, v_raw, v_in, [(1.0, dv)])
        scale_velocity(system, dt, v_raw, v_out)
        lincomb(m, x_out, x_in, [(float(dt), v_out)])

    def _solve(self, m, gravity, f_ext, x_in, v_in, h: float, dv_out) -> None:
        """The forward step's Δv (FastMassSpring's own kernels), copied into ``dv_out``."""
        self.assemble(m, gravity, f_ext, x_in, v_in, h)
        self.system.run_cg()
        wp.copy(dv_out, self.system.dv)

    def assemble(self, m, gravity, f_ext, x_in, v_in, h: float) -> None:
        """FastMassSpring's assembly at (xⁿ, vⁿ): blocks H_e, preconditioner, b (g from ``gravity``).

        g stays on the device (a captured rollout must not read it back): the weights m_i g + f_i are
        summed first into a scratch array and assembled with a zero g, the same sum (0 + a = a exactly)."""
        bw = self.system
        bw.scalars.zero_()
        launch(
            _weight_plus_force,
            m.particle_count,
            [m.particle_mass, gravity, f_ext, self._forces],
            device=m.device,
        )
        inputs = [*bw.model_inputs()[:-1], m.vec3(0.0, 0.0, 0.0)]
        launch(
            _bw_assemble,
            m.particle_count,
            [*inputs, self._forces, x_in, v_in, m.s(h), m.s(1.0), bw.block, bw.precond]
            + [bw.r, bw.z, bw.p[0], bw.dv, bw.scalars],
            device=m.device,
        )


class _Adjoint:
    """One step's adjoint: Δv̄ → cotangents of xⁿ, vⁿ, the spring parameters, masses, g and f."""

    def __init__(self, step: BaraffWitkinStep, m, gravity, f_ext, x_in, v_in, h: float, dv) -> None:
        self.step, self.m, self.gravity, self.f_ext = step, m, gravity, f_ext
        self.x_in, self.v_in, self.h, self.dv = x_in, v_in, h, dv

    def arrays(self) -> list[wp.array]:
        """Arrays whose gradients the adjoint writes (for ``Tape.zero``)."""
        return [a for a in (self.x_in, self.v_in, self.dv, self.gravity, self.f_ext) if a.requires_grad]

    @graph_safe  # launches only: λ stays on the device, so a captured rollout replays this adjoint
    def backward(self) -> None:
        """λ = A⁻¹ Δv̄, then λᵀ ∂R/∂p into the inputs' ``.grad``."""
        m, bw, h = self.m, self.step.system, self.h
        n = m.particle_count
        with untaped_in_place():  # this step's blocks H_e (a later step overwrote them)
            self.step.assemble(m, self.gravity, self.f_ext, self.x_in, self.v_in, h)
        seed = self._solve_transpose(self.dv.grad)
        local = wp.Tape()
        r = wp.zeros(n, dtype=m.vec3, device=m.device, requires_grad=True)
        dv = wp.clone(self.dv, requires_grad=False)
        with local:
            launch(
                _bw_residual_diagonal,
                n,
                [m.particle_mass, m.particle_inv_mass, self.gravity, self.f_ext, dv, m.s(h), r],
                device=m.device,
            )
            launch(
                _bw_residual_springs,
                self.step.adj_row.shape[0],
                [self.step.adj_row, bw.adj_neighbor, bw.adj_spring, m.spring_rest_length]
                + [m.spring_stiffness, m.spring_damping, m.particle_inv_mass, self.x_in, self.v_in, dv]
                + [m.s(h), r],
                device=m.device,
            )
        local.backward(grads={r: seed})

    def _solve_transpose(self, rhs: wp.array) -> wp.array:
        """λ with A λ = rhs (A is symmetric): FastMassSpring's own block-Jacobi CG on the blocks and
        preconditioner the assembly left in its work buffers, started from λ = 0 (pinned rows stay 0). Outside
        a graph capture a non-finite λ raises here; inside one the rollout's gradient check names it."""
        m, bw = self.m, self.step.system
        with untaped_in_place():
            bw.scalars.zero_()
            launch(
                _cg_start,
                m.particle_count,
                [bw.precond, m.particle_inv_mass, rhs, bw.r, bw.z, bw.p[0], bw.dv, bw.scalars],
                device=m.device,
            )
            bw.run_cg()
            lam = wp.clone(bw.dv)
        if not capturing(m.device) and not np.all(np.isfinite(lam.numpy())):
            raise GradientError(
                "FastMassSpring implicit adjoint: the step matrix's solve gave non-finite values"
            )
        return lam
