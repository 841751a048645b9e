"""Fitting benchmarks: the README's fit (``fit_rope``) and a 17×17 cloth fit, wall time and accuracy.

Each row makes synthetic observations of a known truth on the CPU (so that every device fits the same data),
then times ``pl.fit.fit`` — both stages, the outputs without the video, what ``pliant fit --no-video`` runs —
on the row's device, after a warm-up fit of one CMA-ES generation and one gradient epoch (kernel compilation
or cache loading, graph capture: ``compile_s``). Accuracy: each fitted global parameter's relative error
against the truth (``param_rel_error``, largest in ``max_param_rel_error``) and the held-out track error
(``test_error_mm``, the last 30 % of the frames, against ``test_error_start_mm`` of the starting scene).
The GPU comparison of issue 24 is the same row with ``--device cuda:0`` and ``--device cpu`` under
``taskset -c 0`` (one core): ``cpu_cores`` records the cores the process could use.

* ``fit_rope``: the README's commands, ``pliant observe fit_rope --tracks 10 --noise 0.001 --dropout 0.3
  --set 'objects[0].material.stiffness=480'`` then ``pliant fit fit_rope obs.npz --params
  stiffness,damping_rate`` (40 generations, 20 epochs, per-spring stiffness kept where it helps); truth
  k = 480 N/m, damping rate 0.5 1/s, started from the scene's k = 300 N/m. Quick: 15 frames, 6 generations,
  2 epochs.
* ``fit_cloth_17``: ``benchmarks/fit_known_truth.py --only cloth17``: a 17×17 mass-spring cloth (float32,
  90 frames of 30 substeps), 60 tracks with 1 mm noise and 30 % hidden, from k = 480 N/m and damping rate
  0.5 1/s back to 300 and 1.0; 20 generations, then one Adam epoch on per-spring stiffness. Quick: a 7×7
  cloth, 30 frames, 20 tracks, 4 generations.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from ._common import print_rows

if TYPE_CHECKING:
    from ..scene import SceneConfig

#: The 17×17 cloth of the known-truth fits (benchmarks/fit_known_truth.py reads it from here).
CLOTH17 = """
[scene]
name = "cloth17"
frame_dt = 0.03333333333333333
substeps = 30
frames = 89
dtype = "float32"
[[objects]]
kind = "cloth"
nx = 16
ny = 16
size = 0.8
origin = [-0.4, 0.9, -0.4]
plane = "xz"
mass = 1.0
pin = "top-corners"
[objects.material]
stiffness = 300.0
bend_stiffness = 2.0
damping = 0.005
[solver]
integrator = "SymplecticEuler"
damping_rate = 1.0
"""
#: The cloth's truth and the fit's start (global parameters).
CLOTH17_TRUTH = {"stiffness": 300.0, "damping_rate": 1.0}
CLOTH17_START = {"stiffness": 480.0, "damping_rate": 0.5}
#: Its observations: tracked particles, noise σ [m], fraction hidden per frame, seed.
CLOTH17_OBSERVE = {"tracks": 60, "noise": 0.001, "dropout": 0.3, "seed": 3}

#: The README's fit_rope truth (``--set 'objects[0].material.stiffness=480'``; the scene's damping rate).
ROPE_TRUTH = {"stiffness": 480.0, "damping_rate": 0.5}


def fit_row(
    scene: str,
    truth_cfg: SceneConfig,
    start_cfg: SceneConfig,
    truth: dict[str, float],
    observe: dict[str, Any],
    fit: dict[str, Any],
    device: str | None,
) -> dict:
    """Observe ``truth_cfg`` on the CPU (``observe``: :func:`pliant.fit.observe`'s options), warm up, then
    time :func:`pliant.fit.fit` of ``start_cfg`` on ``device`` (``fit``: its options); one row of speed and
    accuracy figures (``truth``: the true values of the fitted global parameters)."""
    import pliant.fit as plfit
    import pliant.scene as plscene

    from .._warp import resolve_device

    device = str(resolve_device(device))
    obs = plfit.observe(plscene.build_scene(truth_cfg, device="cpu"), **observe)
    common: dict[str, Any] = {"device": device, "progress": False, "video": False, "params": list(truth)}
    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        warm = {**fit, "generations": 1, "epochs": 1}
        plfit.fit(start_cfg, obs, os.path.join(out, "warm"), **warm, **common)
        compile_s = time.perf_counter() - t0
        t0, c0 = time.perf_counter(), time.process_time()
        rep = plfit.fit(start_cfg, obs, os.path.join(out, "fit"), **fit, **common)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    values = {k: float(p["value"]) for k, p in rep["params"].items()}
    rel = {k: round(abs(values[k] - v) / abs(v), 6) for k, v in truth.items()}
    return {
        "scene": scene,
        "device": device,
        "dtype": start_cfg.scene.dtype,
        "frames": obs.frames,
        "tracks": obs.tracks,
        "cpu_cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "generations": fit.get("generations"),
        "epochs": fit.get("epochs"),
        "wall_s": round(wall, 3),
        "cpu_s": round(cpu, 3),
        "load_avg_1min": round(os.getloadavg()[0], 2),
        "compile_s": round(compile_s, 3),
        "stage_wall_s": {k: round(v, 3) for k, v in rep["stage_wall_time"].items()},
        "evaluations": rep["evaluations"],
        "values": {k: round(v, 6) for k, v in values.items()},
        "truth": truth,
        "param_rel_error": rel,
        "max_param_rel_error": max(rel.values()),
        "gradient_stage_kept": rep["gradient_stage_kept"],
        "test_error_mm": _mm(rep["error"]["test"]),
        "test_error_start_mm": _mm(rep["error_nominal"]["test"]),
    }


def _mm(metres: float | None) -> float | None:
    return None if metres is None else round(1e3 * metres, 4)


def fit_rope(device: str | None = "cpu", quick: bool = False) -> dict:
    """The README's fit: fit_rope's stiffness and damping rate from 10 noisy, partly hidden tracks."""
    import pliant.scene as plscene

    frames = ["scene.frames=15"] if quick else []
    truth_cfg = plscene.load_scene("fit_rope", ["objects[0].material.stiffness=480", *frames])
    start_cfg = plscene.load_scene("fit_rope", frames)
    observe = {"tracks": 10, "noise": 0.001, "dropout": 0.3, "seed": 0}
    fit = {"per_element": "auto", "generations": 6 if quick else 40, "epochs": 2 if quick else 20}
    return fit_row("fit_rope", truth_cfg, start_cfg, ROPE_TRUTH, observe, fit, device)


def cloth17_config(quick: bool = False) -> SceneConfig:
    """The 17×17 cloth scene (quick: 7×7, 30 frames) with its true parameters."""
    import pliant.scene as plscene

    small = ["objects[0].nx=6", "objects[0].ny=6", "scene.frames=29"] if quick else []
    return plscene.parse_scene(CLOTH17, "cloth17", overrides=small)


def fit_cloth_17(device: str | None = "cpu", quick: bool = False) -> dict:
    """A 17×17 cloth's stiffness and damping rate (then per-spring k) from 60 noisy, partly hidden tracks."""
    from ..fit import apply_globals

    cfg = cloth17_config(quick)
    observe = {**CLOTH17_OBSERVE, "tracks": 20 if quick else CLOTH17_OBSERVE["tracks"]}
    fit = {"per_element": "stiffness", "generations": 4 if quick else 20, "epochs": 1}
    scene = "cloth_7x7" if quick else "cloth_17x17"
    return fit_row(scene, cfg, apply_globals(cfg, CLOTH17_START), CLOTH17_TRUTH, observe, fit, device)


BENCHMARKS: dict[str, Callable[..., dict]] = {"fit_rope": fit_rope, "fit_cloth_17": fit_cloth_17}


if __name__ == "__main__":
    print_rows(BENCHMARKS, sys.argv[1:])
