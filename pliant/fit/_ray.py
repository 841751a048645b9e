"""CMA-ES generations on Ray actors (issue 42 item 2): the worker pool of :mod:`pliant.fit._workers` with
Ray actors in place of worker processes, on this machine's cores or a cluster's (``pliant fit --ray
[--address ADDR]``, ``pl.fit.fit(ray=True, address=...)``; the optional extra ``pliant[ray]``).

Each actor is an :class:`~pliant.fit._workers.Evaluator` (one CPU each), holding its own problem built
once from ``Problem.recipe``, as a worker process does; :class:`~pliant.fit._workers.WorkerPool` deals the
candidates and gathers the losses in candidate order whichever the backend, so the search, its checkpoint
and ``fitted.toml`` are bit for bit those of one process, under the same rules
(:func:`~pliant.fit._workers.unsplittable`: where a generation would not split, it stays in this process
and Ray is not started). Every node must run the same pliant, Warp and NumPy (a candidate's loss is the
same arithmetic only on the same code).

Ray is started here (``ray.init``, a local cluster or ``address``) unless this process is already
connected, and shut down when the last pool stops if it was started here. The actors belong to this
process's Ray job: Ray stops them when it ends, and :func:`~pliant.fit._workers.close_workers` at once.
"""

from __future__ import annotations

import types
import weakref
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ._params import FitError
from ._workers import Evaluator, close_workers

if TYPE_CHECKING:
    from ._problem import Problem

#: Whether Ray was started here (``ray.init``) and how many pools use it: shut down when the last stops.
_OWNED: dict[str, Any] = {"started": False, "pools": 0}


def require_ray() -> None:
    """FitError naming the pip command when Ray is not installed (before any work)."""
    from .._extras import missing_ray

    why = missing_ray()
    if why:
        raise FitError(why)


def use_ray(problem: Problem, address: str | None = None) -> None:
    """Evaluate ``problem``'s CMA-ES generations on Ray actors from now on (``pl.fit.cmaes``'s ``workers``
    then counts actors; ``"auto"``: one per CPU of the cluster, at most one per candidate).

    Args:
        problem: The fitting problem.
        address: A running Ray cluster's address (``ray.init``'s); None: the cluster this process is
            connected to, else a local one started on this machine's cores.
    """
    require_ray()
    close_workers(problem)  # worker processes a previous stage left on it
    problem.__dict__["_ray"] = RayBackend(address or "")


def _connect(address: str) -> types.ModuleType:
    """Ray, connected to ``address`` (``""``: local) unless this process already is."""
    import ray

    if not ray.is_initialized():
        ray.init(address=address or None, include_dashboard=False, log_to_driver=False)
        _OWNED["started"] = True
    return ray


def _release(pools: int = 1) -> None:
    """``pools`` pools fewer: shut Ray down when it was started here and none is left."""
    _OWNED["pools"] = max(0, _OWNED["pools"] - pools)
    if _OWNED["pools"] == 0 and _OWNED["started"]:
        import ray

        _OWNED["started"] = False
        ray.shutdown()


def actor_count(asked: int | None, popsize: int, address: str) -> int:
    """The Ray actors for generations of ``popsize`` candidates: ``asked``, or (None: ``"auto"``) one per
    CPU of the cluster, at most ``popsize``; connects to Ray. FitError when the cluster has fewer CPUs than
    ``asked`` (the actors, one CPU each, would wait for ever).

    Args:
        asked: Actors asked for (``workers``), None for ``"auto"``.
        popsize: Candidates per generation.
        address: The cluster (``""``: local).
    """
    ray = _connect(address)
    cpus = int(ray.cluster_resources().get("CPU", 0))
    if asked is not None and asked > cpus:
        _release(0)  # started for nothing
        raise FitError(
            f"--workers {asked}: the Ray cluster ({address or 'local'}) has {cpus} CPUs, one per actor; give "
            f"--workers {cpus} or fewer, or auto"
        )
    return max(1, min(asked or cpus, popsize))


@dataclass(frozen=True)
class RayBackend:
    """What :func:`use_ray` leaves on a problem: it makes a :class:`~pliant.fit._workers.WorkerPool`'s Ray
    actors on the cluster at ``address`` (``""``: local). Handed to the pool, so that the pool's module does
    not import this one (which imports it)."""

    address: str

    def __call__(self, recipe: tuple, n: int, batched: bool, reuse: bool) -> RayActors:
        """``n`` actors evaluating ``recipe`` (see :class:`RayActors`)."""
        return RayActors(recipe, n, batched, reuse, self.address)


class RayActors:
    """``n`` Ray actors, each an :class:`~pliant.fit._workers.Evaluator` of ``recipe`` on one CPU: a
    :class:`~pliant.fit._workers.WorkerPool`'s backend (``Backend``).

    Args:
        recipe: ``Problem.recipe`` (sent once to the object store).
        n: Actors.
        batched: They evaluate their share as one batched simulation.
        reuse: Their batched scenes are reused across generations.
        address: The cluster (``""``: local, or the one this process is connected to).
    """

    kind = "Ray actor"

    def __init__(self, recipe: tuple, n: int, batched: bool, reuse: bool, address: str) -> None:
        ray = _connect(address)
        _OWNED["pools"] += 1
        self.actors: list[Any] = []
        self._finalizer = weakref.finalize(self, _stop, self.actors)
        try:
            actor = ray.remote(num_cpus=1)(Evaluator)
            ref = ray.put(recipe)
            self.actors += [actor.remote(ref, batched, reuse) for _ in range(n)]
            # an actor runs its calls in order: its "ready" (or the build's error) answers first
            self.pending: list[list[Any]] = [[a.ready.remote()] for a in self.actors]
        except BaseException:
            self.close()
            raise

    def submit(self, i: int, task: tuple) -> None:
        self.pending[i].append(self.actors[i].evaluate.remote(*task))

    def answers(self, busy: list[int]) -> list[tuple[int, tuple]]:
        import ray

        heads = {self.pending[i][0]: i for i in busy}
        done, _ = ray.wait(list(heads), num_returns=1)
        got = []
        for ref in done:
            i = heads[ref]
            self.pending[i].pop(0)
            try:
                got.append((i, ray.get(ref)))
            except ray.exceptions.RayError as exc:
                why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                raise FitError(f"CMA-ES Ray actor {i + 1} of {len(self.actors)} died: {why}") from None
        return got

    def close(self) -> None:
        """Stop the actors at once (one busy with a generation too); Ray too when started here for them."""
        self._finalizer()


def _stop(actors: list[Any]) -> None:
    """Kill ``actors`` (once: a ``weakref.finalize``), then one pool fewer (:func:`_release`)."""
    try:
        import ray

        if ray.is_initialized():
            for a in actors:
                ray.kill(a)
    except Exception:  # noqa: BLE001 (Ray already shut down at exit: the actors went with it)
        pass
    _release()


__all__ = ["RayActors", "actor_count", "require_ray", "use_ray"]
