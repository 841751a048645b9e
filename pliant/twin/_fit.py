"""The twin's fit, coarse to fine.

CMA-ES needs dozens of rollouts, and on the CPU a rollout of the twin at the cameras' resolution (MuJoCo's
beam: 2,440 particles, 10,248 tets, 63 training frames) takes about 4 s when its stiffness is near the truth
and much longer when a candidate is far too soft or stiff for the implicit step to converge quickly. So:

1. **coarse**: ``pl.fit.fit`` (CMA-ES over the stiffness and the damping rate, the Chamfer loss on the
   pictures' clouds) on the same kept voxels merged 2 × 2 × 2 (:func:`pliant.geometry.coarsen_voxels`):
   eight times fewer particles, every candidate cheap;
2. **fine**: the twin's own mesh at the coarse values, with a factor on the stiffness and then one on the
   damping rate found by golden-section searches (a handful of rollouts each). Coarse linear tetrahedra
   lock in bending (they are stiffer than the fine ones at the same modulus), so the stiffness does not
   carry over as it is (MuJoCo's beam: × 1.5); the damping rate moves less, but the held-out frames show
   every per cent of it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ..io import Observations

if TYPE_CHECKING:
    from ..scene import SceneConfig

#: The factor ranges the fine stage searches on the coarse stage's values.
SCALE_RANGE = {"E": (1.0 / 3.0, 3.0), "stiffness": (1.0 / 3.0, 3.0), "damping_rate": (0.25, 4.0)}
#: Stiffness parameters (searched first: they set the period, which the damping's search then needs).
STIFFNESS = ("E", "stiffness")
#: Rollouts of each golden-section search of the fine stage (besides its start): the bracket shrinks to
#: 0.618⁶ of the range, ±2.5 % on the stiffness (a period within about 1 %).
SCALE_EVALUATIONS = 8
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass
class ScaleSearch:
    """The fine stage's result.

    Attributes:
        scales: The best factor on each coarse value searched (name → factor).
        values: The fine twin's global values.
        loss: Its training loss.
        history: (name, factor, loss) of every rollout, in order.
    """

    scales: dict[str, float]
    values: dict[str, float]
    loss: float
    history: list[tuple[str, float, float]] = field(default_factory=list)


def refine_on_fine(
    cfg: SceneConfig,
    obs: Observations,
    values: dict[str, float],
    *,
    train_fraction: float,
    evaluations: int = SCALE_EVALUATIONS,
) -> ScaleSearch:
    """The fine stage: a golden-section search for a factor on each coarse value in turn (the stiffness,
    then the damping rate), each minimising the fine scene's training loss (the loss of ``pl.fit.fit``:
    :class:`pliant.fit.Problem`, open loop) with the others held at their best so far.

    Args:
        cfg: The fine twin's scene.
        obs: The observations (clouds).
        values: The coarse stage's global values.
        train_fraction: Fraction of the frames trained on.
        evaluations: Rollouts of each search after the one at its start.

    Returns:
        The factors and the fine values (a factor is 1 when nothing beats the start).
    """
    from ..fit import Problem
    from ..sim import DivergenceError

    problem = Problem(cfg, obs, params=list(values), train_fraction=train_fraction, shooting=0)
    history: list[tuple[str, float, float]] = []

    def loss(trial: dict[str, float]) -> float:
        try:
            return problem.loss(problem.simulate(problem.build(trial), problem.n_train, forced=False))
        except DivergenceError:
            return math.inf

    best = dict(values)
    scales: dict[str, float] = {}
    current = math.nan  # the loss at ``best`` once known: each later search starts from it
    for name in sorted(values, key=lambda n: n not in STIFFNESS):  # the stiffness first: it sets the period
        base = dict(best)

        def scaled(log_f: float, name: str = name, base: dict[str, float] = base) -> float:
            value = loss({**base, name: base[name] * math.exp(log_f)})
            history.append((name, math.exp(log_f), value))
            return value

        lo, hi = SCALE_RANGE.get(name, SCALE_RANGE["damping_rate"])
        log_f, current = golden_section(scaled, math.log(lo), math.log(hi), evaluations, current)
        scales[name] = math.exp(log_f)
        best[name] = base[name] * scales[name]
    return ScaleSearch(scales, best, current, history)


def golden_section(
    f: Callable[[float], float], a: float, b: float, evaluations: int, at_zero: float = math.nan
) -> tuple[float, float]:
    """The best point of a 1-D function on [a, b] (which holds 0) by golden-section search: ``f(0)`` (or
    ``at_zero`` when already known), then ``evaluations`` more evaluations shrinking the bracket by 0.618
    each.

    Args:
        f: The function (a loss of a log factor).
        a: Lower end of the bracket.
        b: Upper end.
        evaluations: Evaluations after the one at 0.
        at_zero: ``f(0)`` if known (NaN: evaluate it).

    Returns:
        (x, f(x)) of the lowest value met, 0 included.
    """
    seen = {0.0: f(0.0) if math.isnan(at_zero) else at_zero}
    c, d = b - _GOLDEN * (b - a), a + _GOLDEN * (b - a)
    seen[c], seen[d] = f(c), f(d)
    for _ in range(max(0, evaluations - 2)):
        if seen[c] <= seen[d]:
            b, d = d, c
            c = b - _GOLDEN * (b - a)
            seen[c] = f(c)
        else:
            a, c = c, d
            d = a + _GOLDEN * (b - a)
            seen[d] = f(d)
    return min(seen.items(), key=lambda kv: kv[1])


__all__ = ["SCALE_EVALUATIONS", "SCALE_RANGE", "ScaleSearch", "golden_section", "refine_on_fine"]
