"""Differentiable rollouts: loss and gradients w.r.t. named parameters, with frame-wise checkpointing."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from .._warp import GradientError
from ..model import Control, Model, Parameter, RegistryView, State, registry
from ..solvers import FrameStep
from . import _graph

if TYPE_CHECKING:
    from ..solvers import Solver


#: Parameter name → ``get(model, solver, state0, control)`` returning its array (or (array, component) for a
#: scalar held in a shared array): every differentiable parameter the registry declares
#: (:mod:`pliant.model._parameters`; each energy, constraint, collider and solver declares its own). Values
#: are per element: per spring, per tet, per particle, per constraint, per collider.
def parameters() -> dict[str, tuple[Parameter, tuple[type, ...]]]:
    """The whole parameter registry (:mod:`pliant.model._parameters`): name → (declaration, the classes
    that declare it), after importing every package whose classes declare parameters."""
    from .. import collision, constraints, energies, solvers  # noqa: F401  (their classes register)

    return registry()


PARAMETERS: Mapping[str, Callable[[Model, Any, State, Control | None], Any]] = RegistryView(
    lambda p: p.differentiable, lambda p: p.getter(), parameters
)


@dataclass
class RolloutResult:
    """What :func:`rollout` returns.

    Attributes:
        loss: the scalar loss of the final state.
        grads: ∂loss/∂parameter for each requested name, shaped like the parameter (NumPy, float64).
        state: the final State.
        replayed: the rollout was replayed from a captured graph (:mod:`pliant.diff._graph`).
        graph_reason: why it ran launch by launch, when a reason is known (None: replayed, or the first
            call with these arguments, which always runs directly).
    """

    loss: float
    grads: dict[str, np.ndarray] = field(default_factory=dict)
    state: State | None = None
    replayed: bool = False
    graph_reason: str | None = None


def _resolve(names: Sequence[str], model: Model, solver: Solver, state0: State, control: Control | None):
    table = dict(PARAMETERS)
    out = {}
    for name in names:
        if name not in table:
            raise GradientError(
                f"unknown or non-differentiable parameter {name!r}; differentiable: {sorted(table)}"
            )
        out[name] = table[name](model, solver, state0, control)
    return out


def _state_health(state: State, max_speed: float) -> tuple[str, float] | None:
    """(quantity, value) if ``state`` is non-finite or a particle is faster than ``max_speed``, else None."""
    q, v = state.particle_q.numpy(), state.particle_qd.numpy()
    bad = int(np.count_nonzero(~np.all(np.isfinite(q), axis=-1) | ~np.all(np.isfinite(v), axis=-1)))
    if bad:
        return "non-finite positions/velocities in particles:", bad
    speed = float(np.sqrt(np.max(np.sum(np.asarray(v, np.float64) ** 2, axis=-1), initial=0.0)))
    return ("max speed (m/s)", speed) if speed > max_speed else None


def check_rollout(
    loss: float,
    grads: dict[str, np.ndarray],
    final: State,
    *,
    solver: Solver,
    dt: float,
    substeps: int,
    frames: int,
    states: Callable[[], Iterable[tuple[int, State]]] | None = None,
    max_speed: float = 1.0e3,
) -> None:
    """Refuse a rollout that blew up instead of returning its loss and gradients (an explicit step above its
    stability limit gives a finite but meaningless loss such as 6e47 long before it overflows).

    Checks, in this order: the final state is finite and no particle is faster than ``max_speed``; the
    loss is finite; every gradient is finite. One host read of the final state; the frames are searched only
    when something failed.

    Args:
        loss: the rollout's loss value.
        grads: the gradients by parameter name.
        final: the last State of the rollout.
        solver: the solver that stepped (for the advice: an implicit integrator for an explicit one).
        dt: the solver step [s].
        substeps: solver steps per frame.
        frames: frames in the rollout.
        states: yields (frame, State) in frame order, to name the first frame that blew up (default: the
            last frame is named).
        max_speed: a particle faster than this [m/s] counts as diverged (as ``Simulator(max_speed=)``).

    Raises:
        pliant.sim.DivergenceError: naming the first diverged frame (or the backward pass's non-finite
            gradient), the quantity and the stability advice.
        ValueError: a non-finite loss from finite states (``loss_fn`` reads a NaN or divides by zero).
    """
    from ..sim import DivergenceError, stability_advice

    advice = stability_advice(solver, dt, substeps)
    health = _state_health(final, max_speed)
    if health is not None:
        frame = frames
        for k, st in states() if states is not None else ():
            found = _state_health(st, max_speed)
            if found is not None:
                frame, health = k, found
                break
        raise DivergenceError(
            frame, health[0], health[1], f"the loss and gradients are meaningless; {advice}"
        )
    if not np.isfinite(loss):
        raise ValueError(
            f"pl.diff.rollout: loss_fn returned {loss} from a finite final state; check it for a division by "
            "zero or NaN inputs (unseen points)"
        )
    for name, g in grads.items():
        bad = int(np.count_nonzero(~np.isfinite(g)))
        if bad:
            raise DivergenceError(
                frames,
                f"non-finite gradient of {name!r} (entries):",
                bad,
                "the backward pass blew up although the forward run is finite (an unstable adjoint, or a "
                f"switch such as a contact exactly at a particle); {advice}",
            )


class _Pass:
    """What one rollout's device work leaves for the host to read (pliant.diff._graph replays it)."""

    def __init__(self, entries: dict, arrays: dict[int, wp.array], checkpoints: list[State]) -> None:
        self.entries, self.arrays, self.checkpoints = entries, arrays, checkpoints
        self.losses: list[wp.array] = []  # the segments' loss arrays, in the order they are summed
        self.segment_grads: list[dict[int, wp.array]] = []  # each segment's parameter gradients
        self.callbacks: list[str] = []  # Python callbacks the tapes held (a graph cannot replay them)
        self.final: State = checkpoints[0]
        self.adj: tuple[wp.array, wp.array] | None = None

    def collect(self, model: Model) -> tuple[float, dict[str, np.ndarray]]:
        """(loss, gradients by parameter name), read and summed on the host in the segments' order."""
        loss = 0.0
        for x in self.losses:
            loss += float(x.numpy()[0])
        totals = {k: np.zeros_like(a.grad.numpy(), dtype=np.float64) for k, a in self.arrays.items()}
        for seg in self.segment_grads:
            for k, snapshot in seg.items():
                totals[k] += snapshot.numpy()
        assert self.adj is not None
        start = self.checkpoints[0]
        grads: dict[str, np.ndarray] = {}
        for name, (a, comp) in self.entries.items():
            if a is start.particle_q:
                g = self.adj[0].numpy().astype(np.float64)
            elif a is start.particle_qd:
                g = self.adj[1].numpy().astype(np.float64)
            else:
                g = totals[id(a)]
            if name == "particle_mass":
                inv = model.particle_inv_mass.numpy().astype(np.float64)
                g = g - np.where(inv > 0, totals[id(model.particle_inv_mass)] * inv * inv, 0.0)
            grads[name] = np.array(g[comp]) if comp is not None else g
        return loss, grads

    @staticmethod
    def same(a: _Pass, b: _Pass, model: Model) -> bool:
        """Whether two passes' loss, gradients and end state agree: bit for bit on the CPU (kernels run
        serially); on CUDA, where atomics sum in any order, within 1e-6 (float64) or 1e-3 (float32) of each
        array's largest entry (a stale host read differs by far more)."""
        (la, ga), (lb, gb) = a.collect(model), b.collect(model)
        pairs = [(np.float64(la), np.float64(lb))] + [(ga[k], gb[k]) for k in ga]
        pairs += [
            (x.numpy(), y.numpy())
            for x, y in ((a.final.particle_q, b.final.particle_q), (a.final.particle_qd, b.final.particle_qd))
        ]
        if wp.get_device(model.device).is_cpu:
            return all(x.tobytes() == y.tobytes() for x, y in pairs)
        tol = 1e-6 if model.scalar == wp.float64 else 1e-3
        return all(
            np.allclose(x, y, rtol=0.0, atol=tol * float(np.max(np.abs(y), initial=0.0)), equal_nan=True)
            for x, y in pairs
        )


