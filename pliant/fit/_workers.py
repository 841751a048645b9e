"""A CMA-ES generation on several CPU cores (issue 42 item 2): worker processes, each holding its own copy of
the fitting problem, evaluate the generation's candidates; the parent deals them out one at a time to
whichever worker is free (a batched generation: one contiguous share per worker) and gathers the losses in
candidate order (:class:`WorkerPool`). The workers are :class:`Evaluator` s behind a :class:`Backend`:
spawned processes here (:class:`Processes`), or Ray actors on a cluster (:mod:`pliant.fit._ray`).

Warp runs a CPU kernel on one thread, so one process evaluates one candidate at a time. A candidate's loss
does not depend on which process evaluates it (a rollout of a scene built for it alone, or one copy in a
batched scene whose steps are explicit: the same arithmetic per copy), so the search, its checkpoint and
``fitted.toml`` are bit for bit those of one process. Where that would not hold, the generation stays in one
process (:func:`unsplittable`):

* a batched generation (``pliant.fit._cmaes.batchable``) of an implicit or XPBD solver: one Newton / L-BFGS
  solve converges every copy at once, so a copy's iterations depend on its neighbours (the losses of a split
  batch differ from the whole one's within the solver's tolerance);
* an image fit (:class:`~pliant.fit._photometric.PhotometricProblem`): its appearance stage changes the
  problem in place after it is built, which a worker could not rebuild;
* a GPU: one device, already parallel.

Workers are started with the ``spawn`` context (Warp's runtime and ``fork`` do not mix), build their problem
once from its constructor's arguments (``Problem.recipe``: the scene config, the raw observations, the
options) and keep it across generations and stages; per generation the parent sends candidate values (and
the multiple-shooting window, which the open-loop stage sets to 0, and the training window, which the
validation gate holds back) and receives losses. They ignore Ctrl-C
(the parent stops them), exit when the parent's end of their pipe closes, and on Linux are sent SIGTERM when
the parent dies (``PR_SET_PDEATHSIG``). A worker's exception comes back as a :class:`FitError` naming it.
"""

from __future__ import annotations

import logging
import os
import time
import traceback
import weakref
from typing import TYPE_CHECKING, Protocol

import numpy as np

from ._params import FitError

if TYPE_CHECKING:
    from collections.abc import Callable
    from multiprocessing.connection import Connection
    from multiprocessing.process import BaseProcess

    from ._problem import Problem

_LOG = logging.getLogger("pliant.fit")

#: CPU seconds for a worker to start: import pliant and Warp, load the kernels from Warp's cache, build its
#: problem (the 117-particle beam on the 2-core box: 1.6-1.9 s of CPU, 3-10 s of wall time under a load of 7;
#: benchmarks/fit_workers.py). CPU seconds, as the first generation is timed, so that the rule does not
#: change with the machine's load. "auto" starts workers only when they save more than this.
WORKER_START_S = 2.5
#: Generations "auto" expects a search to run (it usually converges in 15-30; ``generations`` is a cap).
AUTO_HORIZON = 10


def cpu_cores() -> int:
    """CPU cores this process may run on (its affinity mask, as ``taskset`` sets it; else all)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def parse_workers(workers: int | str) -> int | None:
    """``workers`` as a count (None: ``"auto"``); FitError on anything else."""
    if workers == "auto":
        return None
    if isinstance(workers, str) and workers.isdigit():
        workers = int(workers)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise FitError(f"--workers: expected a number of processes >= 1 or 'auto', got {workers!r}")
    return workers


def unsplittable(problem: Problem, batched: bool) -> str | None:
    """Why this problem's generations stay in one process (see the module), or None when they can split."""
    from ._problem import Problem

    if type(problem) is not Problem:
        return f"a {type(problem).__name__} cannot be rebuilt in a worker (its appearance stage changes it)"
    scene = problem.build(problem.nominal)
    device = problem.device or str(scene.model.device)
    if not device.startswith("cpu"):
        return f"the problem runs on {device}"
    if batched:
        solver = scene.solver
        integrator = getattr(solver, "integrator", None)
        if type(solver).__name__ != "ForceSolver" or not getattr(integrator, "explicit", False):
            return (
                f"its batched generation is one {type(solver).__name__} solve of every candidate, whose "
                "losses would change if split"
            )
    return None


