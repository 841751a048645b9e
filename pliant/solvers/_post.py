"""What every force-based solver does after integrating: kinematic targets, ground, contact handlers."""

from __future__ import annotations

import weakref
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import warp as wp

from .._warp import fresh, grad_enabled, launch
from ..collision import respond_to_ground
from ..model import Control, Model, State


@wp.kernel
def _kinematic_slots(indices: wp.array(dtype=wp.int32), slot_out: wp.array(dtype=wp.int32)):
    k = wp.tid()
    slot_out[indices[k]] = k


@wp.kernel
def apply_kinematic(
    slot: wp.array(dtype=wp.int32),
    targets: wp.array(dtype=Any),
    inv_dt: Any,
    x_start_in: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    """Put kinematic particles (``slot`` ≥ 0: their index in ``targets``) on their targets, with the
    velocity that got them there from ``x_start_in``; the others keep (x_in, v_in). Every output element is
    written once, so the outputs may be the inputs (in place) or fresh arrays (a recorded step)."""
    i = wp.tid()
    k = slot[i]
    if k >= 0:
        x_out[i] = targets[k]
        v_out[i] = (targets[k] - x_start_in[i]) * inv_dt
    else:
        x_out[i] = x_in[i]
        v_out[i] = v_in[i]


#: Per kinematic-index array: the slot map of :func:`apply_kinematic` (particle → index in the targets,
#: −1 for the others), built on first use. Weak keys: a Control's map goes with its indices.
_SLOTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def kinematic_slot(model: Model, indices: wp.array) -> wp.array:
    """Particle → index in the kinematic targets (−1 for the others) [N] int32, as :func:`apply_kinematic`
    reads it, for the Control's ``indices`` [K] (built once per indices array)."""
    slot = _SLOTS.get(indices)
    if slot is None or slot.shape[0] != model.particle_count:
        slot = wp.full(model.particle_count, -1, dtype=wp.int32, device=model.device)
        wp.launch(_kinematic_slots, indices.shape[0], [indices, slot], device=model.device)
        _SLOTS[indices] = slot
    return slot


@wp.func
def drag_force(target: Any, stiffness: Any, max_force: Any, x: Any):
    """The drag handle's force [N]: a zero-length spring k (target − x) from the particle to the cursor,
    its magnitude capped at ``max_force`` [N] (beyond |target − x| = max_force / k it pulls with max_force:
    the force of the energy k r²/2 inside that radius r, max_force (|d| − r/2) outside)."""
    f = stiffness * (target - x)
    n = wp.length(f)
    if n > max_force:
        f = f * (max_force / n)
    return f


@wp.func
def drag_hessian(target: Any, stiffness: Any, max_force: Any, x: Any):
    """The Hessian [N/m] of the capped drag energy (``drag_force``'s): k I inside the radius, and outside
    (max_force / |d|)(I − n nᵀ), the capped spring's transverse stiffness (positive semi-definite)."""
    d = x - target
    dist = wp.length(d)
    eye = wp.identity(n=3, dtype=type(stiffness))
    if stiffness * dist <= max_force:
        return stiffness * eye
    u = d / dist
    return (max_force / dist) * (eye - wp.outer(u, u))


@wp.kernel
def add_drag_force(
    index: int,
    target: Any,
    stiffness: Any,
    max_force: Any,
    x_in: wp.array(dtype=Any),
    f_io: wp.array(dtype=Any),
):
    """The drag handle (pulls without a jump, with a bounded force), added to the force of the particle it
    holds."""
    f_io[index] = f_io[index] + drag_force(target, stiffness, max_force, x_in[index])


class ContactHandler(Protocol):
    """A post-step contact handler (``pl.collision.Colliders``, ``SelfCollision``, a user's object): corrects
    ``state_out`` in place; one with ``apply_out(model, x_in, v_in, x_out, v_out, dt)`` too can be recorded
    out of place."""

    def apply(self, model: Model, state_in: State, state_out: State, dt: float) -> None: ...


#: One stage of a step after integration: reads (x_in, v_in), writes (x_out, v_out).
Stage = Callable[[wp.array, wp.array, wp.array, wp.array], None]


def _contact_stage(
    c: ContactHandler, m: Model, state_in: State, state_out: State, dt: float, shift_dt: float
) -> Stage:
    """A contact handler as a post-step stage ``(x, v, x_out, v_out)``: out of place through its
    ``apply_out`` when it has one (given ``shift_dt`` [s], ∂x₁/∂v₁ of the step, the Δt its friction moves
    positions by), else in place on ``state_out`` (which is (x, v) on the gradient-free path)."""
    apply_out = getattr(c, "apply_out", None)
    if callable(apply_out):
        # Handlers that declare ``takes_step`` (Colliders) also get the step's start and length: moving
        # colliders advance by Δt, and compliant contact integrates its force over Δt (its damper acts on
        # particles in contact at x₀).
        step = {"x_start": state_in.particle_q, "step_dt": dt} if getattr(c, "takes_step", False) else {}

        def out_of_place(x: wp.array, v: wp.array, xo: wp.array, vo: wp.array) -> None:
            apply_out(m, x, v, xo, vo, shift_dt, **step)

        return out_of_place

    def in_place(x: wp.array, v: wp.array, xo: wp.array, vo: wp.array) -> None:
        c.apply(m, state_in, state_out, dt)

    return in_place


def finish_step(
    model: Model,
    control: Control | None,
    state_in: State,
    state_out: State,
    dt: float,
    integrate: Callable[[wp.array, wp.array], None],
    *,
    ground: wp.array | None = None,
    collisions: Sequence[Any] = (),
    ground_penalty: float | None = None,
    ground_damping: float = 0.0,
    contact: tuple[float, float, float] = (1.0, 1.0, 1.0),
) -> None:
    """A force-based step: integrate, then kinematic targets, the ground response, each contact handler.

    One path whether or not a ``wp.Tape`` records the step. Each stage reads the state the one before it
    wrote and writes its outputs, which this function chooses: with gradients off, ``state_out``'s arrays
    (every stage updates them in place); on a ``requires_grad`` model, fresh arrays for every stage but the
    last, which writes ``state_out``'s, so that no array is written after a recorded launch read it (what
    the tape needs to replay the step). The stages launch the same kernels either way.

    Args:
        model: the Model.
        control: kinematic targets (the drag handle is the integrator's force); None: none.
        state_in: the state at the start of the step (read only).
        state_out: the state written.
        dt: the step [s].
        integrate: ``integrate(x_out, v_out)`` writes the integrated positions [m] and velocities [m/s].
        ground: [friction μ, restitution e] of the ground response
            (:func:`pliant.collision.ground_coefficients`); None: no ground contact.
        collisions: contact handlers, run in order: ``apply_out(model, x_in, v_in, x_out, v_out, dt)`` where
            they have it (:class:`pliant.collision.Colliders`), else ``apply(model, state_in, state_out,
            dt)`` (in place; callers refuse those on recorded steps).
        ground_penalty: κ [1/s²] of a :class:`~pliant.energies.GroundPenalty` the step already minimised;
            the ground response is then friction for the penalty's impulse instead of a projection (without
            one, a compliant ``model.ground`` is a spring–damper after the step,
            :func:`pliant.collision.ground_response`).
        ground_damping: b [1/s] of that penalty's damper (compliant contact's).
        contact: (θ, w, β) [-] of the step (an integrator's ``contact_point``, ``contact_impulse``,
            ``contact_shift``): its forces act at x₀ + θ(x₁ − x₀) over wΔt, and friction's velocity change
            Δv_t moves a particle by βΔt Δv_t (ground and ``apply_out`` handlers). Backward Euler's
            (1, 1, 1) stands for the explicit steps too.
    """
    m = model
    stages: list[Stage] = []
    if control is not None and control.kinematic_indices.shape[0]:
        slot = kinematic_slot(m, control.kinematic_indices)
        targets, inv_dt = control.kinematic_targets, m.s(1.0 / dt)

        def kinematic(x: wp.array, v: wp.array, xo: wp.array, vo: wp.array) -> None:
            args = [slot, targets, inv_dt, state_in.particle_q, x, v, xo, vo]
            launch(apply_kinematic, m.particle_count, args, device=m.device)

        stages.append(kinematic)
    point, impulse, shift = contact
    if ground is not None:
        stages.append(
            lambda x, v, xo, vo: respond_to_ground(
                m,
                ground,
                dt,
                x,
                v,
                xo,
                vo,
                penalty=ground_penalty,
                penalty_damping=ground_damping,
                x_start=state_in.particle_q,
                point=point,
                impulse=impulse,
                shift=shift,
            )
        )
    for c in collisions:
        stages.append(_contact_stage(c, m, state_in, state_out, dt, shift * dt))
    recorded = grad_enabled(m)

    def outputs(last: bool) -> tuple[wp.array, wp.array]:
        if recorded and not last:
            return fresh(m), fresh(m)
        return state_out.particle_q, state_out.particle_qd

    x, v = outputs(not stages)
    integrate(x, v)
    for k, stage in enumerate(stages):
        xo, vo = outputs(k == len(stages) - 1)
        stage(x, v, xo, vo)
        x, v = xo, vo


def check_collisions(collisions: Sequence[Any]) -> list[ContactHandler]:
    """The handlers as a list, each checked for ``apply(model, state_in, state_out, dt)``."""
    out = list(collisions)
    for c in out:
        if not callable(getattr(c, "apply", None)):
            raise TypeError(
                f"collisions must have apply(model, state_in, state_out, dt), got {type(c).__name__}"
            )
    return out