def _copy_state(state: State) -> State:
    return State(
        wp.clone(state.particle_q, requires_grad=True), wp.clone(state.particle_qd, requires_grad=True)
    )


def _check_differentiable(
    model: Model,
    solver: Solver,
    frames: int,
    substeps: int,
    checkpoint_every: int,
    loss_fn: Callable[[State], wp.array] | None,
    frame_loss: Callable[[int, State, wp.array], None] | None,
) -> None:
    """:func:`rollout`'s checks before any work: a model with gradients, counts >= 1, differentiable contact
    handlers, a multistep integrator on one segment, and a loss."""
    if not model.requires_grad:
        raise GradientError("rollout needs a model finalised with requires_grad=True")
    if frames < 1 or substeps < 1 or checkpoint_every < 1:
        raise ValueError(
            "frames, substeps and checkpoint_every must be >= 1, "
            f"got {frames}, {substeps}, {checkpoint_every}"
        )
    records = getattr(solver, "records_contact_handlers", False)
    for c in getattr(solver, "collisions", None) or ():
        if not (callable(getattr(c, "apply_out", None)) and records):
            # The handler would correct the state in place on the tape (a wrong gradient).
            raise GradientError(
                f"the contact handler {type(c).__name__} (collisions=) of {type(solver).__name__} is not "
                "differentiable: use ForceSolver with pl.collision.Colliders (spheres, boxes, capsules), "
                "the ground plane (model.ground), or finalize with requires_grad=False"
            )
    integrator = getattr(solver, "integrator", None)
    if integrator is not None and getattr(integrator, "multistep", False) and checkpoint_every < frames:
        raise GradientError(
            f"{integrator.name} is a multistep method: its history cannot cross a checkpoint boundary; "
            f"pass checkpoint_every={frames} (one segment, the whole rollout on one tape)"
        )
    if loss_fn is None and frame_loss is None:
        raise ValueError("rollout: give loss_fn (a loss of the final state) and/or frame_loss")