def auto_workers(cores: int, popsize: int, generation_s: float, generations_left: int) -> int:
    """The worker count "auto" takes after a first generation that took ``generation_s`` CPU seconds in one
    process: ``min(cores, popsize)``, or 1 when that saves less than :data:`WORKER_START_S` over the next
    ``min(generations_left, AUTO_HORIZON)`` generations (a generation on n workers takes 1/n of the time).

    Args:
        cores: CPU cores available (:func:`cpu_cores`).
        popsize: Candidates per generation.
        generation_s: CPU seconds of one generation in one process.
        generations_left: Generations the search may still run.
    """
    n = max(1, min(cores, popsize))
    saved = generation_s * min(generations_left, AUTO_HORIZON) * (1.0 - 1.0 / n)
    return n if n > 1 and saved >= WORKER_START_S else 1


def _die_with_parent() -> None:
    """SIGTERM to this process when its parent dies (Linux's PR_SET_PDEATHSIG; elsewhere nothing)."""
    import signal

    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # 1: PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _failure(exc: BaseException) -> tuple:
    return ("error", f"{type(exc).__name__}: {exc}", traceback.format_exc())


class Evaluator:
    """A worker's copy of the problem, built once from ``Problem.recipe``, and its evaluations: the body of
    a worker process (:func:`_serve`) and of a Ray actor (:mod:`pliant.fit._ray`). Its answers are messages:
    ``("ready", pid)``, ``("ok", losses, CPU seconds)`` or ``("error", "Type: message", traceback)``.

    Args:
        recipe: ``Problem.recipe`` (the scene config, the raw observations, the options).
        batched: Evaluate a share as one batched simulation (``pliant.fit._cmaes.batchable``).
        reuse: Reuse the batched scenes across generations (``BatchScenes``).
    """

    def __init__(self, recipe: tuple, batched: bool, reuse: bool) -> None:
        self.batched, self.failed = batched, None
        try:
            from ._problem import Problem
            from ._reuse import BatchScenes

            cfg, obs, kwargs = recipe
            self.problem = Problem(cfg, obs, **kwargs)
            self.scenes = BatchScenes(reuse) if batched else None
        except Exception as exc:  # noqa: BLE001 (sent to the parent, which raises it)
            self.failed = _failure(exc)

    def ready(self) -> tuple:
        """``("ready", pid)``, or the error that stopped the problem's build."""
        return self.failed or ("ready", os.getpid())

    def evaluate(self, shooting: int, n_train: int, values: list[dict[str, float]]) -> tuple:
        """The losses of ``values`` with the parent's shooting window [frames] (the open-loop stage sets it
        to 0) and training window [frames] (the validation gate holds frames back), which the parent's
        stage changes on its problem after the workers built theirs."""
        from ._evaluate import evaluate, evaluate_batch

        cpu = time.process_time()
        try:
            self.problem.shooting, self.problem.n_train = shooting, n_train
            if self.batched:
                losses = evaluate_batch(self.problem, values, self.scenes)
            else:
                losses = [evaluate(self.problem, v) for v in values]
            return ("ok", [float(f) for f in losses], time.process_time() - cpu)
        except Exception as exc:  # noqa: BLE001
            return _failure(exc)


