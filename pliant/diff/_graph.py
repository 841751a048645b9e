"""Replaying a whole differentiable rollout — forward under the tape, the losses and ``tape.backward()`` —
as one captured Warp graph (a CUDA graph; Warp's CPU graph from Warp 1.19).

A gradient loop calls :func:`pliant.diff.rollout` again and again with the same model, solver and loss,
changing parameter values in place (``array.assign``). Each call records thousands of launches on a tape and
launches their adjoints one by one from Python. Captured once, the forward launches, the seeds, the adjoint
launches, the gradient zeroing and the copies of the per-segment results replay without Python; the host
reads (loss, gradients) happen after the replay, in the direct run's order, so the returned numbers are the
direct run's bit for bit.

What a capture bakes in, and the answers (as for :mod:`pliant.sim._graph`, whose ``fingerprint`` is used):

* **array addresses**: the arrays a rollout allocates (the per-substep States, the tape's gradient
  buffers, the losses) are allocated during the capture and kept by the graph, so every replay writes the
  same ones; the caller's ``state0`` and ``control`` arrays are part of the key.
* **Python values**: the solver's and the control's scalars and array addresses (``fingerprint``), the
  rollout's arguments (frames, Δt, substeps, checkpointing, parameters), the *identity* of the callbacks
  (``loss_fn``, ``frame_loss``, ``control_fn``) and what their closures and named globals hold
  (:func:`callback_values`: a target rebound to a new array is a new key). A callback that launches other
  kernels or passes other Python values on a later call in any other way must be a new function; the same
  rule the backward pass already imposes on ``control_fn`` (it is re-run).
* **host work**: an implicit step minimises on the host and its adjoint is a host solve recorded as a Python
  callback on the tape (``wp.Tape.record_func``); neither can be replayed. :func:`tape_graph_blocker` names
  such solvers before capturing, a tape holding Python callbacks is refused after capturing, and the call
  that captures also runs directly and compares: a replay that differs from the direct run by a single bit
  (a host read hidden in a callback) turns graphs off for that key. Each reason is reported once.
"""

from __future__ import annotations

import logging
import os
import types
import warnings
import weakref
from collections.abc import Callable, Hashable
from typing import TYPE_CHECKING, Any, Protocol, TypeVar, cast

import warp as wp

from ..sim import fingerprint

if TYPE_CHECKING:
    from ..model import Control, State
    from ..solvers import Solver


class _DevicePass(Protocol):
    """What a rollout's device pass returns for the host to read: at least the names of the Python callbacks
    found on its tapes (:func:`tape_callbacks`)."""

    callbacks: list[str]


#: The rollout's own device-pass result type.
R = TypeVar("R", bound=_DevicePass)

_LOG = logging.getLogger("pliant")
#: Graphs kept per solver (each holds one rollout's intermediate arrays).
_MAX_GRAPHS = 2
#: Keys seen once and not yet captured, per solver.
_MAX_WARM = 8
#: Attributes a recorded step replaces with a fresh array every step and reads only after writing it (the
#: XPBD multipliers λ: ``Constraint.begin_step`` under a tape): a pass leaves a new address there, which must
#: not make the next call a new key.
_STEP_OUTPUTS = ("lam",)
#: Reasons already reported in this process.
_REPORTED: set[str] = set()


def graphs_enabled(graph: bool | None) -> bool:
    """Whether a rollout may be captured: ``graph`` is not False and ``PLIANT_GRAPH=0`` (the Simulator's
    environment switch) is not set."""
    return graph is not False and os.environ.get("PLIANT_GRAPH", "1") != "0"


def tape_graph_blocker(solver: Solver) -> str | None:
    """Why a taped rollout of ``solver`` cannot be replayed as a graph, or None when it can.

    A solver may answer itself through a ``tape_graph_blocker()`` method. Otherwise: an implicit integrator
    minimises on the host and back-propagates through a host solve; a contact handler's own
    ``graph_blocker`` is asked as the Simulator asks it. Everything else is tried, and checked on the
    capturing call (see the module).
    """
    own = getattr(solver, "tape_graph_blocker", None)
    if callable(own):
        return own()
    integrator = getattr(solver, "integrator", None)
    if integrator is not None and not getattr(integrator, "explicit", True):
        return (
            f"{integrator.name} is differentiated by the implicit-function adjoint, a linear solve run from "
            "Python in the backward pass (a wp.Tape.record_func callback)"
        )
    collisions = getattr(solver, "_collisions_blocker", None)
    return collisions() if callable(collisions) else None