#: One frame range's run: ``run(state, f0, f1, acc)`` steps frames f0..f1 from ``state``, adding each
#: frame's loss into ``acc`` when given, and returns the end state.
_Run = Callable[..., State]


def _device_pass(
    model: Model,
    solver: Solver,
    params: Sequence[str],
    state0: State | None,
    control: Control | None,
    bounds: list[int],
    run: _Run,
    loss_fn: Callable[[State], wp.array] | None,
    frame_loss: Callable[[int, State, wp.array], None] | None,
) -> _Pass:
    """The forward pass (checkpoints at ``bounds``, no tape) and the backward pass segment by segment, last
    first, each re-run from its checkpoint under a tape: device work only (no host read), so that it can be
    captured as one graph (:mod:`pliant.diff._graph`)."""
    # Device work only (no host read), so that it can be captured as one graph (pliant.diff._graph).
    start = _copy_state(model.state() if state0 is None else state0)
    entries = {
        name: e if isinstance(e, tuple) else (e, None)
        for name, e in _resolve(params, model, solver, start, control).items()
    }
    # Arrays whose gradients accumulate over segments (the initial state's come from the adjoint).
    initial = (id(start.particle_q), id(start.particle_qd))
    arrays = {id(a): a for a, _ in entries.values() if id(a) not in initial}
    if "particle_mass" in entries:
        # Built without gradients (constant in most rollouts): switch them on for this one.
        model.particle_mass.requires_grad = True
        model.particle_inv_mass.requires_grad = True
        arrays[id(model.particle_inv_mass)] = model.particle_inv_mass
    for a in arrays.values():
        if a.grad is None:
            raise GradientError(
                "a requested parameter array does not require grad: finalize(requires_grad=True)"
            )
        a.grad.zero_()
    out = _Pass(entries, arrays, [start])
    # Forward without a tape, keeping the checkpoints; the last segment is run once, under the tape below.
    for a, b in zip(bounds[:-2], bounds[1:-1], strict=True):
        out.checkpoints.append(run(out.checkpoints[-1], a, b))
    adj: tuple[wp.array, wp.array] | None = None
    for seg in range(len(bounds) - 2, -1, -1):
        first = out.checkpoints[seg] if seg == 0 else _copy_state(out.checkpoints[seg])
        for a in (first.particle_q, first.particle_qd):
            a.grad.zero_()
        tape = wp.Tape()
        acc = None
        if frame_loss is not None:
            acc = wp.zeros(1, dtype=model.scalar, device=model.device, requires_grad=True)
        with tape:
            last = run(first, bounds[seg], bounds[seg + 1], acc)
            loss = loss_fn(last) if adj is None and loss_fn is not None else None
        # Seeds: 1 for this segment's losses, the adjoint of its last state from the segment after it.
        seeds = {} if acc is None else {acc: wp.ones_like(acc)}
        if loss is not None:
            seeds[loss] = wp.ones_like(loss)
        out.losses += [x for x in (loss, acc) if x is not None]  # read in this order after the pass
        if adj is None:
            out.final = last
        else:
            seeds[last.particle_q], seeds[last.particle_qd] = adj
        tape.backward(grads=seeds)
        adj = (wp.clone(first.particle_q.grad), wp.clone(first.particle_qd.grad))
        out.segment_grads.append({k: wp.clone(a.grad) for k, a in arrays.items()})
        for a in arrays.values():
            a.grad.zero_()
        out.callbacks += _graph.tape_callbacks(tape)
        tape.reset()
    assert adj is not None
    out.adj = adj
    return out


