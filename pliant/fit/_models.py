"""Model choice (``pliant fit --models mass_spring,fem``): fit each candidate model of the same geometry to
the same observations and report their held-out errors side by side."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..io import Observations, atomic_write_text
from ._params import FitError
from ._resume import CHECKPOINT_FILE

if TYPE_CHECKING:
    from ..scene import SceneConfig

#: The object models a scene object may take (``[[objects]] model``).
MODELS = ("mass_spring", "fem", "pbd")


def _spacing(o: Any) -> float:  # any object kind: duck-typed on the fields its kind has
    """A typical element size [m] of object ``o`` (cell edge, segment length), for converting materials."""
    if getattr(o, "cells", None) is not None and getattr(o, "size", None) is not None:
        size = o.size if isinstance(o.size, (list, tuple)) else (o.size,) * 3
        return float(sum(s / c for s, c in zip(size, o.cells, strict=False)) / len(o.cells))
    if getattr(o, "n_segments", None):
        return float(o.length) / o.n_segments
    if getattr(o, "nx", None):
        size = o.size[0] if isinstance(o.size, (list, tuple)) else o.size
        return float(size) / o.nx
    return 0.05


def candidate(cfg: SceneConfig, model: str) -> SceneConfig:
    """A deep copy of scene ``cfg`` with every object given ``model``, its material converted where the
    candidate needs a value the scene does not give: a spring k = E·h from a Young's modulus, E = k / h from
    a spring constant (h the object's element size: a spring of a cubic lattice of spacing h carries about
    E·h), so that each candidate starts at the same stiffness scale.

    Raises:
        FitError: an unknown model.
    """
    if model not in MODELS:
        raise FitError(f"--models: unknown model {model!r}; choose from {', '.join(MODELS)}")
    cfg = cfg.model_copy(deep=True)
    for o in cfg.objects:
        mat, h = o.material, _spacing(o)
        if model == "fem" and mat.E is None:
            k = mat.stiffness if mat.stiffness is not None else (mat.Et or 100.0)
            mat.E = float(k) / h
        if model in ("mass_spring", "pbd") and mat.stiffness is None and mat.Et is None:
            mat.stiffness = float(mat.E) * h if mat.E is not None else 100.0
        o.model = model
    if model != "pbd" and cfg.solver.kind == "xpbd":
        cfg.solver.kind = None  # the solver follows the objects' model
    if model == "pbd":
        cfg.solver.kind = "xpbd"
    return cfg


def compare_models(
    cfg: SceneConfig, obs: Observations, models: list[str], out: str | Path, **fit_kwargs: Any
) -> dict[str, Any]:
    """Fit each of ``models`` (as :func:`candidate` makes them) with :func:`pliant.fit.fit` into
    ``out/<model>/`` and write ``out/models.json``: per model its held-out and training track errors [m],
    the nominal ones, the fitted values and the wall time [s], or the error that stopped it; ``best`` is the
    model with the lowest held-out error.

    Args:
        cfg: The scene (its objects' geometry is kept; their model and material are replaced).
        obs: The observations.
        models: Candidate model names (:data:`MODELS`), at least two.
        out: Output folder.
        **fit_kwargs: Passed to :func:`pliant.fit.fit` (params, generations, device, ...); ``resume``
            continues the models whose folder holds a checkpoint and starts the others.
    """
    from ..scene import SceneError
    from ._run import fit

    if len(models) < 2 or len(set(models)) != len(models):
        raise FitError(f"--models: name two or more different models, got {','.join(models)}")
    for m in models:
        candidate(cfg, m)  # unknown names fail before any fit runs
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows: dict[str, Any] = {}
    for m in models:
        t0 = time.perf_counter()
        # --resume: continue each model's fit that has a checkpoint; start the ones never begun
        kw = {**fit_kwargs, "resume": bool(fit_kwargs.get("resume")) and (out / m / CHECKPOINT_FILE).exists()}
        try:
            rep = fit(candidate(cfg, m), obs, out / m, **kw)
        except (FitError, SceneError, ValueError) as exc:
            rows[m] = {"failed": str(exc).splitlines()[0]}
            continue
        rows[m] = {
            "test": rep["error"]["test"],
            "train": rep["error"]["train"],
            "nominal_test": rep["error_nominal"]["test"],
            "values": {k: p["value"] for k, p in rep["params"].items()},
            "wall_time": time.perf_counter() - t0,
        }
    scored = {m: r["test"] for m, r in rows.items() if r.get("test") is not None and math.isfinite(r["test"])}
    report = {"models": rows, "best": min(scored, key=scored.__getitem__) if scored else None}
    atomic_write_text(out / "models.json", json.dumps(report, indent=2) + "\n")
    return report


def models_table(report: dict[str, Any]) -> list[str]:
    """Lines of the side-by-side table ``pliant fit --models`` prints (errors in mm)."""
    lines = [f"{'model':<12} {'held-out':>10} {'train':>10} {'nominal':>10}  fitted values"]
    for m, r in report["models"].items():
        if "failed" in r:
            lines.append(f"{m:<12} failed: {r['failed']}")
            continue
        vals = ", ".join(f"{k} {v:.4g}" for k, v in r["values"].items())
        errors = " ".join(f"{1e3 * r[k]:>8.3g}mm" for k in ("test", "train", "nominal_test"))
        lines.append(f"{m:<12} {errors}  {vals}" + ("  <- best" if m == report["best"] else ""))
    return lines


__all__ = ["MODELS", "candidate", "compare_models", "models_table"]