def report_once(reason: str, device: wp.DeviceLike) -> None:
    """Say once per process that rollouts run launch by launch, and why: a RuntimeWarning on CUDA (where a
    graph is the expected path), a log line on ``logging.getLogger("pliant")`` (INFO) on the CPU."""
    if reason in _REPORTED:
        return
    _REPORTED.add(reason)
    msg = f"pliant: pl.diff rollouts run launch by launch (no graph): {reason}"
    if wp.get_device(device).is_cuda:
        warnings.warn(msg, RuntimeWarning, stacklevel=3)
    else:
        _LOG.info(msg)


def tape_callbacks(tape: wp.Tape) -> list[str]:
    """Names of the Python callbacks recorded on ``tape`` (``wp.Tape.record_func``), which a graph cannot
    replay (read before ``tape.reset()`` clears them)."""
    return [
        getattr(f, "__qualname__", type(f).__name__)
        for f in tape.launches
        # Warp's own (the adjoint of a recorded wp.copy) and pliant's marked ones (pliant._warp.graph_safe)
        # only launch Warp operations, which are captured.
        if callable(f)
        and not getattr(f, "__module__", "").startswith("warp.")
        and not getattr(f, "graph_safe", False)
    ]


class _Entry:
    """One key's state: the callbacks it was made with (weakly), and its graph once captured."""

    def __init__(self, callbacks: tuple) -> None:
        self.refs = tuple(None if f is None else _ref(f) for f in callbacks)
        self.graph: wp.Graph | None = None
        self.result: object = None
        self.blocked: str | None = None

    def matches(self, callbacks: tuple) -> bool:
        # A freed callback's id() can be reused by a new one: the key alone is not enough.
        return all(
            (r is None and f is None) or (r is not None and r() is f)
            for r, f in zip(self.refs, callbacks, strict=True)
        )


def _ref(f: Callable) -> Callable[[], Any]:
    try:
        return weakref.ref(f)
    except TypeError:  # not weakly referenceable (a builtin): held strongly
        return lambda: f


