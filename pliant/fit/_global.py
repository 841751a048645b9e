"""The global stages of a fit (``pl.fit.fit``): the searches over the global parameters on the training
frames less the validation ones, the validation gate (:mod:`pliant.fit._gate`), and, where the gate keeps the
fitted values, the same searches again on every training frame.

Why the second search: the gate needs frames the search has not seen, but the frames held back for it are
the last of the training window, often the ones that show what the first ones do not. MuJoCo's cube of
tests/data/foreign, thrown and sliding on the ground, predicted its held-out frames at 0.65× the nominal
scene's error from values fitted without them (friction 0.06), and at 0.17× from values fitted on all the
training frames (friction 0.69, another basin: CMA-ES again from the first values with half the step stayed
in theirs). So the gate judges the search; when it passes, the search is run again as it would be without a
gate, on all the training frames from the scene's values, as a model chosen on validation is refitted on
the training and validation data together. That doubles the global stage's cost when it passes and leaves
its values as they were before the gate (same seed, same frames); when it fails, the scene's values are
kept and the second search is not run.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

from ._cmaes import StageResult, cmaes
from ._gate import gate, held_back, open_loop_loss
from ._identify import identify
from ._photometric import PhotometricProblem, refinable, refine_globals

if TYPE_CHECKING:
    from tqdm.auto import tqdm

    from ._problem import Problem
    from ._resume import StageHook

#: A stage run through the checkpoint: ``staged(name, run)`` (:func:`pliant.fit.fit`).
Staged = Callable[[str, Callable[["StageHook"], StageResult]], StageResult]

#: CMA-ES's initial step in the unit box for the open-loop search that follows multiple shooting (half the
#: first stage's 1/6: it starts near the answer).
SIGMA_OPEN_LOOP = 1.0 / 12.0


def _bar(progress: bool, total: int, desc: str) -> tqdm | None:
    if not progress:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="it", leave=False, dynamic_ncols=True)


def _tick(bar: tqdm | None) -> Callable[[int, float], None]:
    def cb(it: int, loss: float) -> None:
        if bar is not None:
            bar.update(1)
            bar.set_postfix_str(f"loss {loss:.4g}")

    return cb


@contextlib.contextmanager
def stage_progress(progress: bool, total: int, desc: str) -> Iterator[Callable[[int, float], None]]:
    """A stage's progress bar (none without ``progress``) as the stage's ``callback``, closed however the
    stage ends (Ctrl-C included)."""
    bar = _bar(progress, total, desc)
    try:
        yield _tick(bar)
    finally:
        if bar is not None:
            bar.close()


def _search(
    problem: Problem,
    staged: Staged,
    stages: dict[str, StageResult],
    *,
    generations: int,
    epochs: int,
    optimizer: str,
    lr: float,
    tol: float,
    seed: int,
    progress: bool,
    workers: int | str = 1,
) -> tuple[dict[str, float], bool]:
    """The searches of :func:`global_stages` (CMA-ES, its open-loop pass after multiple shooting, and from
    images the image-gradient stage); returns (the global values, interrupted)."""
    values, interrupted = problem.nominal, False
    if problem.globals and generations > 0:
        with stage_progress(progress, generations, "fit: CMA-ES") as tick:
            stages["cmaes"] = staged(
                "cmaes",
                lambda hook: cmaes(
                    problem,
                    generations=generations,
                    seed=seed,
                    callback=tick,
                    checkpoint=hook,
                    workers=workers,
                ),
            )
        values = stages["cmaes"].values
        interrupted = stages["cmaes"].interrupted
        if problem.shooting > 0 and not interrupted:
            # Multiple shooting finds the basin of a long motion; what the fit must do is predict it open
            # loop (the held-out frames are): CMA-ES again, open loop, from there with half the step. Its
            # first evaluation is that start, so the open-loop training loss cannot get worse. On MuJoCo's
            # rope the windows' values alone predicted the held-out frames 1.3x worse than the nominal's.
            done = _open_loop(
                problem,
                staged,
                stages,
                "cmaes_open_loop",
                "fit: CMA-ES (open loop)",
                values,
                generations=generations,
                seed=seed,
                progress=progress,
                workers=workers,
            )
            values, interrupted = done.values, done.interrupted
    if isinstance(problem, PhotometricProblem) and epochs > 0 and not interrupted and refinable(problem):
        # From images, stage 2 refines the global values with image gradients through the rollout.
        with stage_progress(progress, epochs, f"fit: {optimizer} (image gradients)") as tick:
            stages["gradient"] = staged(
                "image_gradient",
                lambda hook: refine_globals(
                    problem,
                    values,
                    iterations=epochs,
                    optimizer=optimizer,
                    lr=lr,
                    tol=tol,
                    callback=tick,
                    checkpoint=hook,
                ),
            )
        values, interrupted = stages["gradient"].values, stages["gradient"].interrupted
    return values, interrupted


def _open_loop(
    problem: Problem,
    staged: Staged,
    stages: dict[str, StageResult],
    name: str,
    desc: str,
    start: dict[str, float],
    *,
    generations: int,
    seed: int,
    progress: bool,
    workers: int | str,
) -> StageResult:
    """Stage ``name``: CMA-ES open loop (no multiple-shooting window) from ``start`` with half the first
    stage's step (:data:`SIGMA_OPEN_LOOP`); its first evaluation is that start, so its open-loop training
    loss cannot end worse. Recorded in ``stages`` through ``staged`` (the checkpoint)."""
    window, problem.shooting = problem.shooting, 0
    try:
        with stage_progress(progress, generations, desc) as tick:
            stages[name] = staged(
                name,
                lambda hook: cmaes(
                    problem,
                    generations=generations,
                    seed=seed,
                    start=start,
                    sigma=SIGMA_OPEN_LOOP,
                    callback=tick,
                    checkpoint=hook,
                    workers=workers,
                ),
            )
    finally:
        problem.shooting = window
    return stages[name]


def _refine(
    problem: Problem,
    staged: Staged,
    stages: dict[str, StageResult],
    values: dict[str, float],
    validated: dict[str, Any],
    generations: int,
    seed: int,
    progress: bool,
    workers: int | str,
) -> tuple[dict[str, float], bool]:
    """CMA-ES open loop on all the training frames from the held-back search's ``values`` with a small step
    (its first evaluation is that start, so it cannot end worse): the held-back search found the basin, the
    frames it did not see still move its optimum (on MuJoCo's cloth the damping rate, 0.117 → 0.2 1/s).
    The parameters the gate put back stay out. Returns (the values, interrupted)."""
    searched = problem.globals
    problem.globals = [b for b in searched if b.name not in validated["reset"]]
    try:
        if not problem.globals or generations <= 0:
            return values, False
        result = _open_loop(
            problem,
            staged,
            stages,
            "cmaes_refined_all_frames",
            "fit: CMA-ES (refined on all frames)",
            values,
            generations=generations,
            seed=seed,
            progress=progress,
            workers=workers,
        )
    finally:
        problem.globals = searched
    validated["refit"].append("cmaes_refined_all_frames")
    return {**values, **result.values}, result.interrupted


def global_stages(
    problem: Problem,
    staged: Staged,
    stages: dict[str, StageResult],
    frames: int,
    *,
    generations: int,
    epochs: int,
    optimizer: str,
    lr: float,
    tol: float,
    seed: int,
    progress: bool,
    workers: int | str = 1,
) -> tuple[dict[str, float], bool, dict[str, Any] | None, dict[str, Any] | None]:
    """The global stages of :func:`pliant.fit.fit` (module docstring), each through ``staged`` (the
    checkpoint) and recorded in ``stages``.

    Args:
        problem: The fitting problem.
        staged: Runs a stage, or returns its result from the checkpoint.
        stages: The fit's stage results (name → StageResult), added to.
        frames: The searches train on frames 1 … ``frames`` − 1 (:func:`pliant.fit._gate.fit_window`).
        generations: Most CMA-ES generations per search.
        epochs: Image-gradient iterations.
        optimizer: The image-gradient stage's optimiser (``"adam"`` / ``"lbfgs"``).
        lr: Adam's step.
        tol: The image-gradient stage's relative tolerance.
        seed: CMA-ES seed.
        progress: Show progress bars.
        workers: Processes that evaluate a CMA-ES generation (``pl.fit.cmaes``'s ``workers``).

    Returns:
        (global values, interrupted, the ``global_validation`` report, the ``identifiability`` report); the
        reports are None without a global search or when it was interrupted.
    """
    with held_back(problem, frames):
        values, interrupted = _search(
            problem,
            staged,
            stages,
            generations=generations,
            epochs=epochs,
            optimizer=optimizer,
            lr=lr,
            tol=tol,
            seed=seed,
            progress=progress,
            workers=workers,
        )
    if not stages or interrupted or not problem.globals:
        return values, interrupted, None, None
    # never worse than the scene as given on frames the search did not see, without saying so
    values, validated, identified = gate(problem, values, frames)
    if not validated["kept"] or frames >= problem.n_train:
        return values, interrupted, validated, identified
    # the search again, on all the training frames; the parameters put back on a tie stay at the scene's
    # values (the scene the candidates are built on)
    searched = problem.globals
    again: dict[str, StageResult] = {}
    problem.globals = [b for b in searched if b.name not in validated["reset"]]
    try:
        if problem.globals:
            refit, interrupted = _search(
                problem,
                lambda name, run: staged(f"{name}_all_frames", run),
                again,
                generations=generations,
                epochs=epochs,
                optimizer=optimizer,
                lr=lr,
                tol=tol,
                seed=seed,
                progress=progress,
                workers=workers,
            )
            candidate = {**values, **refit}
    finally:
        problem.globals = searched
    stages.update({f"{k}_all_frames": r for k, r in again.items()})
    validated["refit"] = [f"{k}_all_frames" for k in again]
    if again and interrupted:
        values = candidate  # where the stopped search stands (a resume continues it)
    elif again:
        # The search again from the scene's values may stop in a worse basin than the held-back search
        # found (MuJoCo's cloth: 3 s, E·t 64 N/m and lumped masses, 40 mm on validation, where the first
        # had 94 N/m, even masses and 6 mm): the values written are the better of the two on all the
        # training frames, the objective of both.
        n = problem.n_train
        first, second = open_loop_loss(problem, values, 1, n), open_loop_loss(problem, candidate, 1, n)
        validated["all_frames"] = {"held_back_search": first, "search_again": second}
        if second <= first:
            values = candidate
            validated["why"] += "; then searched again on all the training frames (the values written)"
        else:
            validated["why"] += (
                f"; searched again on all the training frames, which ended worse there ({second:.4g} > "
                f"{first:.4g}): the held-back search's values, refined on all the training frames, written"
            )
            values, interrupted = _refine(
                problem, staged, stages, values, validated, generations, seed, progress, workers
            )
    if not interrupted:  # at the values written, over the frames they were fitted on
        identified = identify(problem, values, problem.n_train)
    return values, interrupted, validated, identified


__all__ = ["SIGMA_OPEN_LOOP", "global_stages", "stage_progress"]