def _frame_states(
    checkpoints: list[State], bounds: list[int], frames: int, max_speed: float, run: _Run
) -> Iterable[tuple[int, State]]:
    """(frame, state) after each frame from the last healthy checkpoint on: for the message of a rollout
    whose end blew up (only then)."""
    # Only when the end blew up: the checkpoints, then frame by frame from the last good one.
    good = 0
    for seg in range(1, len(bounds) - 1):
        if _state_health(checkpoints[seg], max_speed) is not None:
            break
        good = seg
    state = _copy_state(checkpoints[good])
    for k in range(bounds[good] + 1, frames + 1):
        state = run(state, k - 1, k)
        yield k, state


def _passes(
    model: Model,
    solver: Solver,
    control: Control | None,
    state0: State | None,
    callbacks: tuple,
    settings: tuple,
    graph: bool | None,
    device_pass: Callable[[], _Pass],
) -> tuple[_Pass, bool, str | None]:
    """Run ``device_pass`` as a captured graph (replayed when the rollout repeats: same solver, control,
    start, ``callbacks`` and ``settings``) or directly; (its result, whether it was a replay, why no graph
    was used or None)."""
    key = _graph.rollout_key(solver, control, state0, callbacks, settings)
    why = _graph.tape_graph_blocker(solver) if _graph.graphs_enabled(graph) else "graph=False"
    graphs = _graph.rollout_graphs(solver)
    if why is None:
        done = graphs.run(
            key,
            callbacks,
            device_pass,
            lambda a, b: _Pass.same(a, b, model),
            model.device,
        )
        why, replayed = graphs.reason, graphs.last_replayed
    else:
        if why != "graph=False":
            _graph.report_once(f"{type(solver).__name__}: {why}", model.device)
        done, replayed = device_pass(), False
    return done, replayed, why


def _frames_runner(
    frame_step: FrameStep,
    control: Control | None,
    control_fn: Callable[[int, Control], None] | None,
    frame_loss: Callable[[int, State, wp.array], None] | None,
    first_frame: int,
) -> _Run:
    """The rollout's :data:`_Run`: ``control_fn`` before each frame, ``frame_loss`` into ``acc`` after it."""

    def run(state: State, f0: int, f1: int, acc: wp.array | None = None) -> State:
        for f in range(f0, f1):
            if control_fn is not None and control is not None:  # control is made above for a control_fn
                control_fn(first_frame + f, control)
            state, _ = frame_step(state, control)
            if acc is not None and frame_loss is not None:  # acc is only passed with a frame_loss
                frame_loss(first_frame + f + 1, state, acc)
        return state

    return run