def _serve(conn: Connection, recipe: tuple, batched: bool, reuse: bool) -> None:
    """A worker process's life: build the problem, say ready, then evaluate what the parent sends until it
    says stop or its pipe closes."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle: it stops the workers
    _die_with_parent()
    worker = Evaluator(recipe, batched, reuse)
    conn.send(worker.ready())
    if worker.failed:
        return
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):  # the parent is gone
            return
        if msg[0] == "stop":
            return
        conn.send(worker.evaluate(*msg[1:]))


class Backend(Protocol):
    """Where a :class:`WorkerPool`'s ``n`` :class:`Evaluator` s run: worker processes
    (:class:`Processes`) or Ray actors (:class:`pliant.fit._ray.RayActors`)."""

    #: What one is called in messages ("worker", "Ray actor").
    kind: str

    def submit(self, i: int, task: tuple) -> None:
        """Have worker ``i`` run ``Evaluator.evaluate(*task)`` once it has answered what it was given."""

    def answers(self, busy: list[int]) -> list[tuple[int, tuple]]:
        """Wait until some of the ``busy`` workers answer: their (index, message); FitError when one died."""
        ...

    def close(self) -> None:
        """Stop the workers (at once: one busy with a generation is stopped)."""


class Processes:
    """``n`` worker processes (``spawn``), a pipe each (see the module).

    Args:
        recipe: ``Problem.recipe``.
        n: Worker processes.
        batched: They evaluate their share as one batched simulation.
        reuse: Their batched scenes are reused across generations.
    """

    kind = "worker"

    def __init__(self, recipe: tuple, n: int, batched: bool, reuse: bool) -> None:
        import multiprocessing as mp

        ctx = mp.get_context("spawn")
        self.conns: list[Connection] = []
        self.procs: list[BaseProcess] = []
        for i in range(n):
            parent, child = ctx.Pipe()
            p = ctx.Process(target=_serve, args=(child, recipe, batched, reuse), name=f"pliant-fit-{i + 1}")
            p.daemon = True
            p.start()
            child.close()
            self.conns.append(parent)
            self.procs.append(p)
        self._finalizer = weakref.finalize(self, _stop, self.conns, self.procs)

    def submit(self, i: int, task: tuple) -> None:
        self.conns[i].send(("eval", *task))

    def answers(self, busy: list[int]) -> list[tuple[int, tuple]]:
        from multiprocessing.connection import wait

        by_pipe = {id(self.conns[i]): i for i in busy}
        by_sentinel = {self.procs[i].sentinel: i for i in busy}
        got: dict[int, tuple] = {}
        for ready in wait([self.conns[i] for i in busy] + [self.procs[i].sentinel for i in busy]):
            i = by_sentinel[ready] if isinstance(ready, int) else by_pipe[id(ready)]
            if i in got:
                continue  # its pipe and its sentinel both fired: answered already
            conn, proc = self.conns[i], self.procs[i]
            if not conn.poll():
                proc.join(1.0)
                raise FitError(
                    f"CMA-ES worker {i + 1} of {len(self.procs)} exited (code {proc.exitcode}) before "
                    "answering; run with workers=1 to see the error in this process"
                )
            got[i] = conn.recv()
        return list(got.items())

    def close(self) -> None:
        self._finalizer()


class WorkerPool:
    """``n`` workers for a problem's CMA-ES generations (see the module): worker processes, or Ray actors
    with ``ray``; this process deals the candidates and waits (it uses no CPU meanwhile).

    Args:
        problem: The fitting problem (a :class:`~pliant.fit.Problem` with its ``recipe``).
        n: Workers (>= 2 processes; >= 1 Ray actors).
        batched: Workers evaluate their share as one batched simulation (``pliant.fit._cmaes.batchable``).
        reuse: Their batched scenes are reused across generations (``BatchScenes``).
        ray: Makes the Ray actors (``pliant.fit._ray.RayBackend``, which :func:`pliant.fit._ray.use_ray`
            leaves on the problem: called with the recipe, n, batched, reuse); None: worker processes.
    """

    def __init__(
        self, problem: Problem, n: int, batched: bool, reuse: bool, ray: Callable[..., Backend] | None = None
    ) -> None:
        self.n, self.batched, self.reuse, self.ray = n, batched, reuse, ray
        self.started = time.perf_counter()
        #: Wall seconds from the start to every worker ready (set by the first :meth:`evaluate`).
        self.warmup_s: float | None = None
        self._ready: set[int] = set()
        #: Per generation: the CPU seconds each worker spent on it.
        self.cpu_s: list[list[float]] = []
        if ray is None:
            self.backend: Backend = Processes(problem.recipe, n, batched, reuse)
        else:
            self.backend = ray(problem.recipe, n, batched, reuse)

    def _check(self, i: int, msg: tuple) -> tuple:
        """Worker ``i``'s message ``msg``, once checked: FitError when it failed; a "ready" noted."""
        if msg[0] == "error":
            raise FitError(f"CMA-ES {self.backend.kind} {i + 1} of {self.n} failed: {msg[1]}\n{msg[2]}")
        if msg[0] == "ready":
            self._ready.add(i)
            if len(self._ready) == self.n:
                self.warmup_s = time.perf_counter() - self.started
                what = "worker processes" if self.ray is None else "Ray actors"
                _LOG.info("CMA-ES: %d %s ready in %.1f s", self.n, what, self.warmup_s)
        return msg

    def evaluate(self, problem: Problem, values: list[dict[str, float]]) -> list[float]:
        """Losses of ``values``, in order: one candidate at a time to whichever worker is free (a slower or
        busier one takes fewer); a batched problem's generation in one contiguous share per worker (a batch
        each)."""
        if self.batched:
            tasks = [list(s) for s in np.array_split(np.arange(len(values)), self.n) if s.size]
        else:
            tasks = [[j] for j in range(len(values))]
        losses: list[float] = [0.0] * len(values)
        cpus = [0.0] * self.n
        busy: dict[int, list[int]] = {}
        nxt = 0

        def feed(i: int) -> None:
            nonlocal nxt
            if nxt < len(tasks):
                self.backend.submit(i, (problem.shooting, problem.n_train, [values[j] for j in tasks[nxt]]))
                busy[i] = tasks[nxt]
                nxt += 1

        for i in range(self.n):
            feed(i)
        while busy:
            for i, msg in self.backend.answers(list(busy)):
                if self._check(i, msg)[0] != "ok":
                    continue  # "ready"
                for j, f in zip(busy.pop(i), msg[1], strict=True):
                    losses[j] = f
                cpus[i] += msg[2]
                feed(i)
        self.cpu_s.append(cpus)
        return losses

    def close(self) -> None:
        """Stop the workers (at once: a worker busy with a generation is stopped)."""
        self.backend.close()


