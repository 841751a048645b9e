"""Evaluating CMA-ES candidates: one candidate's training loss, or a generation's as one batched simulation
(copies of the object). Below both the search (:mod:`._cmaes`) and its worker processes (:mod:`._workers`),
which evaluate the same way."""

from __future__ import annotations

import numpy as np

from ._params import GLOBAL
from ._problem import Problem
from ._reuse import BatchScenes, build_batch

#: Loss given to a candidate whose simulation diverges or cannot be built (CMA-ES needs a finite number).
PENALTY = 1.0e6


def evaluate(problem: Problem, values: dict[str, float]) -> float:
    """Training loss of one candidate (a forward run of the train frames); PENALTY when it diverges."""
    from ..scene import SceneError
    from ..sim import DivergenceError

    try:
        x = problem.simulate(problem.build(values), problem.n_train)
    except (DivergenceError, SceneError, ValueError):
        return PENALTY
    loss = problem.loss(x)
    return loss if np.isfinite(loss) else PENALTY


#: Global parameters that live in the object's own section (material, point-cloud topology): candidates
#: differing only in these can run as copies of the object in one model, stepped by the same launches. A
#: view of the knobs (``Knob.on_object``, pliant/scene/_knobs.py).
OBJECT_PARAMS = frozenset(n for n, k in GLOBAL.items() if k.on_object)


def batchable(problem: Problem) -> bool:
    """Whether a generation can run as one batched simulation (copies of the object, one per candidate):
    one object, only object-level parameters searched, no spring handles or observed controls (they drive
    one object) and no self-collision (it would couple the copies). Copies share the ground and colliders,
    which act per particle, so each copy moves as it would alone (explicit steps: the same arithmetic;
    implicit steps: one Newton solve whose block-diagonal Hessian is converged for every copy at once)."""
    from ..scene import coupled

    cfg = problem.cfg
    return (
        len(cfg.objects) == 1
        and coupled(cfg) is None
        and problem.obs.controls is None
        and all(b.name in OBJECT_PARAMS for b in problem.globals)
    )


def evaluate_batch(
    problem: Problem, candidates: list[dict[str, float]], scenes: BatchScenes | None = None
) -> list[float]:
    """Training losses of several candidates from one simulation holding one copy of the object per
    candidate (see :func:`batchable`); when that simulation diverges or cannot be built, each candidate is
    evaluated alone so that one bad candidate costs only its own PENALTY.

    ``scenes``: the run's batched scenes (:class:`~pliant.fit._reuse.BatchScenes`), which reuse one scene
    and its captured frame graphs across generations where that gives the same numbers; None: a scene is
    built for these candidates.
    """
    from ..scene import SceneError
    from ..sim import DivergenceError

    if len(candidates) < 2:
        return [evaluate(problem, v) for v in candidates]
    try:
        if scenes is None:
            scene, sim = build_batch(problem, candidates), None
        else:
            scene, sim = scenes.get(problem, candidates)
        x = problem.simulate(scene, problem.n_train, sim=sim)
    except (DivergenceError, SceneError, ValueError):
        return [evaluate(problem, v) for v in candidates]
    losses = []
    for o in scene.model.objects:
        f = problem.loss(x[:, o["start"] : o["start"] + o["count"]])
        losses.append(f if np.isfinite(f) else PENALTY)
    return losses
