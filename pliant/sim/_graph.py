"""Replaying a frame's substeps as a Warp graph (CUDA graphs; Warp's CPU graphs from Warp 1.19).

A frame of an explicit solver is hundreds of kernel launches whose Python cost dominates small scenes: on the
CPU the 24² demo cloth spends 58 % of a frame in Python (measured 2.4× faster replayed). Capturing the frame
once and replaying it removes that cost on both devices and, on CUDA, the per-launch latency.

What a graph fixes at capture time, and how this module keeps replays equal to direct steps:

* **array addresses**: every array a launch reads or writes. The states ping-pong, so a graph is kept per
  starting state (with an odd substep count a frame starts in either buffer) and the Python references are
  swapped after a replay exactly as the direct loop swaps them.
* **Python scalars** passed to kernels (Δt, a damping factor, a drag target). :func:`fingerprint` collects
  the solver's and the control's scalars and array addresses; a replay whose fingerprint changed is
  captured again, so changing ``solver.damping_rate`` or replacing a model array between frames takes effect.
* **host work inside a step** (reading a residual, a host solve, a BVH refit) cannot be replayed at all: a
  solver says so through ``Solver.graph_blocker()``, and the frame runs directly.

A replay is bit-for-bit the direct run (``tests/test_graph.py`` checks every built-in scene).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Hashable
from typing import Any

import numpy as np
import warp as wp

_SCALARS = (bool, int, float, str, bytes, type(None), np.generic)
#: Attributes that change from step to step without changing what a step launches (statistics, the last
#: step's outputs, caches of recorded plans): not part of the fingerprint.
_SKIP = (
    "last",
    "stats",
    "_plans",
    "_recording",
    "minimizer_cache",
    "_cache",
    "cg_steps",
    "cg_iterations_total",
)
_MAX_GRAPHS = 4
#: Keys seen once and not yet captured that are remembered (each holds a fingerprint).
_MAX_WARM = 16


#: Exact types that are fingerprint leaves (the common case, checked before the isinstance chain).
_LEAF_TYPES = frozenset({bool, int, float, str, bytes, type(None)})
#: Per attribute name, whether it is skipped; per type, whether its attributes are walked. The walk runs
#: every replayed frame over the same few hundred names and types: the substring tests and module lookups
#: were half its cost (issue #42). Bounded, for dicts whose keys keep changing.
_SKIP_MEMO: dict[str, bool] = {}
_PLIANT_MEMO: dict[type, bool] = {}
_MEMO_MAX = 4096


def _skip(name: str) -> bool:
    hit = _SKIP_MEMO.get(name)
    if hit is None:
        if len(_SKIP_MEMO) >= _MEMO_MAX:
            _SKIP_MEMO.clear()
        hit = _SKIP_MEMO[name] = any(s in name for s in _SKIP)
    return hit


def _walked(t: type) -> bool:
    """Whether objects of type ``t`` have their attributes walked (pliant's own classes)."""
    hit = _PLIANT_MEMO.get(t)
    if hit is None:
        if len(_PLIANT_MEMO) >= _MEMO_MAX:
            _PLIANT_MEMO.clear()
        hit = _PLIANT_MEMO[t] = t.__module__.startswith("pliant")
    return hit


def fingerprint(*roots: Any, depth: int = 4) -> tuple:
    """What a captured graph bakes in: Python scalars and array addresses reachable from ``roots``.

    Walks the attributes of pliant objects (and lists, tuples and string-keyed dicts of them) to ``depth``
    levels, skipping statistics and caches (``_SKIP``). Warp arrays contribute (address, shape), so an
    array replaced by a new one changes the fingerprint while an in-place write (``assign``) does not.

    Args:
        roots: the objects a step reads (the solver and the control).
        depth: how many attribute levels to follow.

    Returns:
        A hashable tuple; equal tuples mean a graph captured under one replays the other's step.
    """
    out: list = []
    seen: set[int] = set()

    def walk(obj: object, path: str, d: int) -> None:
        t = type(obj)
        if t in _LEAF_TYPES:  # never a wp.array: the same entry the chain below gives, sooner
            out.append((path, obj))
        elif isinstance(obj, wp.array):
            out.append((path, obj.ptr, obj.shape))
        elif isinstance(obj, _SCALARS):
            out.append((path, obj))
        elif isinstance(obj, np.ndarray):
            # Small host arrays become kernel scalars (a drag target): their values; large ones (the
            # model's host copies) are never passed to a launch, so their identity is enough.
            out.append((path, obj.shape, obj.tobytes() if obj.size <= 64 else id(obj)))
        elif isinstance(obj, list | tuple):
            for i, x in enumerate(obj):
                walk(x, f"{path}[{i}]", d)
        elif isinstance(obj, dict):
            for k, v in obj.items():
                if isinstance(k, str) and not _skip(k):
                    walk(v, f"{path}.{k}", d)
        elif d > 0 and _walked(t) and id(obj) not in seen:
            seen.add(id(obj))
            for k, v in vars(obj).items() if hasattr(obj, "__dict__") else ():
                if _skip(k):
                    continue
                if type(v) in _LEAF_TYPES:  # most attributes: no call for them
                    out.append((f"{path}.{k}", v))
                else:
                    walk(v, f"{path}.{k}", d - 1)

    for i, r in enumerate(roots):
        walk(r, str(i), depth)
    return tuple(out)


class FrameGraphs:
    """Captures a frame's launches once per (starting state, fingerprint) and replays them.

    ``run(frame_fn, states, key_roots)`` calls ``frame_fn(states)``, which launches one frame's substeps and
    returns the (state_0, state_1) pair as it leaves it. The first frame under a new key runs directly (it
    loads kernel modules and lets solvers allocate their buffers); the next one under the same key is
    captured and replayed, and so is every later one.

    Args:
        device: the Warp device the frame runs on.
    """

    def __init__(self, device: wp.DeviceLike) -> None:
        self.device = wp.get_device(device)
        self._graphs: dict[Hashable, tuple[Any, tuple]] = {}
        self._warm: set[Hashable] = set()
        #: Graphs captured so far (a capture per starting state and per change of the fingerprint).
        self.captures = 0
        #: Frames replayed from a graph.
        self.replays = 0
        #: Why graphs are off for good on this device (a failed capture), else None.
        self.failed: str | None = None

    def clear(self) -> None:
        """Forget every graph (after a change the fingerprint cannot see)."""
        self._graphs.clear()
        self._warm.clear()

    def run(self, frame_fn: Callable[[tuple], tuple], states: tuple, key_roots: tuple) -> tuple:
        """One frame: replayed, captured then replayed, or run directly (see the class). Returns the
        (state_0, state_1) pair after the frame."""
        if self.failed is not None:
            return frame_fn(states)
        key = (id(states[0]), id(states[1]), fingerprint(*key_roots))
        hit = self._graphs.get(key)
        if hit is None:
            if key not in self._warm:
                if len(self._warm) >= _MAX_WARM:
                    self._warm.clear()  # a key that changes every frame (a live drag) must not pile up
                self._warm.add(key)
                return frame_fn(states)
            try:
                with wp.ScopedCapture(device=self.device) as cap:
                    after = frame_fn(states)
            except Exception as exc:  # an older Warp without CPU graphs, or an uncapturable launch
                self.failed = f"graph capture failed on {self.device} ({type(exc).__name__}: {exc})"
                warnings.warn(
                    f"pliant: {self.failed}; frames run launch by launch", RuntimeWarning, stacklevel=3
                )
                return frame_fn(states)
            if len(self._graphs) >= _MAX_GRAPHS:
                self._graphs.clear()
            hit = self._graphs[key] = (cap.graph, after)
            self.captures += 1
        wp.capture_launch(hit[0])
        self.replays += 1
        return hit[1]
