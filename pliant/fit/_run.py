"""The whole fit (``pl.fit.fit``, ``pliant fit``): stage 1 CMA-ES on global parameters, stage 2 gradients on
per-element parameters, then the outputs: ``fitted.toml`` (+ ``fitted_params.npz``), ``fit.json``,
``fit.png`` and ``fit.mp4``."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..io import Observations, atomic_output, atomic_savez, atomic_write_text
from ..scene import format_bytes
from . import _explain
from ._cmaes import StageResult, close_workers
from ._gate import fit_window
from ._global import global_stages, stage_progress
from ._gradient import gradient_stage
from ._mass import choose_mass_distribution
from ._memory import device_memory, memory_problem, problem_memory
from ._params import COMPLIANT, FitError, auto_per_element, scene_constraints
from ._photometric import PhotometricProblem, gradient_capable, problem_for, refinable
from ._problem import Problem
from ._ray import require_ray, use_ray
from ._resume import FitCheckpoint, StageHook
from ._toml import scene_toml

if TYPE_CHECKING:
    from ..scene import Scene, SceneConfig
    from ._params import Bound

PARAMS_FILE = "fitted_params.npz"
#: The per-element stage is kept only if it lowers the validation loss by at least this fraction. On
#: MuJoCo's cloth (tests/data/foreign) 600 per-spring values lowered an 8-frame validation loss by 3.8 %
#: and raised the held-out error from 30 to 40 mm; where the per-element values are real (two materials,
#: the beam) they lower it by far more.
PER_ELEMENT_MARGIN = 0.1


def fitted_scene(problem: Problem, values: dict[str, float], per_element: dict[str, np.ndarray]) -> Scene:
    """The scene built with fitted global values and per-element arrays."""
    scene = problem.build(values)
    for key, a in per_element.items():
        parts = key.split(".")
        target = getattr(scene.model, parts[1]) if parts[0] == "model" else None
        if parts[0] == "constraints":
            target = getattr(scene_constraints(scene)[int(parts[1])], parts[2])
        if target is None:
            raise FitError(f"per-element array {key!r}: expected model.<array> or constraints.<i>.<array>")
        target.assign(a)
    return scene


def fit(
    cfg: SceneConfig,
    obs: Observations,
    out: str | Path,
    *,
    params: list[str] | None = None,
    per_element: str | None = None,
    train_fraction: float = 0.7,
    generations: int = 40,
    epochs: int = 20,
    optimizer: str = "adam",
    horizon: int | None = 1,
    lr: float = 0.01,
    smoothness: float = 0.0,
    validation: float = 0.2,
    tol: float = 1e-4,
    shooting: int | None = None,
    seed: int = 42,
    device: str | None = None,
    dtype: str | None = None,
    progress: bool = True,
    video: bool = True,
    appearance: bool | None = None,
    force: bool = False,
    resume: bool = False,
    workers: int | str = "auto",
    ray: bool = False,
    address: str | None = None,
) -> dict[str, Any]:
    """Fit a scene to observations and write the outputs into ``out``.

    Stage 1 (CMA-ES, forward runs only) fits the global parameters ``params`` (default: the scene model's
    material); stage 2 (Adam or L-BFGS on tape gradients) fits the per-element parameter ``per_element``
    when one is named. Both train on the first ``train_fraction`` of the frames less their last
    ``validation`` fraction, and each stage's values are kept only if they predict those validation frames
    better (the global search, once it passes, runs again on all the training frames:
    :mod:`pliant.fit._global`); the frames after ``train_fraction`` are the test. A Ctrl-C during a stage
    keeps the best values found so far, writes the outputs and re-raises.

    Args:
        cfg: The scene (``pl.scene.load_scene``).
        obs: The observations (``pl.io.Observations.load``).
        out: Output folder (created).
        params: Global parameter names (``pl.fit.GLOBAL``); None: the material; ``[]``: none.
        per_element: Per-element parameter (``"stiffness"``, ``"E"``, ``"compliance"``, a per-element
            registry name) or None; ``"auto"``: the model's own (k per spring, E per tet, α per
            constraint; none from images or where the scene has none), kept only where it lowers the
            validation error (``pliant fit``'s default); ``"none"``: None.
        train_fraction: Fraction of frames to train on.
        generations: Most CMA-ES generations (it stops earlier once converged).
        epochs: Gradient-stage iterations (passes over the training frames).
        optimizer: ``"adam"`` or ``"lbfgs"``.
        horizon: Frames per tape (1: PhysTwin's default), None: the whole training rollout.
        lr: Adam step size (log-scale units; one step per frame with the default horizon).
        smoothness: Weight of the total-variation prior over neighbouring elements in the gradient stage
            (``pl.fit.Smoothness``; 0: none; 1e-4 separates a two-material cloth, see docs/fitting.md).
        validation: Fraction of the training frames (the last ones) no stage trains on. The global values
            are kept only if their open-loop rollout predicts these frames better than the scene's own
            (:func:`pliant.fit._gate.gate`, which also puts back the parameters the data do not constrain
            where that is a tie: ``global_validation`` and ``identifiability`` in fit.json); the
            per-element values only if they lower that loss by PER_ELEMENT_MARGIN without raising it on the
            whole training window. 0: train on all and decide on the training loss alone.
        tol: The gradient stages stop when an epoch improves the loss by less than this fraction (five in a
            row; L-BFGS: its ftol); ``epochs`` is the cap.
        shooting: Multiple-shooting window of the training runs [frames] (:class:`pliant.fit.Problem`;
            None: by the tracks' coverage and the motion's length, 0: open loop).
        seed: CMA-ES seed.
        device: Warp device (None: the scene's).
        dtype: ``"float32"`` / ``"float64"`` (None: the scene's).
        progress: Show progress bars.
        video: Write ``fit.mp4``.
        appearance: From images: fit the splats' appearance to the first frame before the physics
            (``pl.fit._explain.before_physics``); None: when the scene has no ``[gaussians]`` section.
        resume: Continue from ``out/fit_checkpoint.json``, which every fit writes after each CMA-ES
            generation and gradient iteration (:mod:`pliant.fit._resume`): the same outputs as a fit that was
            never stopped (on the CPU, ``fitted.toml`` byte for byte). Its scene, observations, options and
            fit version must be this fit's.
        workers: Processes that evaluate a CMA-ES generation (``pl.fit.cmaes``; "auto": the CPU's cores
            where that pays); the same outputs whatever the count. With ``ray``: Ray actors ("auto": one per
            CPU of the cluster).
        ray: Evaluate the CMA-ES generations on Ray actors (:mod:`pliant.fit._ray`; ``pip install
            'pliant[ray]'``), with the same outputs.
        address: With ``ray``, a running Ray cluster's address (None: a local one).
        force: From images: go on when the fit's memory estimate (:mod:`pliant.fit._memory`) exceeds the
            memory available on its device.

    Returns:
        The contents of ``fit.json`` (also written to ``out``).

    Raises:
        FitError: bad options, a problem that cannot be built, an image fit whose memory estimate
            exceeds the memory available (without ``force``), or with ``resume`` a missing checkpoint or one
            from another scene, other observations, other options or another version of the fit.
    """
    t0 = time.perf_counter()
    if not 0.0 <= validation < 1.0:
        raise FitError(f"--validation: expected a fraction in [0, 1), got {validation}")
    if not (math.isfinite(smoothness) and smoothness >= 0):
        raise FitError(f"--smoothness: expected a weight >= 0, got {smoothness}")
    if address and not ray:
        raise FitError("--address goes with --ray")
    if ray:
        require_ray()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    options = {
        "params": params,
        "per_element": per_element,
        "train_fraction": train_fraction,
        "generations": generations,
        "epochs": epochs,
        "optimizer": optimizer,
        "horizon": horizon,
        "lr": lr,
        "smoothness": smoothness,
        "validation": validation,
        "tol": tol,
        "shooting": shooting,
        "seed": seed,
        "device": device,
        "dtype": dtype,
        "appearance": appearance,
    }
    ck = FitCheckpoint.open(out, cfg, obs, options, resume)  # refused here, before any work

    def staged(name: str, run: Callable[[StageHook], StageResult]) -> StageResult:
        """Stage ``name``: its result when the checkpoint has it, else run (continuing a saved state)."""
        done = ck.finished(name)
        if done is None:
            done = run(ck.stage(name))
            if not done.interrupted:
                ck.finish(name, done)
        return done

    auto = per_element == "auto"
    per_element = auto_per_element(cfg, obs) if auto else (None if per_element == "none" else per_element)
    kw: dict[str, Any] = {
        "params": params,
        "train_fraction": train_fraction,
        "device": device,
        "dtype": dtype,
    }
    make = problem_for(obs)  # images in the file: the photometric loss (_photometric.py)
    try:
        problem = make(cfg, obs, per_element=per_element, shooting=shooting, **kw)
    except FitError:
        if not auto or per_element is None:
            raise
        per_element = None  # "auto" on a scene without such elements (rigid XPBD sets): no per-element stage
        problem = make(cfg, obs, per_element=None, shooting=shooting, **kw)
    if ray:
        use_ray(problem, address)
    image_gradient = isinstance(problem, PhotometricProblem) and epochs > 0 and bool(refinable(problem))
    mem = problem_memory(problem, gradient=image_gradient)
    plan = search_plan(problem)
    if mem is not None:
        have = device_memory(problem.model_device)  # type: ignore[attr-defined]
        plan.append(f"  memory: {mem.describe()}; {'?' if have is None else format_bytes(have)} available")
        too_big = None if force else memory_problem(mem, have)
        if too_big:  # before the appearance stage and the searches: nothing is rendered yet
            raise FitError(too_big)
    if progress:
        print("fit: searching\n" + "\n".join(plan), flush=True)
    # images: the appearance stage, and whether the splats can explain the images at all (warns if not)
    explained = _explain.before_physics(problem, out, appearance=appearance)
    stages: dict[str, StageResult] = {}
    arrays: dict[str, np.ndarray] = {}
    n = problem.n_train
    n_fit = fit_window(n, validation)  # the global and per-element stages train on 1 ... n_fit - 1
    values, interrupted, validated, identified = global_stages(
        problem,
        staged,
        stages,
        n_fit,
        generations=generations,
        epochs=epochs,
        optimizer=optimizer,
        lr=lr,
        tol=tol,
        seed=seed,
        progress=progress,
        workers=workers,
    )
    close_workers(problem)
    mass = None
    if not interrupted and any(b.name == "mass_uniformity" for b in problem.globals) and n_fit < n:
        # lumped, uniform or the fitted blend, by the validation frames (the simpler one on a tie)
        mass = choose_mass_distribution(problem, values, frames=(n_fit, n))
        values = {**values, "mass_uniformity": mass.uniformity}
    if per_element is not None and epochs > 0 and not interrupted:
        with stage_progress(progress, epochs, f"fit: {optimizer} ({per_element})") as tick:
            stages["gradient"] = staged(
                "gradient",
                lambda hook: gradient_stage(
                    problem,
                    values,
                    iterations=epochs,
                    lr=lr,
                    horizon=horizon,
                    optimizer=optimizer,
                    smoothness=smoothness,
                    frames=n_fit,
                    tol=tol,
                    callback=tick,
                    checkpoint=hook,
                ),
            )
        arrays = stages["gradient"].per_element
        interrupted = stages["gradient"].interrupted
        # The one-frame-horizon losses are not the open-loop rollout's, and many per-element values can fit
        # the training frames and predict worse (over-fitting): keep them only if the open-loop rollout
        # predicts the held-back validation frames clearly better than the global stage's (by
        # PER_ELEMENT_MARGIN: hundreds of free values buy a few per cent on a short window by chance), and
        # the whole training window no worse.
        x0 = problem.simulate(problem.build(values), n, forced=False)
        x1 = problem.simulate(fitted_scene(problem, values, arrays), n, forced=False)
        before, after = problem.loss(x0), problem.loss(x1)
        stages["gradient"].loss = after
        if n_fit < n:
            v0, v1 = problem.loss(x0, n_fit, n), problem.loss(x1, n_fit, n)
            stages["gradient"].validation = {"frames": [n_fit, n], "before": v0, "after": v1}
            keep = v1 < (1.0 - PER_ELEMENT_MARGIN) * v0 and after <= before
        else:
            keep = after < before
        if not keep:
            stages["gradient"].kept = False
            arrays = {}
    report = write_outputs(problem, out, values, arrays, stages, video=video, progress=progress)
    checks = _explain.after_physics(problem, values)
    report.update(explained, warnings=explained.get("warnings", []) + checks.pop("warnings"), **checks)
    report["global_validation"], report["identifiability"] = validated, identified
    report["mass_distribution"] = (
        None
        if mass is None
        else {
            "name": mass.name,
            "uniformity": mass.uniformity,
            "errors": {k: _finite(v) for k, v in mass.errors.items()},  # [m]; None: diverged
            "reason": mass.reason,
        }
    )
    report["shooting"] = problem.shooting
    report["wall_time"] = time.perf_counter() - t0
    report["interrupted"] = interrupted
    atomic_write_text(out / "fit.json", json.dumps(report, indent=2, default=_json_default) + "\n")
    if interrupted:
        raise KeyboardInterrupt
    return report


def stages_of(problem: Problem, b: Bound) -> list[str]:
    """The stages that fit global parameter ``b`` (a Bound): CMA-ES always; from images also the
    image-gradient stage when it can differentiate it (:func:`pliant.fit._photometric.gradient_capable`)."""
    out = ["cmaes"]
    if isinstance(problem, PhotometricProblem) and gradient_capable(b.param):
        out.append("image-gradient")
    return out


def search_plan(problem: Problem) -> list[str]:
    """One line per searched global parameter: its bounds, start, scale, why and which stages fit it (what
    ``pliant fit`` prints before it starts)."""
    lines = []
    for b in problem.globals:
        unit = b.param.doc.rsplit("[", 1)[-1].rstrip("])") if "[" in b.param.doc else ""
        scale = "log" if b.param.log else "linear"
        # a hard ground the fit made compliant to start its search: the scene itself has no such value
        given = "none (hard contact)" if problem.seeded and b.name in COMPLIANT else f"{b.scene_value:.4g}"
        lines.append(
            f"  {b.name}: [{b.lo:.4g}, {b.hi:.4g}] {unit} ({scale}), scene {given}, start "
            f"{b.nominal:.4g}; {b.why}; fitted by {' + '.join(stages_of(problem, b))}"
        )
    if problem.per_element is not None:
        lines.append(f"  {problem.per_element} per element: gradient stage (kept where it lowers validation)")
    return lines


def _json_default(v: object) -> object:
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    raise TypeError(type(v).__name__)


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def write_outputs(
    problem: Problem,
    out: Path,
    values: dict[str, float],
    per_element: dict[str, np.ndarray],
    stages: dict[str, StageResult],
    *,
    video: bool = True,
    progress: bool = False,
) -> dict[str, Any]:
    """Write ``fitted.toml`` (+ ``fitted_params.npz``), ``fit.png`` and ``fit.mp4``; returns fit.json's
    data."""
    cfg = problem.config(values)
    if per_element:
        atomic_savez(out / PARAMS_FILE, **per_element)
        cfg.scene.parameters = PARAMS_FILE
    elif cfg.scene.parameters is not None:
        cfg.scene.parameters = str((Path(cfg.base_dir) / cfg.scene.parameters).resolve())
    if isinstance(problem, PhotometricProblem) and problem.appearance_section is not None:  # its splats
        # a registered section (scene._registry.register_section): a field of the rebuilt model only
        cfg = cfg.model_copy(update={"gaussians": problem.appearance_section})
    scene_toml(cfg, out / "fitted.toml", comment=f"Fitted by `pliant fit` from {problem.cfg.source}")
    x_nom = problem.simulate(problem.build_given(), problem.frames)  # the scene as given
    scene = fitted_scene(problem, values, per_element)
    x = problem.simulate(scene, problem.frames)
    err, err_nom = problem.errors(x), problem.errors(x_nom)
    report: dict[str, Any] = {
        "scene": problem.cfg.source,
        "observations": problem.obs.source,
        "frames": problem.frames,
        "train_frames": problem.n_train,
        "params": {
            b.name: {
                "value": values[b.name],
                "nominal": b.scene_value,  # the scene's, not the search's start
                "start": b.nominal,
                "bounds": [b.lo, b.hi],
                "log": b.param.log,
                "why": b.why,
                "stages": stages_of(problem, b),
            }
            for b in problem.globals
        },
        "per_element": {
            k: {
                "file": PARAMS_FILE,
                "count": int(a.size),
                "min": float(a.min()),
                "median": float(np.median(a)),
                "max": float(a.max()),
            }
            for k, a in per_element.items()
        },
        "loss_history": {k: s.history for k, s in stages.items()},
        "gradient_stage_kept": stages["gradient"].kept if "gradient" in stages else None,
        "gradient_validation": stages["gradient"].validation if "gradient" in stages else None,
        "stage_wall_time": {k: s.wall_time for k, s in stages.items()},
        "stage_stop": {k: s.stop for k, s in stages.items() if s.stop},
        "evaluations": {k: s.evaluations for k, s in stages.items()},
        "error": {k: _finite(v) for k, v in problem.split_errors(x).items()},
        "error_nominal": {k: _finite(v) for k, v in problem.split_errors(x_nom).items()},
        "error_per_frame": [_finite(v) for v in err],
        "error_unit": "m (mean distance between visible tracks and their particles)"
        if problem.obs.tracks
        else "none: the observation has no tracks (the image error is under photometric)",
    }
    ylabel, scale = "track error [mm]", 1e3
    if hasattr(problem, "image_report"):  # photometric fits: per-frame image loss and PSNR
        report["photometric"] = ph = problem.image_report(x, x_nom)
        if not problem.obs.tracks:  # no tracks to plot: the per-frame RMS image error instead
            err, err_nom = (np.sqrt(ph[k]["loss_per_frame"]) for k in ("fitted", "nominal"))
            ylabel, scale = "RMS image error (0-1 per channel)", 1.0
    _plot(out / "fit.png", stages, err, err_nom, problem.n_train, problem.frame_dt, ylabel, scale)
    if video:
        with atomic_output(out / "fit.mp4") as tmp:
            _video(tmp, scene, x, problem, progress)
    return report


def _plot(
    path: Path,
    stages: dict[str, StageResult],
    err: np.ndarray,
    err_nom: np.ndarray,
    n_train: int,
    frame_dt: float,
    ylabel: str = "track error [mm]",
    scale: float = 1e3,
):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8))
    offset = 0
    for name, s in stages.items():
        if s.history:
            it = np.arange(1, len(s.history) + 1) + offset
            a.plot(it, s.history, marker=".", label=name)
            offset += len(s.history)
    a.set_yscale("log")
    a.set_xlabel("iteration (CMA-ES generation, then gradient epoch)")
    a.set_ylabel("training loss")
    a.set_title("loss")
    if any(s.history for s in stages.values()):  # a run stopped before its first iteration has none
        a.legend()
    t = np.arange(len(err)) * frame_dt

    def means(e: np.ndarray) -> str:  # the summary's train and held-out means, beside each curve
        m = [scale * np.nanmean(p) if np.isfinite(p).any() else np.nan for p in (e[1:n_train], e[n_train:])]
        return f"train {m[0]:.3g}, test {m[1]:.3g}"

    b.plot(t[:n_train], scale * err[:n_train], color="C0", label=f"fitted: {means(err)}")
    b.plot(t[n_train - 1 :], scale * err[n_train - 1 :], color="C3", label="fitted (test frames)")
    b.plot(t, scale * err_nom, color="0.6", ls="--", label=f"nominal: {means(err_nom)}")
    b.axvline((n_train - 1) * frame_dt, color="k", lw=0.8)
    b.set_xlabel("time [s]")
    b.set_ylabel(ylabel)
    b.set_title("per-frame error (train | test)")
    b.legend()
    fig.tight_layout()
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)


def _video(path: Path, scene: Scene, x: np.ndarray, problem: Problem, progress: bool) -> None:
    """The fitted motion (orange particles) with observed tracks drawn over it: visible ones green, hidden
    ones red at the position of the particle they are bound to. From camera videos: the first camera's
    observed images beside the fitted motion drawn as splats from that camera."""
    from ..render import render_video, write_video

    if isinstance(problem, PhotometricProblem):
        write_video(problem.comparison_frames(x), path, fps=scene.fps)
        return

    o = problem.obs
    t = min(x.shape[0], o.frames)
    x = x[:t]
    obs_pts = np.where(o.visible[:t, :, None], np.nan_to_num(o.points[:t]), x[:, o.particle])
    pts = np.concatenate([x, obs_pts], axis=1)
    n, k = x.shape[1], o.tracks
    colors = np.empty((t, n + k, 3))
    colors[:, :n] = (0.91, 0.42, 0.16)
    colors[:, n:] = np.where(o.visible[:t, :, None], (0.1, 0.75, 0.25), (0.85, 0.1, 0.1))
    from scipy.spatial import cKDTree

    # Radii from the particles' spacing (the observed points sit on them, which would make it ~0).
    spacing = float(np.median(cKDTree(x[0]).query(x[0], k=2)[0][:, 1])) if n > 1 else 0.01
    extent = float(np.ptp(x.reshape(-1, 3), axis=0).max()) or 1.0
    r = max(min(0.3 * spacing, 0.02 * extent), 1e-3 * extent)
    radius = np.concatenate([np.full(n, 0.7 * r), np.full(k, r)])  # observed points drawn over the particles
    pts, colors, radius = _with_rope_beads(scene, x, pts, colors, radius, 0.7 * r)
    render_video(
        pts,
        path,
        colors=colors,
        point_radius=radius,
        fps=scene.fps,
        camera=scene.camera,
        progress=progress,
        ground=scene.model.ground.height if scene.model.ground is not None else False,
    )


def _with_rope_beads(scene: Scene, x: np.ndarray, pts, colors, radius, r: float):
    """Ropes drawn as lines: beads of the particles' colour and radius ``r`` along every link, spaced at
    most ``r`` apart, put before the observed points (drawn over them)."""
    from ..render import link_beads

    n = x.shape[1]
    segs = [
        np.stack(
            [
                np.arange(o["start"], o["start"] + o["count"] - 1),
                np.arange(o["start"] + 1, o["start"] + o["count"]),
            ],
            1,
        )
        for o in scene.model.objects
        if o.get("kind") == "rope" and o["count"] >= 2
    ]
    if not segs:
        return pts, colors, radius
    seg = np.concatenate(segs)
    link = float(np.median(np.linalg.norm(x[0, seg[:, 0]] - x[0, seg[:, 1]], axis=1)))
    beads = link_beads(x, seg, min(32, max(1, int(np.ceil(link / max(r, 1e-9))))))
    pts = np.concatenate([pts[:, :n], beads, pts[:, n:]], axis=1)
    colors = np.concatenate(
        [colors[:, :n], np.broadcast_to(colors[:, :1], beads.shape), colors[:, n:]], axis=1
    )
    radius = np.concatenate([radius[:n], np.full(beads.shape[1], r), radius[n:]])
    return pts, colors, radius


__all__ = ["PARAMS_FILE", "fit", "fitted_scene", "write_outputs"]
