"""One batched scene for every CMA-ES generation (issue 24 item 4): later generations write their candidates'
values into the held model's arrays in place and run its Simulator again from frame 0, which keeps its
captured frame graphs, instead of building a scene, a solver and a Simulator and capturing a graph each time.

That is the run a rebuilt scene makes, bit for bit, only when

* every searched parameter sets one model array per element, to the value itself: what the scene builds
  from the value is then written without building it. The registry (:mod:`pliant.model._parameters`) names
  the arrays (``GlobalParam.drives``); the elements a parameter sets are those of the held scene equal to the
  value it was built with (the bend springs of ``stiffness`` keep theirs). A value the scene derives
  (``Et``: the structural and shear k; ``E``: the Lamé parameters) matches no element, and ν, the topology
  parameters (radius, neighbours) change more than an array: those scenes are rebuilt;
* the solver takes the new arrays in place: ``Solver.refresh_parameters()`` says how each solver does (an
  explicit ForceSolver's energies read them each step; XPBD binds its constraints again into the arrays its
  graphs hold; FastMassSpring packs them again per row) or returns why it cannot (L-BFGS keeps a lagged
  Hessian and its factorisation): that one is rebuilt.

:class:`BatchScenes` decides once per (problem, candidate count), says which in a log line on
``logging.getLogger("pliant.fit")`` and in :attr:`BatchScenes.reason`.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from ._params import GLOBAL, registry_arrays

if TYPE_CHECKING:
    from ..model import Model
    from ..scene import Scene
    from ..sim import Simulator
    from ._problem import Problem

_LOG = logging.getLogger("pliant.fit")


class _Writes:
    """Where each searched parameter goes in a batched model: per (parameter, array) the elements it sets
    and the copy (candidate) each belongs to."""

    def __init__(self, problem: Problem, scene: Scene, built: list[dict[str, float]]) -> None:
        m = scene.model
        starts = np.array([o["start"] for o in m.objects], np.int64)
        self.rows: list[tuple[str, str, wp.array, np.ndarray, np.ndarray]] = []
        #: Why these writes cannot reproduce a rebuild (None: they can).
        self.reason: str | None = None
        from ..diff import parameters as registry

        reg = registry()
        taken: dict[str, np.ndarray] = {}
        for b in problem.globals:
            drives = GLOBAL[b.name].drives
            arrays = registry_arrays(scene, drives)
            if not arrays or any(not k.startswith("model.") for k in arrays):
                self.reason = f"{b.name} is not held in the model's per-element arrays"
                return
            for key, a in arrays.items():
                attr = key.split(".", 1)[1]
                per = next(reg[n][0].per for n in drives if reg[n][0].model_array == attr)
                first = self._first_particle(m, per, a.shape[0])
                copy = np.searchsorted(starts, first, side="right") - 1
                values = np.array([v[b.name] for v in built], dtype=a.numpy().dtype)
                hit = a.numpy() == values[copy]
                if not all(np.any(hit & (copy == w)) for w in range(len(built))):
                    self.reason = f"the scene derives {attr} from {b.name} (no element holds the value)"
                    return
                if attr in taken and np.any(taken[attr] & hit):
                    self.reason = f"two searched parameters set the same elements of {attr}"
                    return
                taken[attr] = taken.get(attr, np.zeros_like(hit)) | hit
                idx = np.flatnonzero(hit)
                self.rows.append((b.name, attr, a, idx, copy[idx]))

    @staticmethod
    def _first_particle(m: Model, per: str, n: int) -> np.ndarray:
        """The first particle of each of ``n`` elements of kind ``per`` (which object owns it)."""
        if per == "particle":
            return np.arange(n)
        return getattr(m, f"{per}_indices").numpy().reshape(n, -1)[:, 0]

    def write(self, candidates: list[dict[str, float]]) -> None:
        """Set every searched parameter's elements to its candidates' values (copy w: candidate w)."""
        for name, _, a, idx, copy in self.rows:
            host = a.numpy()
            values = np.array([v[name] for v in candidates], dtype=host.dtype)
            host[idx] = values[copy]
            a.assign(host)


class BatchScenes:
    """The batched scenes of one CMA-ES run, one per candidate count, each with its Simulator.

    :meth:`get` returns a scene and Simulator holding the candidates, ready for
    ``problem.simulate(scene, ..., sim=sim)``: the held ones with the values written in place when
    reuse is safe (see the module), else a scene built for these candidates (a new Simulator each time).

    Args:
        reuse: False: always build (the path before issue 24 item 4, for comparison).
    """

    def __init__(self, reuse: bool = True) -> None:
        self.reuse = reuse
        self._held: dict[int, tuple[Scene, Simulator, _Writes]] = {}
        #: Why this run's batches are built rather than reused, decided once (None: reused, or undecided).
        self.reason: str | None = None
        #: Scenes built so far, and generations run on a held scene.
        self.built = 0
        self.reused = 0

    def get(self, problem: Problem, candidates: list[dict[str, float]]) -> tuple[Scene, Simulator | None]:
        """(scene, Simulator to restart or None for a new one) for ``candidates`` as copies of the object."""
        n = len(candidates)
        held = self._held.get(n)
        if held is not None:
            scene, sim, writes = held
            writes.write(candidates)
            why = scene.solver.refresh_parameters()
            if why is None:
                self.reused += 1
                return scene, sim
            del self._held[n]
            self._say(why)
        scene = build_batch(problem, candidates)
        self.built += 1
        if not self.reuse:
            self._say("reuse is off")
            return scene, None
        if self.reason is not None:
            return scene, None  # decided already: rebuild
        # The scene was built with these values: refreshing it changes nothing, and says whether it can.
        writes = _Writes(problem, scene, candidates)
        why = writes.reason or scene.solver.refresh_parameters()
        if why is not None:
            self._say(why)
            return scene, None
        sim = problem.simulator(scene)
        self._held[n] = (scene, sim, writes)
        _LOG.info(
            "CMA-ES: one batched scene of %d copies reused across generations (%s; written in place: %s)",
            n,
            type(scene.solver).__name__,
            ", ".join(f"{nm} -> {attr} ({idx.size} of {a.shape[0]})" for nm, attr, a, idx, _ in writes.rows),
        )
        return scene, sim

    def _say(self, why: str) -> None:
        if self.reason is None:
            _LOG.info("CMA-ES: batched scene rebuilt each generation: %s", why)
        self.reason = why


def build_batch(problem: Problem, candidates: list[dict[str, float]]) -> Scene:
    """The scene holding one copy of the problem's object per candidate (copy w: candidate w's values)."""
    from ..scene import build_scene

    cfg = problem.cfg.model_copy(deep=True)
    objects = []
    for w, values in enumerate(candidates):
        obj = problem.config(values).objects[0]
        objects.append(obj.model_copy(update={"name": f"{obj.name or 'object'}_{w}"}))
    cfg.objects = objects
    return build_scene(cfg, device=problem.device, dtype=problem.dtype)


__all__ = ["BatchScenes", "build_batch"]