def _stop(conns: list[Connection], procs: list[BaseProcess]) -> None:
    for c in conns:
        try:
            c.send(("stop",))
        except (OSError, ValueError):
            pass
    deadline = time.monotonic() + 2.0
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.terminate()
            p.join(1.0)
    for c in conns:
        c.close()


def pool_for(problem: Problem, n: int, batched: bool, reuse: bool) -> WorkerPool:
    """The problem's pool of ``n`` workers (Ray actors after :func:`pliant.fit._ray.use_ray`, else
    processes), kept on the problem for its later CMA-ES stages (the open-loop search after multiple
    shooting) and stopped with it (:func:`close_workers`, or when it is garbage-collected)."""
    ray = problem.__dict__.get("_ray")
    pool = problem.__dict__.get("_worker_pool")
    if pool is not None and (pool.n, pool.batched, pool.reuse, pool.ray) == (n, batched, reuse, ray):
        return pool
    close_workers(problem)
    pool = WorkerPool(problem, n, batched, reuse, ray)
    problem.__dict__["_worker_pool"] = pool
    weakref.finalize(problem, pool.close)
    return pool


def close_workers(problem: Problem) -> None:
    """Stop the problem's workers (processes or Ray actors), if it has any."""
    pool = problem.__dict__.pop("_worker_pool", None)
    if pool is not None:
        pool.close()


__all__ = [
    "AUTO_HORIZON",
    "WORKER_START_S",
    "Backend",
    "Evaluator",
    "Processes",
    "WorkerPool",
    "auto_workers",
    "close_workers",
    "cpu_cores",
    "parse_workers",
    "pool_for",
    "unsplittable",
]
