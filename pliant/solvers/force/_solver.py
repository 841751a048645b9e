"""ForceSolver: any set of energies advanced by any integrator (mass-spring, FEM: one path)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import warp as wp

from ..._warp import GradientError, fresh, grad_enabled, launch
from ...collision import Colliders, ground_coefficients
from ...energies import Energy, Gravity, GravityFromArray, GroundPenalty, axpy, ground_penalty, mass_spring
from ...integrators import Integrator, SymplecticEuler
from ...model import Control, Model, Parameter, State, declares
from .._base import DAMPING_RATE, Solver
from .._post import add_drag_force, check_collisions, finish_step
from ..minimizers import (
    DeviceNewtonStats,
    MinimizerCache,
    MinimizerOptions,
    NewtonStats,
    band_checkpoint_state,
    band_restore_checkpoint_state,
    device_newton,
    device_newton_blocker,
    lbfgs_checkpoint_state,
    lbfgs_restore_checkpoint_state,
    minimize,
    resolve_method,
)


@wp.kernel
def _accel_from_force_gradient(
    inv_mass: wp.array(dtype=Any),
    f_in: wp.array(dtype=Any),
    grad_in: wp.array(dtype=Any),
    a_out: wp.array(dtype=Any),
):
    # Recorded steps: a = M⁻¹(F − ∇E), the potentials' gradients summed apart from the other forces so that
    # no per-energy negation pass (and its array) is recorded.
    i = wp.tid()
    a_out[i] = inv_mass[i] * (f_in[i] - grad_in[i])


@wp.kernel
def _accel_from_force(inv_mass: wp.array(dtype=Any), f_in: wp.array(dtype=Any), a_out: wp.array(dtype=Any)):
    i = wp.tid()
    a_out[i] = inv_mass[i] * f_in[i]


@declares
class ForceSolver(Solver):
    """Force-based dynamics M x'' = −∇E(x) + F_diss(x, v) + F_ext advanced by any integrator.

    Args:
        model: the Model.
        energies: potential and dissipation terms (e.g. ``pl.energies.mass_spring()``).
        integrator: any ``pl.integrators`` object (default SymplecticEuler).
        velocity_damping: the lecture's δ, multiplying velocities each step (1 = none). Depends on Δt.
        damping_rate: c [1/s] for the Δt-independent form v ← v·exp(−cΔt); overrides ``velocity_damping``.
        contact: resolve ground contact after each step (needs ``model.ground``; a compliant ground,
            ``Ground.stiffness`` set, is a spring–damper: after explicit steps,
            :func:`pliant.collision.ground_response`; inside implicit ones, its GroundPenalty).
        collisions: contact handlers run after ground contact, each with
            ``apply(model, state_in, state_out, dt)`` (``pl.collision.Colliders``, ``SelfCollision``).
        minimizer: how an implicit integrator's steps are minimised: a
            :class:`pliant.solvers.MinimizerOptions` or a dict of its settings (``{"method": "lbfgs"}``);
            None: the defaults (Newton).

    Example::

        solver = pl.solvers.ForceSolver(model, energies=pl.energies.mass_spring(),
                                        integrator=pl.integrators.SymplecticEuler())
        solver.step(state_0, state_1, control, 1e-3)
    """

    @classmethod
    def parameters(cls) -> tuple[Parameter, ...]:
        """The velocity damping rate c [1/s] (``damping_rate=c``; a Δt-independent decay)."""
        return (DAMPING_RATE,)

    def __init__(
        self,
        model: Model,
        energies: Sequence[Energy] | None = None,
        integrator: Integrator | None = None,
        *,
        velocity_damping: float = 1.0,
        damping_rate: float | None = None,
        contact: bool = True,
        collisions: Sequence[Any] = (),
        minimizer: MinimizerOptions | dict[str, Any] | None = None,
    ) -> None:
        super().__init__(model)
        self.energies = list(mass_spring() if energies is None else energies)
        for e in self.energies:
            if not isinstance(e, Energy):
                raise TypeError(f"energies must be pl.energies.Energy objects, got {type(e).__name__}")
        self.integrator = integrator if integrator is not None else SymplecticEuler()
        if not isinstance(self.integrator, Integrator):
            raise TypeError(
                f"integrator must be a pl.integrators.Integrator, got {type(self.integrator).__name__}"
            )
        if not 0.0 < velocity_damping <= 1.0:
            raise ValueError(f"velocity_damping δ must be in (0, 1], got {velocity_damping}")
        if damping_rate is not None and damping_rate < 0:
            raise ValueError(f"damping_rate must be >= 0 1/s, got {damping_rate}")
        self.velocity_damping_factor = float(velocity_damping)
        self.damping_rate = damping_rate
        if self.integrator.explicit and any(getattr(e, "feasible_start", False) for e in self.energies):
            raise ValueError(
                f"ForceSolver: barrier contact needs an implicit integrator (its CCD bounds Newton's steps), "
                f"not {self.integrator.name}; use pl.integrators.BackwardEuler()"
            )
        # An energy that is the ground contact itself (barrier contact) replaces the penalty and the
        # post-step projection: projecting would undo the barrier's intersection-free positions.
        owned = any(getattr(e, "owns_ground", False) for e in self.energies)
        self.contact = contact and model.ground is not None and not owned
        if self.contact and not self.integrator.explicit:
            # Newton must see the ground: projecting after a large implicit step flattens (inverts) elements.
            # A compliant ground is its own spring–damper; a hard one the default penalty. Explicit steps
            # get a compliant ground's spring–damper after the step (collision.ground_response: stable).
            if not any(isinstance(e, GroundPenalty) for e in self.energies):
                g = model.ground
                assert g is not None  # self.contact: the model has a ground
                self.energies.append(
                    ground_penalty(g.stiffness, g.damping)
                    if g.compliant and g.stiffness is not None
                    else GroundPenalty()
                )
        self.collisions = check_collisions(collisions)
        # Kinematic colliders whose contact is an energy (barrier, penalty) evaluate at the step's end
        # pose; when they are not also a post-step handler (which moves them), a motion handler does.
        for e in self.energies:
            cols = getattr(e, "colliders", None)
            if isinstance(cols, Colliders) and cols.moving:
                if not any(c is cols or getattr(c, "colliders", None) is cols for c in self.collisions):
                    self.collisions.append(cols.motion())
        d = model.device
        self._force = wp.zeros(model.particle_count, dtype=model.vec3, device=d)
        #: [friction μ, restitution e] of the ground as every step reads them; on a requires_grad model
        #: their ``.grad`` holds ∂loss/∂μ and ∂loss/∂e after ``tape.backward`` (None without ground contact).
        self.ground_coefficients: wp.array | None = ground_coefficients(model) if self.contact else None
        #: Recorded explicit steps read gravity g [m/s²] (1-element vec3) and the damping rate c [1/s]
        #: (1-element, only with ``damping_rate``) from these arrays; their ``.grad`` holds ∂loss/∂g and
        #: ∂loss/∂c after ``tape.backward``. None without gradients. Explicit and implicit steps alike read
        #: g through :class:`~pliant.energies.GravityFromArray`, which replaces the Gravity energies here.
        self.gravity: wp.array | None = None
        self.damping_rate_array: wp.array | None = None
        if grad_enabled(model):
            self.gravity = wp.array([model.gravity], dtype=model.vec3, device=d, requires_grad=True)
            self.energies = [
                GravityFromArray(self.gravity) if type(e) is Gravity else e for e in self.energies
            ]
            if damping_rate is not None:
                self.damping_rate_array = wp.array(
                    [damping_rate], dtype=model.scalar, device=d, requires_grad=True
                )
        self._control: Control | None = None
        self.last_stats: NewtonStats | DeviceNewtonStats | None = None
        #: What the implicit minimisers keep between steps (Hessian pattern, L-BFGS pairs and warm start).
        self.minimizer_cache = MinimizerCache()
        #: How implicit steps are minimised (:class:`MinimizerOptions`; validated here, before any step).
        self.minimizer = MinimizerOptions.coerce(minimizer)

    # ------------------------------------------------------------------ System interface
    @property
    def control(self) -> Control | None:
        """The Control of the step in progress (read by the implicit minimisers; None outside a step)."""
        return self._control

    def velocity_damping(self, dt: float) -> float:
        """δ for a step of ``dt`` [s]: exp(−cΔt) when ``damping_rate`` c is set, else the fixed δ."""
        if self.damping_rate is not None:
            return math.exp(-self.damping_rate * dt)
        return self.velocity_damping_factor

    def forces(self, t: float, x: wp.array, v: wp.array, out: wp.array) -> None:
        """Write the total force [N] at (x, v) into ``out``: −∇E, dissipation, control forces."""
        m = self.model
        c = self._control
        if grad_enabled(m):
            # ``out`` is a fresh zeroed array (see acceleration): no zeroing outside the tape.
            if c is not None:
                axpy(out, c.particle_f, 1.0, m)
        elif c is not None:
            wp.copy(out, c.particle_f)
        else:
            out.zero_()
        for e in self.energies:
            e.force(m, x, v, out)
        if c is not None and c.drag_index >= 0:
            launch(
                add_drag_force,
                1,
                [c.drag_index, m.vec3(*c.drag_target), m.s(c.drag_stiffness), m.s(c.drag_max_force), x, out],
                device=m.device,
            )

    def acceleration(self, t: float, x: wp.array, v: wp.array, out: wp.array) -> None:
        """a = M⁻¹F [m/s²]; zero for pinned and kinematic particles (inverse mass 0)."""
        m = self.model
        if grad_enabled(m):
            force, grad = fresh(m), fresh(m)
            if self._control is not None:
                axpy(force, self._control.particle_f, 1.0, m)
            for e in self.energies:
                if type(e).force is Energy.force:  # a potential: −∇E
                    e.gradient(m, x, grad)
                else:
                    e.force(m, x, v, force)
            launch(
                _accel_from_force_gradient,
                m.particle_count,
                [m.particle_inv_mass, force, grad, out],
                device=m.device,
            )
            return
        force = self._force
        self.forces(t, x, v, force)
        launch(
            _accel_from_force,
            self.model.particle_count,
            [self.model.particle_inv_mass, force, out],
            device=self.model.device,
        )

    def minimize(self, t, h, x_tilde, x_ref, v_ref, x_out, options=None):
        """Minimise the incremental potential (Newton or L-BFGS: ``self.minimizer.method``)."""
        return minimize(self, t, h, x_tilde, x_ref, v_ref, x_out, options, minimizer=self.minimizer)

    # ------------------------------------------------------------------ Solver interface
    #: Contact handlers with ``apply_out`` (pl.collision.Colliders) are recorded out of place (``rollout``).
    records_contact_handlers = True

    def step(self, state_in: State, state_out: State, control: Control | None, dt: float) -> None:
        """Advance by ``dt`` [s]: integrate, then kinematic targets, ground contact, contact handlers.

        One path with or without gradients (:func:`~pliant.solvers._post.finish_step`): on a
        ``requires_grad`` model each stage writes fresh arrays, so that ``wp.Tape`` can replay the step.
        """
        m, integ = self.model, self.integrator
        self._control = control
        if grad_enabled(m):
            self._check_recordable(control)
        finish_step(
            m,
            control,
            state_in,
            state_out,
            dt,
            lambda x, v: self.integrator.step_system(
                self, 0.0, dt, state_in.particle_q, state_in.particle_qd, x, v
            ),
            ground=self.ground_coefficients,
            collisions=self.collisions,
            ground_penalty=self._ground_penalty(),
            ground_damping=self._ground_damping(),
            contact=(integ.contact_point, integ.contact_impulse, integ.contact_shift),
        )

    def _check_recordable(self, control: Control | None) -> None:
        """GradientError, before any launch, for what a recorded step cannot differentiate."""
        if not self.integrator.explicit and not getattr(self.integrator, "differentiable", False):
            raise GradientError(
                f"{self.integrator.name} has no adjoint in this version: differentiate an explicit "
                "integrator (SymplecticEuler, VelocityVerlet, RK2/Heun/Midpoint, RK4, ForwardEuler) or "
                "BackwardEuler, ImplicitMidpoint, BDF2, or finalize the model with requires_grad=False"
            )
        for c in self.collisions:
            if not callable(getattr(c, "apply_out", None)):
                raise GradientError(
                    f"the contact handler {type(c).__name__} (collisions=) corrects the state in place and "
                    "has no apply_out for recorded steps: use pl.collision.Colliders, the ground plane "
                    "(model.ground), or finalize with requires_grad=False"
                )
        if control is not None and control.drag_index >= 0:
            raise GradientError("the drag handle is interactive and not differentiable: release_drag() first")

    def reset(self) -> None:
        """Forget what earlier steps leave for the next: the L-BFGS curvature pairs and warm start, a
        multistep integrator's history. Set-up that depends only on the model (Hessian patterns, the lagged
        Hessian's factorisation) is kept."""
        self.minimizer_cache.reset()
        if hasattr(self.integrator, "reset"):
            self.integrator.reset()

    def refresh_parameters(self) -> str | None:
        """Nothing to do for explicit integrators (the energies read the model's arrays in their kernels each
        step) and for implicit ones with Newton (it assembles from them every step; its workspace is the
        Hessian's pattern). L-BFGS keeps a lagged Hessian and its factorisation built from them: it returns
        why such a solver must be rebuilt (see :meth:`Solver.refresh_parameters`)."""
        if self.integrator.explicit or resolve_method(self.minimizer, self.model.device, self) == "newton":
            return None
        return (
            f"{type(self).__name__}({self.integrator.name}) with L-BFGS keeps a lagged Hessian and its "
            "factorisation built from the model's arrays"
        )

    def _ground_penalty(self) -> float | None:
        """κ of the GroundPenalty among the energies (the post-step then only adds friction).

        Implicit steps always have one (added in ``__init__``); an explicit step has one only when the
        caller added it, and then integrates the same contact physics as the implicit steps: the penalty
        force inside the step, Coulomb friction for its impulse after it, no projection.
        """
        for e in self.energies:
            if isinstance(e, GroundPenalty):
                return e.stiffness
        return None

    def _ground_damping(self) -> float:
        """b [1/s] of the GroundPenalty's damper (a :class:`~pliant.energies.DampedGroundPenalty`), else 0."""
        return next((getattr(e, "damping", 0.0) for e in self.energies if isinstance(e, GroundPenalty)), 0.0)

    def energy(self, state: State) -> dict[str, float]:
        """Kinetic and potential energies [J] of ``state`` (host sync: use outside hot loops)."""
        m = self.model
        out = {}
        buf = wp.zeros(1, dtype=m.scalar, device=m.device)
        for e in self.energies:
            if e.dissipative:
                continue
            buf.zero_()
            e.value(m, state.particle_q, buf)
            out[type(e).__name__] = float(buf.numpy()[0])
        v = state.particle_qd.numpy().astype(np.float64)
        out["kinetic"] = float(0.5 * np.sum(m.particle_mass_np * np.sum(v * v, axis=1)))
        return out

    def graph_blocker(self) -> str | None:
        """None for explicit integrators without a tape: their steps are kernel launches only (see
        :meth:`Solver.graph_blocker`) and for one-step implicit ones with the device Newton
        (``minimizer={"linear_solver": "pcg"}``, or the default "auto" on CUDA); other implicit steps solve on
        the host, recorded steps allocate."""
        if grad_enabled(self.model):
            return "a differentiable model's steps write fresh arrays each step"
        if not self.integrator.explicit:
            mz = self.minimizer
            if not device_newton(mz, self.model.device, self):
                return f"{self.integrator.name} minimises on the host (line search, sparse solves)"
            if getattr(self.integrator, "multistep", False):
                return f"{self.integrator.name} chooses its history on the host"
            why = device_newton_blocker(self.energies, self.model.device)
            if why is not None:
                return why
        return self._collisions_blocker()

    def describe(self) -> dict:
        """Solver, integrator and damping options."""
        return {
            "solver": "ForceSolver",
            "integrator": self.integrator.name,
            "energies": [type(e).__name__ for e in self.energies],
            "velocity_damping": self.velocity_damping_factor,
            "damping_rate": self.damping_rate,
        }

    # ------------------------------------------------------------------ checkpoints
    def checkpoint_state(self) -> dict[str, np.ndarray]:
        """L-BFGS's history and warm start (``lbfgs_*``), the band Newton's factor and warm start
        (``band_*``) and the integrator's (e.g. BDF2's ``bdf2_*``)."""
        out = lbfgs_checkpoint_state(self.minimizer_cache)
        out.update(band_checkpoint_state(self.minimizer_cache))
        own = getattr(self.integrator, "checkpoint_state", None)
        if own is not None:
            out.update(own())
        return out

    def restore_checkpoint_state(self, state: dict[str, np.ndarray]) -> None:
        """Take back :meth:`checkpoint_state`'s arrays (validated by their owners; ValueError if wrong)."""
        lbfgs = {k: a for k, a in state.items() if k.startswith("lbfgs_")}
        band = {k: a for k, a in state.items() if k.startswith("band_")}
        rest = {k: a for k, a in state.items() if not k.startswith(("lbfgs_", "band_"))}
        own = getattr(self.integrator, "restore_checkpoint_state", None)
        if own is None and rest:
            raise ValueError(
                f"{self.integrator.name} keeps no state between steps, but got {sorted(rest)}; "
                "resume with the integrator that wrote the checkpoint"
            )
        lbfgs_restore_checkpoint_state(self, lbfgs)
        band_restore_checkpoint_state(self, band)
        if own is not None:
            own(rest, self)
