"""Can the images be explained? The appearance stage before a photometric fit's physics, the PSNR checks
around it, and the warnings a fit gives when its figures say that the model cannot explain the data (a low
PSNR at the observed initial state, a fitted value at a bound).

``pl.fit.fit`` calls :func:`before_physics` once the problem is built and :func:`after_physics` once the
stages are done; both return what goes into ``fit.json`` and raise :class:`FitWarning`\\ s with advice.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ._params import MASS

if TYPE_CHECKING:
    from ..gaussians import AppearanceResult
    from ..scene import GaussiansSection
    from ._photometric import PhotometricProblem
    from ._problem import Problem

#: PSNR [dB] under which the splats are said not to explain the images. Measured: pliant's own footage
#: gives 26-30 dB at a wrong motion and > 40 dB at the true one; MuJoCo footage drawn with pliant's
#: generated colours on black 2-7 dB, with a fitted appearance > 20 dB (docs/gaussians.md).
PSNR_LOW_DB = 20.0

#: A fitted value closer than this to a bound, as a fraction of the search box (log-scaled where the
#: parameter is), is "at the bound".
AT_BOUND = 0.01


class FitWarning(UserWarning):
    """A fit whose figures say that the model does not explain the observations (the message says what to
    check)."""


def _psnr(mse: float) -> float:
    return float("inf") if mse <= 0 else -10.0 * math.log10(mse)


def _colour_losses(problem: PhotometricProblem, x: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """Per-frame colour MSE (the mask term left out) of positions ``x`` over frames ``lo … hi − 1``."""
    w = problem.mask_weight
    problem.mask_weight = 0.0
    try:
        return problem.frame_losses(x, lo, hi)
    finally:
        problem.mask_weight = w


def before_physics(
    problem: Problem, out: Path, *, appearance: bool | None = None, iterations: int = 300
) -> dict[str, Any]:
    """For a photometric problem: fit the splats' appearance to the first frame when ``appearance`` (None:
    when the scene has no ``[gaussians]`` section), write it as ``out/appearance.ply`` (the section that
    ``fitted.toml`` will carry is left in ``problem.appearance_section``), then measure the PSNR at the
    observed initial state and of the nominal motion over the training frames, and warn when it is low.

    Args:
        problem: The fitting problem (a track problem returns ``{}`` at once).
        out: The fit's output folder.
        appearance: Run the appearance stage (None: only without a ``[gaussians]`` section).
        iterations: Most Adam steps of the appearance stage.

    Returns:
        The ``fit.json`` entry: the appearance stage's figures (``psnr_before_db``, ``psnr_after_db``,
        background, light, iterations, wall time) and ``psnr_initial_state_db`` (frame 0, all cameras),
        ``psnr_nominal_train_db`` (the nominal motion over the training frames: the physics fit's start),
        and ``warnings`` (the messages warned) when there are any.
    """
    from ._photometric import PhotometricProblem

    if not isinstance(problem, PhotometricProblem):
        return {}
    from ..gaussians import fit_splat_appearance

    obs, cams = problem.obs, problem.cameras
    has_section = getattr(problem.cfg, "gaussians", None) is not None
    run = (not has_section) if appearance is None else bool(appearance)
    report: dict[str, Any] = {}
    x0 = problem.build(problem.nominal).model.particle_q_np.astype(np.float64)
    if run:
        masks = None if obs.masks is None else [[obs.mask(c, 0) for c in range(len(cams))]]
        res = fit_splat_appearance(
            problem.splats,
            cams,
            [x0],
            [[obs.image(c, 0) for c in range(len(cams))]],
            masks,
            # shading needs flat splats with normals: the generated surface ones, not round per-particle ones
            shading=problem.binding.method == "triangles",
            iterations=iterations,
            mask_weight=problem.mask_weight,
        )
        problem.gaussians = problem.binding.gaussians
        report["appearance"] = {
            "frames": [0],
            "sh_degree": res.sh_degree,
            "background": list(res.background),
            "light": None if res.light is None else list(res.light),
            "psnr_before_db": res.psnr_before,
            "psnr_after_db": res.psnr_after,
            "iterations": res.iterations,
            "wall_time": res.wall_time,
        }
        problem.appearance_section = _section(problem, out, res)
    x = x0[None]
    report["psnr_initial_state_db"] = _psnr(float(np.mean(_colour_losses(problem, x, 0, 1))))
    x_nom = problem.simulate(problem.build(problem.nominal), problem.n_train)
    per_frame = _colour_losses(problem, x_nom, 1, problem.n_train)
    report["psnr_nominal_train_db"] = _psnr(float(np.mean(per_frame))) if len(per_frame) else None
    if report["psnr_initial_state_db"] < PSNR_LOW_DB:
        advice = (
            "the appearance stage could not match them: check the cameras (K and world_to_camera in "
            "OpenCV axes, x right, y down, z forward, world to camera) and that frame 0 shows the scene's "
            "initial state"
            if run
            else "the scene's [gaussians] section does not describe the footage: remove it so that "
            "`pliant fit` fits the appearance from the first frame, or fix its colours, background and light"
        )
        msg = (
            f"the splats do not explain the images at the observed initial state (PSNR "
            f"{report['psnr_initial_state_db']:.1f} dB < {PSNR_LOW_DB:g} dB): {advice}; a fit of the "
            "physics to images it cannot draw may move away from the truth"
        )
        report["warnings"] = [msg]
        warnings.warn(msg, FitWarning, stacklevel=3)
    return report


def _section(problem: PhotometricProblem, out: Path, res: AppearanceResult) -> GaussiansSection | None:
    """The ``[gaussians]`` section that draws the fitted appearance (a PLY in ``out``), or None where a
    section cannot describe the splats (several objects: generated splats span the whole model)."""
    from ..gaussians import save_ply
    from ..io import atomic_output
    from ..scene import GaussiansSection

    own = getattr(problem.cfg, "gaussians", None)
    if own is None and len(problem.cfg.objects) != 1:
        return None
    path = Path(out).resolve() / "appearance.ply"
    b = problem.binding
    with atomic_output(path) as tmp:  # a kill never leaves half a PLY that fitted.toml names
        save_ply(b.gaussians.baked(), tmp)
    fields: dict[str, Any] = {"ply": str(path), "bind": b.method, "background": res.background}
    if res.light is not None:
        fields["light"] = list(res.light)
    if own is not None:  # the scene's own section, its splats refitted: keep its object and skinning
        return own.model_copy(update={**fields, "generate": None})
    if b.method == "lbs":  # the generated per-particle splats' skinning (pliant/gaussians/_surface.py)
        fields.update(k=int(b.link_gauss.shape[0] // max(b.gaussians.count, 1)), neighbours=8)
    return GaussiansSection(**fields)


def after_physics(problem: Problem, values: dict[str, float]) -> dict[str, Any]:
    """Measure the fitted and nominal motions' colour PSNR on the held-out (test) frames (photometric
    problems), and warn about fitted values at a bound of their search box (the data pushed them out of the
    plausible range: usually a model that cannot explain the data, or images it cannot draw).

    Args:
        problem: The fitting problem.
        values: The fitted global values.

    Returns:
        ``warnings`` (the messages warned) and, from images, ``psnr_fitted_test_db`` and
        ``psnr_nominal_test_db`` (None without test frames).
    """
    report: dict[str, Any] = {}
    from ._photometric import PhotometricProblem

    if isinstance(problem, PhotometricProblem):
        for key, vals in (("fitted", values), ("nominal", problem.nominal)):
            x = problem.simulate(problem.build(vals), problem.frames)
            per_frame = _colour_losses(problem, x, problem.n_train, problem.frames)
            report[f"psnr_{key}_test_db"] = _psnr(float(np.mean(per_frame))) if len(per_frame) else None
    msgs = []
    for b in problem.globals:
        if b.name in MASS:  # α = 0 and 1 are lumped and uniform: answers, not a search pushed out of range
            continue
        v = values[b.name]
        if v == b.scene_value:  # the scene's own value (the validation gate kept it): not pushed there
            continue
        u = b.param.to_unit(min(max(v, b.lo), b.hi), b.lo, b.hi)
        if u < AT_BOUND or u > 1.0 - AT_BOUND:
            side = "lower" if u < AT_BOUND else "upper"
            msgs.append(
                f"{b.name} ended at its {side} bound ({v:.6g}; the search box is [{b.lo:.6g}, {b.hi:.6g}]): "
                "the data pushed it out of the plausible range. Check that the observations can be explained "
                "(the PSNR at the start in fit.json, the cameras, the scene's initial state), fit fewer "
                "parameters, or widen the box by starting from a better nominal value"
            )
    for m in msgs:
        warnings.warn(m, FitWarning, stacklevel=3)
    report["warnings"] = msgs
    return report


__all__ = ["AT_BOUND", "PSNR_LOW_DB", "FitWarning", "after_physics", "before_physics"]