def rollout(
    model: Model,
    solver: Solver,
    loss_fn: Callable[[State], wp.array] | None,
    *,
    frames: int,
    dt: float,
    substeps: int = 1,
    params: Sequence[str] = (),
    state0: State | None = None,
    control: Control | None = None,
    checkpoint_every: int = 1,
    max_speed: float = 1.0e3,
    frame_loss: Callable[[int, State, wp.array], None] | None = None,
    control_fn: Callable[[int, Control], None] | None = None,
    first_frame: int = 0,
    reset: bool = True,
    graph: bool | None = None,
) -> RolloutResult:
    """Run ``frames`` × ``substeps`` steps of ``solver`` and return the loss and its gradients.

    Memory: the forward pass keeps one State every ``checkpoint_every`` frames and no tape; the backward
    pass re-runs each segment of frames under a ``wp.Tape`` from its checkpoint and back-propagates the
    adjoint of its last state, so memory grows with frames × state (plus one segment's intermediates),
    not with substeps × kernels. The work is one forward run, one recomputation of all but the last segment
    and one backward pass (``checkpoint_every >= frames``: no recomputation, the whole rollout on one tape).

    Args:
        model: a Model finalised with ``requires_grad=True`` (float64 recommended for gradient checks).
        solver: a differentiable solver on ``model``: ``ForceSolver`` with an explicit integrator or an
            implicit one (BackwardEuler, ImplicitMidpoint, BDF2; Newton or L-BFGS, differentiated by the
            implicit-function-theorem adjoint; BDF2 needs ``checkpoint_every >= frames``),
            ``FastMassSpring(method="symplectic")``, ``XPBD``/``PBD`` with ``schedule="jacobi"``; others
            raise :class:`pliant.diff.GradientError`. ``solver.reset()`` is called first.
        loss_fn: maps the final State to a 1-element Warp array of the model's scalar type holding the loss,
            computed with Warp kernels (so the tape records it); None: the loss is ``frame_loss``'s alone.
        frames: number of frames (checkpoint granularity).
        dt: substep [s].
        substeps: solver steps per frame.
        params: names from :data:`PARAMETERS` whose gradients to return.
        state0: initial State (default ``model.state()``); it is not modified.
        control: optional Control, constant over the rollout (its ``particle_f`` / ``kinematic_targets``
            can be differentiated).
        checkpoint_every: frames per checkpoint segment (1: recompute one frame at a time).
        max_speed: a particle faster than this [m/s] at the end means the rollout diverged (see
            :func:`check_rollout`, which refuses it).
        frame_loss: ``frame_loss(frame, state, out)`` adds the loss of each frame's end ``state`` into the
            1-element ``out`` with Warp kernels (a loss over the whole trajectory, as a fit's); ``frame`` is
            ``first_frame + k`` after the k-th frame. It is called once per frame, under the tape of its
            segment; segments run last first when ``checkpoint_every < frames``, so a term that reads
            earlier frames' states needs ``checkpoint_every >= frames``.
        control_fn: ``control_fn(frame, control)`` before each frame (``frame`` = ``first_frame`` + the
            frames done): controls that move over time (the frames are re-run in the backward pass, so it
            must depend on ``frame`` alone). A Control is made when ``control`` is None.
        first_frame: index of the first frame (passed to ``frame_loss`` and ``control_fn``).
        reset: call ``solver.reset()`` first (False: keep what the solver carries from the previous
            rollout, as a rollout continuing another one does).
        graph: None (default): a rollout repeated with the same model, solver, callbacks and arguments is
            captured as one graph on its second call (checked against a direct run) and replayed from the
            third on, with the same numbers bit for bit (:mod:`pliant.diff._graph`; parameters changed in
            place with ``assign`` take effect). The callbacks must then launch the same kernels with the
            same Python values on every call (pass a new function otherwise). Solvers that work on the host
            (implicit steps) run directly, reported once. False, or ``PLIANT_GRAPH=0`` in the
            environment: always launch by launch.

    Returns:
        :class:`RolloutResult` with ``loss``, ``grads`` (name → array shaped like the parameter) and the
        final ``state``.

    Raises:
        pliant.sim.DivergenceError: the rollout blew up (see :func:`check_rollout`): the message names the
            first diverged frame and what to change.

    Example::

        res = pl.diff.rollout(model, solver, loss, frames=20, dt=1e-3, substeps=5,
                              params=["spring_stiffness", "v0"])
        res.grads["spring_stiffness"]  # ∂loss/∂k per spring
    """
    _check_differentiable(model, solver, frames, substeps, checkpoint_every, loss_fn, frame_loss)
    if control_fn is not None and control is None:
        control = model.control()
    if reset and hasattr(solver, "reset"):
        solver.reset()  # no L-BFGS pairs or BDF2 history from an earlier run
    frame_step = FrameStep(solver, dt, substeps, fresh=True)  # one frame's substeps, fresh states

    run = _frames_runner(frame_step, control, control_fn, frame_loss, first_frame)
    bounds = list(range(0, frames, checkpoint_every)) + [frames]

    def device_pass() -> _Pass:
        return _device_pass(model, solver, params, state0, control, bounds, run, loss_fn, frame_loss)

    callbacks = (loss_fn, frame_loss, control_fn)
    settings = (id(model), frames, dt, substeps, tuple(params), checkpoint_every, first_frame, reset)
    done, replayed, why = _passes(model, solver, control, state0, callbacks, settings, graph, device_pass)
    loss_value, grads = done.collect(model)
    # A replay's arrays are rewritten by the next replay: the caller gets its own copy of the end state.
    final = _copy_state(done.final) if replayed else done.final
    checkpoints = done.checkpoints

    def frame_states() -> Iterable[tuple[int, State]]:
        return _frame_states(checkpoints, bounds, frames, max_speed, run)

    check_rollout(
        loss_value,
        grads,
        final,
        solver=solver,
        dt=dt,
        substeps=substeps,
        frames=frames,
        states=frame_states,
        max_speed=max_speed,
    )
    return RolloutResult(loss_value, grads, final, replayed, why)
