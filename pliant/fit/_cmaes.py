"""Stage 1: CMA-ES over the global and topology parameters (forward runs only), as PhysTwin's
``cma_optimize_warp.py`` does: the parameters normalised to [0, 1]ᵈ, σ₀ = 1/6, bounds [0, 1], a fixed seed."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np

from ._evaluate import OBJECT_PARAMS, PENALTY, batchable, evaluate, evaluate_batch
from ._params import FitError
from ._problem import Problem
from ._resume import StageHook, rng_state, set_rng_state
from ._reuse import BatchScenes
from ._stage import StageResult
from ._workers import auto_workers, close_workers, cpu_cores, parse_workers, pool_for, unsplittable

if TYPE_CHECKING:
    import cma

_LOG = logging.getLogger("pliant.fit")


def cmaes(
    problem: Problem,
    *,
    generations: int = 20,
    sigma: float = 1.0 / 6.0,
    popsize: int | None = None,
    seed: int = 42,
    start: dict[str, float] | None = None,
    callback: Callable[[int, float], None] | None = None,
    batch: bool = True,
    reuse: bool = True,
    rtol: float = 1e-3,
    patience: int = 5,
    checkpoint: StageHook | None = None,
    workers: int | str = 1,
) -> StageResult:
    """Minimise the training loss over ``problem.globals`` with CMA-ES (the ``cma`` package).

    When :func:`batchable`, a generation's candidates run as one simulation (``batch=True``, the default),
    else one after another; with ``workers`` > 1, dealt out to that many worker processes
    (:mod:`pliant.fit._workers`) with the same losses bit for bit. A one-parameter problem gets a second,
    ignored coordinate, since ``cma`` needs at least two dimensions. Ctrl-C stops the search and returns the
    best candidate so far (``interrupted=True``).

    Stopping: by convergence, when the best loss improved by less than ``rtol`` (relative) over the last
    ``patience`` generations (``stop="converged"``), or when the search's step in the unit box is below
    1e-4 (``"step"``); ``generations`` is a cap (``"cap"``), not a count to run.

    Args:
        problem: The fitting problem.
        generations: Most CMA-ES generations.
        sigma: Initial step size in the normalised [0, 1] box (PhysTwin: 1/6).
        popsize: Candidates per generation (None: at least 10, 16 with a topology parameter; cma's own
            default 4 + ⌊3 ln d⌋ when larger).
        seed: Random seed, >= 1 (PhysTwin: 42; cma would take 0 as a seed from the clock).
        start: Starting values (default: the scene's own).
        callback: ``callback(generation, best_loss)`` after each generation (progress bars).
        batch: Run a generation as one batched simulation when the problem allows it.
        reuse: Run every generation on one batched scene, its candidates' values written into the model's
            arrays in place and its frame graphs kept, where that gives the numbers of a scene built for
            them (:mod:`pliant.fit._reuse`; a log line on ``pliant.fit`` says which); False: build a scene
            per generation.
        rtol: Relative improvement of the best loss over ``patience`` generations below which it stops
            (0: never on this criterion).
        patience: Generations over which the improvement is measured.
        checkpoint: Saves the search after every generation (:mod:`pliant.fit._resume`), and when it holds
            a saved search, continues it: the saved generations are replayed into ``cma`` (no simulation).
        workers: Worker processes that evaluate each generation (1: none, this process alone). ``"auto"``:
            1 on a GPU, else the first generation runs here and is timed (CPU seconds), then
            ``min(CPU cores, popsize)`` when that saves more than a worker's start over the next generations
            (:func:`pliant.fit._workers.auto_workers`). Where splitting a generation would change its losses
            (:func:`pliant.fit._workers.unsplittable`) it stays in one process (a log line on
            ``pliant.fit`` says why). The workers stay with ``problem`` for its next CMA-ES stage;
            ``pliant.fit._workers.close_workers(problem)`` stops them (garbage collection does too). After
            ``pliant.fit._ray.use_ray(problem)``: Ray actors, as many (1 too), or for ``"auto"`` one per CPU
            of the Ray cluster (at most ``popsize``), under the same rules and with the same losses.
    """
    import cma

    bounds = _check_inputs(problem, seed)
    start = {**problem.nominal, **(start or {})}
    x0 = [b.param.to_unit(min(max(start[b.name], b.lo), b.hi), b.lo, b.hi) for b in bounds]
    pad = len(x0) == 1
    if pad:
        x0.append(0.5)
    opts, popsize = _cma_options(problem, x0, pad, seed, generations, popsize)
    decode = partial(_decode, bounds)
    t0 = time.perf_counter()
    batched = batch and batchable(problem)
    scenes = BatchScenes(reuse) if batched else None
    pool, decide = _pool(problem, workers, popsize, batched, reuse)
    es = cma.CMAEvolutionStrategy(x0, sigma, opts)
    saved = None if checkpoint is None else checkpoint.state
    if saved is None:
        best = StageResult(values=dict(start), loss=evaluate(problem, start), evaluations=1)
    else:
        best = _replay(es, saved)
    gens: list[dict] = [] if saved is None else saved["generations"]
    try:
        for gen in range(len(gens), generations):
            if best.stop:  # the saved search had stopped at its last generation
                break
            rng = None if checkpoint is None else rng_state()
            cands = es.ask()
            values = [decode(np.asarray(u)) for u in cands]
            tg = time.process_time()
            losses = (
                _local(problem, values, batched, scenes) if pool is None else pool.evaluate(problem, values)
            )
            if decide:
                decide = False
                n = auto_workers(cpu_cores(), len(values), time.process_time() - tg, generations - gen - 1)
                if n > 1:
                    pool = pool_for(problem, n, batched, reuse)
            best.evaluations += len(values)
            for v, f in zip(values, losses, strict=True):
                if f < best.loss:
                    best.values, best.loss = v, f
            es.tell(cands, losses)
            best.history.append(best.loss)
            best.stop = _stop(best.history, es, patience, rtol)
            if checkpoint is not None:
                cand = [np.asarray(u).tolist() for u in cands]
                gens.append({"rng": rng, "candidates": cand, "losses": [float(f) for f in losses]})
                checkpoint.save({"generations": gens, "best": _best_json(best), "rng": rng_state()}, gen + 1)
            if callback is not None:
                callback(gen + 1, best.loss)
            if best.stop:
                break
        else:
            best.stop = "cap"
    except KeyboardInterrupt:
        close_workers(problem)  # a worker may be mid-generation: it cannot serve the next one
        best.interrupted = True
        best.stop = "interrupted"
    except BaseException:
        close_workers(problem)
        raise
    best.wall_time = time.perf_counter() - t0
    return best


def _check_inputs(problem: Problem, seed: int) -> list:
    """``problem.globals``; FitError when there is none or ``seed`` would let cma seed from the clock."""
    bounds = problem.globals
    if not bounds:
        raise FitError("CMA-ES needs global parameters (--params); none were given")
    if seed == 0 or seed is None:
        # cma reads 0 (and None) as "seed from the clock": a fit must be reproducible.
        raise FitError(
            "--seed: cma takes 0 as 'a random seed from the clock'; give an integer >= 1 (default 42)"
        )
    return bounds


def _cma_options(
    problem: Problem, x0: list[float], pad: bool, seed: int, generations: int, popsize: int | None
) -> tuple[dict[str, Any], int]:
    """cma's options for a search from ``x0`` in the unit box (``pad``: a second, ignored coordinate), and
    the population size (``popsize``, or the default below when None)."""
    bounds = problem.globals
    # The losses of a good fit are tiny (mm² / β): cma's absolute tolerances on f (1e-11) would stop it
    # long before the parameters settle, so it stops on the step size in the unit box only (tolx).
    opts = {
        "bounds": [0.0, 1.0],
        "seed": seed,
        "verbose": -9,
        "maxiter": generations,
        "tolfun": 0.0,
        "tolfunhist": 0.0,
        "tolflatfitness": 10 * generations,
        "tolx": 1e-4,  # in the unit box: 5e-4 relative on a log-scaled parameter spanning ×100
    }
    if popsize is None:
        # cma's default population (4 + ⌊3 ln d⌋: 6 for two parameters) is tuned for smooth functions. Ours
        # are rugged where contact switches (a box dropped on the ground: from 2× E, 6 candidates settled on
        # a local minimum at 2.1× E with noisy tracks; 10 found the truth within 0.01 %), and piecewise
        # constant in topology parameters (a spring appears when the radius passes a pair's distance: 16
        # candidates find the true neighbour count from 1.5× off, 6 stay on the plateau they start on). Both
        # cases are in benchmarks/fit_known_truth.py.
        default = 4 + int(3 * np.log(len(x0)))
        popsize = max(default, 16 if any(b.param.topology for b in bounds) else 10)
    if popsize:
        opts["popsize"] = popsize
    # A whole-number parameter (a neighbour count) makes the loss flat between integers: keep the search's
    # step in it at least a third of one integer, or CMA-ES shrinks onto a plateau and stops exploring.
    ints = [0.3 / max(b.hi - b.lo, 1.0) if b.param.integer else 0.0 for b in bounds] + ([0.0] if pad else [])
    if any(ints):
        opts["minstd"] = ints
    return opts, popsize


def _decode(bounds: list, u: np.ndarray) -> dict[str, float]:
    """The parameter values at the point ``u`` of the unit box (a padded last coordinate ignored)."""
    return {b.name: b.param.from_unit(u[i], b.lo, b.hi) for i, b in enumerate(bounds)}


def _local(
    problem: Problem, vals: list[dict[str, float]], batched: bool, scenes: BatchScenes | None
) -> list[float]:
    """The training losses of ``vals`` in this process: one batched run, or one run each."""
    if batched:
        return evaluate_batch(problem, vals, scenes)
    return [evaluate(problem, v) for v in vals]


def _stop(h: list[float], es: cma.CMAEvolutionStrategy, patience: int, rtol: float) -> str:
    """Why the search stops after this generation (best losses ``h`` so far): "converged", "step" or ""."""
    if len(h) > patience and h[-1 - patience] - h[-1] <= rtol * abs(h[-1 - patience]):
        return "converged"
    if es.stop() and "maxiter" not in es.stop():
        return "step"
    return ""


def _pool(problem: Problem, workers: int | str, popsize: int, batched: bool, reuse: bool) -> tuple[Any, bool]:
    """The worker pool that evaluates the generations (None: this process) and whether the first generation
    is to be timed to decide (``workers="auto"``)."""
    asked = parse_workers(workers)  # None: "auto"
    if asked is not None:
        asked = min(asked, popsize or asked)  # no more processes than candidates
    ray = problem.__dict__.get("_ray")  # pliant.fit._ray.use_ray: Ray actors, even one
    why = None if asked == 1 and ray is None else unsplittable(problem, batched)
    if why is not None:
        _LOG.info(
            "CMA-ES: one process (workers=%s asked%s): %s", workers, "" if ray is None else ", Ray", why
        )
    elif ray is not None:
        from ._ray import actor_count

        return pool_for(problem, actor_count(asked, popsize, ray.address), batched, reuse), False
    pool = None
    if why is None and asked is not None and asked > 1:
        pool = pool_for(problem, asked, batched, reuse)
    elif why is None and asked is None:  # "auto": a pool a previous stage of this problem started
        held = problem.__dict__.get("_worker_pool")
        pool = held if held is not None and (held.batched, held.reuse) == (batched, reuse) else None
    decide = why is None and asked is None and pool is None
    return pool, decide


def _best_json(best: StageResult) -> dict:
    return {
        "values": {k: float(v) for k, v in best.values.items()},
        "loss": float(best.loss),
        "evaluations": best.evaluations,
        "history": [float(v) for v in best.history],
        "stop": best.stop,
    }


def _replay(es: Any, saved: dict) -> StageResult:
    """Bring ``es`` (a fresh ``cma.CMAEvolutionStrategy``) to the state of a checkpoint's search: each saved
    generation's ask (from its generator state; the candidates must come out bit for bit) and tell (its
    saved losses); then the best candidate and the generator state as saved."""
    for i, g in enumerate(saved["generations"]):
        set_rng_state(g["rng"])
        cands = es.ask()
        if len(cands) != len(g["candidates"]) or not all(
            np.array_equal(np.asarray(u), np.asarray(c)) for u, c in zip(cands, g["candidates"], strict=False)
        ):
            raise FitError(
                f"the checkpoint's CMA-ES generation {i + 1} does not replay (another version of cma?); run "
                "without --resume to start over"
            )
        es.tell(cands, [float(f) for f in g["losses"]])
    set_rng_state(saved["rng"])
    b = saved["best"]
    return StageResult(
        values={k: float(v) for k, v in b["values"].items()},
        loss=float(b["loss"]),
        history=[float(v) for v in b["history"]],
        evaluations=int(b["evaluations"]),
        stop=str(b["stop"]),
    )


__all__ = [
    "OBJECT_PARAMS",
    "PENALTY",
    "StageResult",
    "batchable",
    "close_workers",
    "cmaes",
    "evaluate",
    "evaluate_batch",
]