class RolloutGraphs:
    """The captured rollouts of one solver: ``run(key, callbacks, device_pass, device)``.

    The first call under a key runs ``device_pass(capturing=False)`` directly; the second captures it, replays
    it and checks the replay against a direct run; later calls replay. ``device_pass`` launches the whole
    rollout and returns what the host reads afterwards.
    """

    def __init__(self, name: str = "") -> None:
        self.name = name  # the solver's class, in the reports
        self._entries: dict[Hashable, _Entry] = {}
        #: Rollouts captured, replayed, and run directly.
        self.captures = 0
        self.replays = 0
        self.direct = 0
        #: Graphs kept (each holds one rollout's intermediate arrays). A caller that cycles through a known
        #: set of keys (the fit's gradient stage: one per horizon shape) raises it to that set's size, or
        #: every key's graph would be evicted before its next call and captured again.
        self.max_graphs = _MAX_GRAPHS
        #: Why the last rollout ran directly (None: it was replayed, or it was a key's first call).
        self.reason: str | None = None
        #: Whether the last rollout was replayed.
        self.last_replayed = False

    def run(
        self,
        key: Hashable,
        callbacks: tuple,
        device_pass: Callable[[], R],
        same: Callable[[R, R], bool],
        device: wp.DeviceLike,
    ) -> R:
        """One rollout: replayed, captured (and checked), or direct. ``same(a, b)``: whether two passes'
        host results are identical."""
        self.last_replayed = False
        entry = self._entries.get(key)
        if entry is not None and not entry.matches(callbacks):
            entry = None
        self.reason = entry.blocked if entry is not None else None
        if entry is None or entry.blocked is not None:
            if entry is None:
                if len(self._entries) >= max(_MAX_WARM, self.max_graphs):
                    self._entries.clear()  # keys that change every call (new closures) must not pile up
                self._entries[key] = _Entry(callbacks)
            return self._direct(device_pass)
        if entry.graph is None:
            try:
                with wp.ScopedCapture(device=device) as cap:
                    captured = device_pass()
            except Exception as exc:  # an older Warp, a host read on CUDA, an allocation without a mempool
                return self._block(
                    entry, f"capture failed ({type(exc).__name__}: {exc})", device, device_pass
                )
            names = captured.callbacks  # what tape_callbacks found on the pass's tapes
            if names:
                why = f"the backward pass runs Python callbacks ({', '.join(sorted(set(names))[:3])})"
                return self._block(entry, why, device, device_pass)
            wp.capture_launch(cap.graph)
            direct = device_pass()
            if not same(captured, direct):
                why = "a replay differed from the direct run (a host read or a changing Python value in the "
                return self._block(entry, why + "step or a callback)", device, None, direct)
            graphs = [e for e in self._entries.values() if e.graph is not None]
            if len(graphs) >= self.max_graphs:
                graphs[0].graph = graphs[0].result = None
            entry.graph, entry.result = cap.graph, captured
            self.captures += 1
            return direct
        wp.capture_launch(entry.graph)
        self.replays += 1
        self.last_replayed = True
        return cast(R, entry.result)  # stored by this key's capture, from the same device_pass

    def _direct(self, device_pass: Callable[[], R]) -> R:
        self.direct += 1
        return device_pass()

    def _block(
        self,
        entry: _Entry,
        why: str,
        device: wp.DeviceLike,
        device_pass: Callable[[], R] | None,
        done: R | None = None,
    ) -> R:
        entry.blocked = self.reason = why
        report_once(f"{self.name}: {why}", device)
        return self._direct(device_pass) if device_pass is not None else cast(R, done)


_GRAPHS: weakref.WeakKeyDictionary[Solver, RolloutGraphs] = weakref.WeakKeyDictionary()


def rollout_graphs(solver: Solver) -> RolloutGraphs:
    """The :class:`RolloutGraphs` of ``solver`` (made on first use, freed with the solver)."""
    g = _GRAPHS.get(solver)
    if g is None:
        g = _GRAPHS[solver] = RolloutGraphs(type(solver).__name__)
    return g


def callback_values(fn: Callable | None) -> tuple:
    """What a callback reads besides its arguments, as far as Python shows it: the values of its closure
    cells and of the module globals its code names (arrays by address, Python scalars and small NumPy
    arrays by value, pliant objects by their attributes; :func:`pliant.sim._graph.fingerprint`). A loss
    whose target array is rebound to a new array between calls is then a new key; helpers it calls are not
    looked into."""
    if fn is None:
        return ()
    cells = [c.cell_contents for c in getattr(fn, "__closure__", None) or () if _filled(c)]
    code, names = getattr(fn, "__code__", None), getattr(fn, "__globals__", {})
    used = [names[n] for n in (code.co_names if code is not None else ()) if n in names]
    return fingerprint(*cells, *used, depth=2)


def _filled(cell: types.CellType) -> bool:
    try:
        cell.cell_contents  # noqa: B018 - an empty cell (a variable assigned later) raises
    except ValueError:
        return False
    return True


def rollout_key(
    solver: Solver, control: Control | None, state0: State | None, callbacks: tuple, args: tuple
) -> Hashable:
    """What a captured rollout bakes in besides the callbacks' identities: the solver's and control's
    scalars and array addresses (:func:`pliant.sim._graph.fingerprint`), what the callbacks read
    (:func:`callback_values`), the initial state's arrays and the arguments."""
    s0 = None if state0 is None else tuple((a.ptr, a.shape) for a in (state0.particle_q, state0.particle_qd))
    fp = tuple(e for e in fingerprint(solver, control) if e[0].rsplit(".", 1)[-1] not in _STEP_OUTPUTS)
    return (fp, s0, tuple(callback_values(f) for f in callbacks), args)
