"""The global stage's validation gate (issue 38, item 1): a fit is never worse than the scene as given on
frames it did not train on without saying so.

The global stages (CMA-ES, its open-loop pass, the image-gradient stage) train on the first frames of the
training window only (:func:`fit_window`, as the per-element stage does); the last ``validation`` fraction
is held back. Then :func:`gate`:

1. measures identifiability at the fitted values (:func:`pliant.fit._identify.identify`);
2. prefers the simpler explanation on a tie: each parameter the data do not constrain goes back to the
   scene's value where the open-loop loss stays within :data:`TIE` of the fitted values', on the validation
   frames and on the frames the search trained on (loosest first);
3. keeps the (simplified) fitted values only if their open-loop rollout predicts the validation frames
   strictly better than the scene's own values do; else the scene's values, and says why.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from ._identify import identify

if TYPE_CHECKING:
    from ._problem import Problem

#: Validation losses within this fraction of the fitted values' are a tie (the simpler explanation wins).
TIE = 0.02


def fit_window(n_train: int, validation: float) -> int:
    """The frames the stages train on (1 … result − 1): all ``n_train`` but the last ``validation`` fraction
    of them, at least 2; all of them when there are fewer than 6 (too few to hold some back)."""
    n_fit = n_train - int(round(validation * (n_train - 1))) if n_train >= 6 else n_train
    return min(max(n_fit, 2), n_train)


@contextlib.contextmanager
def held_back(problem: Problem, frames: int) -> Iterator[None]:
    """``problem``'s training window cut to its first ``frames`` frames while the block runs (what the global
    stages read: their runs and losses end at ``problem.n_train``)."""
    n = problem.n_train
    problem.n_train = frames
    try:
        yield
    finally:
        problem.n_train = n


def scene_values(problem: Problem) -> dict[str, float]:
    """The scene's own values of the global parameters (what ``error_nominal`` measures; the search may
    start elsewhere, e.g. at √(lo·hi) for a damping rate of 0)."""
    return {b.name: b.nominal if b.scene_value is None else float(b.scene_value) for b in problem.globals}


def open_loop_loss(problem: Problem, values: dict[str, float] | None, lo: int, hi: int) -> float:
    """The open-loop loss of global ``values`` on frames ``lo … hi − 1`` (inf when the run diverges); None:
    the scene as given (``problem.build_given``)."""
    return open_loop_losses(problem, values, [(lo, hi)])[0]


def open_loop_losses(
    problem: Problem, values: dict[str, float] | None, windows: list[tuple[int, int]]
) -> list[float]:
    """:func:`open_loop_loss` on each frame window ``(lo, hi)`` of ``windows``, from one run up to the last
    window's end (inf everywhere when it diverges)."""
    from ..sim import DivergenceError

    try:
        scene = problem.build_given() if values is None else problem.build(values)
        x = problem.simulate(scene, max(hi for _, hi in windows), forced=False)
    except DivergenceError:
        return [float("inf")] * len(windows)
    out = [problem.loss(x, lo, hi) for lo, hi in windows]
    return [v if np.isfinite(v) else float("inf") for v in out]


def gate(
    problem: Problem, fitted: dict[str, float], frames: int, *, identifiability: bool = True
) -> tuple[dict[str, float], dict[str, Any], dict[str, Any] | None]:
    """The global values a fit keeps: ``fitted`` (simplified on ties) or the scene's own (module docstring).

    Args:
        problem: The fitting problem (its whole training window: ``problem.n_train``).
        fitted: The global stages' values (name → value).
        frames: The frames they trained on (:func:`fit_window`); frames ``frames … n_train − 1`` validate.
            With none left (``frames == n_train``) the decision is on the whole training window's loss.
        identifiability: Measure it (its report is returned; ties need it).

    Returns:
        (the values kept, the ``global_validation`` report, the ``identifiability`` report or None). The
        first: ``frames`` [lo, hi) compared, ``nominal`` / ``fitted`` their open-loop losses there,
        ``simplified`` the loss after the resets, ``reset`` (name → fitted value) the parameters put back on
        a tie, ``fitted_values`` the stages' values, ``kept`` whether the fitted values were kept, ``why``.
    """
    n = problem.n_train
    nominal = scene_values(problem)
    ident = identify(problem, fitted, frames) if identifiability else None
    lo, hi = (frames, n) if frames < n else (1, n)
    # against the scene as given, also where the search's scene differs from it (a seeded compliant ground)
    v_fit, v_nom = open_loop_loss(problem, fitted, lo, hi), open_loop_loss(problem, None, lo, hi)
    values, v, reset = dict(fitted), v_fit, {}
    if frames < n and ident is not None and "params" in ident:
        # the frames the search trained on as well: a band that is wide with the others re-adjusting does
        # not make a parameter free to drop with them held. On MuJoCo's cloth (tests/data/foreign) the
        # dashpot at the fitted values was "not constrained" and dropping it lowered the 8 validation
        # frames' loss by 7 % but doubled the loss on the 33 frames trained on; the fit written without it
        # predicted the held-out frames at 0.27x nominal, with it 0.23x (mean over a 0.5 % neighbourhood).
        t_fit = open_loop_loss(problem, fitted, 1, frames)
        # The simpler explanation is the mechanism the scene leaves off (a damping, a restitution, the even
        # masses of a blend at 0: a scene value of 0 or none), not the user's guess of a material constant:
        # an E the data cannot pin down is still fitted, not put back.
        off = {b.name for b in problem.globals if not b.scene_value}
        loose = [
            k
            for k, p in ident["params"].items()
            if p["constrained"] is False and fitted[k] != nominal[k] and k in off
        ]
        for name in sorted(loose, key=lambda k: -ident["params"][k]["sigma_unit"]):
            trial = {**values, name: nominal[name]}
            t_trial, v_trial = open_loop_losses(problem, trial, [(1, frames), (lo, hi)])
            if v_trial <= (1.0 + TIE) * v_fit and t_trial <= (1.0 + TIE) * t_fit:
                values, v, reset[name] = trial, v_trial, fitted[name]
    where = f"validation frames {lo}-{hi - 1}" if frames < n else "training frames (no validation frames)"
    kept = v < v_nom
    if kept:
        why = (
            f"the fitted values predict the {where} better than the scene's own (loss {v:.4g} < {v_nom:.4g})"
        )
    else:
        why = (
            f"the fitted values predict the {where} no better than the scene's own (loss {v:.4g} >= "
            f"{v_nom:.4g}): kept the scene's values"
        )
        problem.unseed()  # back to the scene as given (its hard ground, where the fit had made it compliant)
        values, reset = scene_values(problem), {}
    if reset:
        why += (
            f"; {', '.join(reset)} not constrained by the data and a tie on the training and validation "
            f"frames (within {100 * TIE:g} %): back to the scene's value"
        )
    report = {
        "frames": [lo, hi],
        "nominal": v_nom,
        "fitted": v_fit,
        "simplified": v,
        "reset": reset,
        "fitted_values": dict(fitted),
        "kept": kept,
        "why": why,
    }
    return values, report, ident


__all__ = ["TIE", "fit_window", "gate", "held_back", "open_loop_loss", "scene_values"]
