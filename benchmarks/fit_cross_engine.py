"""Cross-engine fitting figures: pliant's scenes fitted to observations made by Newton 1.8 (SYNTHETIC data
from another engine, standing in for real measurements through a genuine model mismatch).

    python benchmarks/fit_cross_engine.py [--only cloth beam] [--json out.jsonl]

The observations (``benchmarks/peers/data/newton_{cloth,beam}.npz``, 40 tracks, 61 frames at 30 fps) are made
by ``benchmarks/peers/observe_newton.py`` in its own venv (README there); they are committed (about 30 kB
each), so this script needs pliant only. For each object it runs ``pl.fit.fit``: CMA-ES over the global
material, then Adam on a per-element parameter, training on the first 70 % of the frames, and prints one
JSON line with the mean track error [m] on the held-out last 30 % for

- ``nominal``: the scene's material converted from Newton's (E·t and ν of the membrane; E and ν of the
  tets) and no velocity damping (Newton's SemiImplicit has none);
- ``global``: after the CMA-ES stage alone;
- ``fitted``: after both stages (the per-element values are kept only when they lower the training loss).

Goals (issue 13): fitted ≤ 0.3 × nominal on the held-out frames, and fitted ≤ global there.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

import pliant as pl
import pliant.fit
import pliant.io
import pliant.scene

DATA = Path(__file__).resolve().parent / "peers" / "data"

# The scenes are committed beside the observations (peers/data/newton_{cloth,beam}.toml), so that
# `pliant fit` runs on them too. Cloth: observe_newton.py's 12 × 12 cells, 0.6 m, corners of largest z held,
# 0.1 kg; Newton tri_ke = μt = 40 N/m, tri_ka = λt = 40 N/m: plane-stress E·t = 4μt(μ+λ)/(2μ+λ) = 106.7 N/m,
# ν = λ/(2μ+λ) = 1/3. Beam: 6 × 2 × 2 cells, 0.36 × 0.1 × 0.1 m centred at (0, 0.6, 0), the x = −0.18 face
# clamped; ρ = 1000 kg/m³, E = 2e5 Pa, ν = 0.3 (Newton: Smith 2018 tets with viscosity k_damp = 100 Pa s).
# Both start without velocity damping (Newton's SemiImplicit has none).

CASES = {
    "cloth": ("newton_cloth", ["Et", "damping_rate"], "stiffness"),
    "beam": ("newton_beam", ["E", "nu", "damping_rate"], "E"),
}


def run(name: str, generations: int = 20, epochs: int = 10, lr: float = 0.01) -> dict:
    """Fit one case; returns its figures (errors in metres)."""
    stem, params, per_element = CASES[name]
    cfg = pl.scene.load_scene(DATA / f"{stem}.toml")
    obs = pl.io.Observations.load(DATA / f"{stem}.npz")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as out:
        rep = pl.fit.fit(
            cfg,
            obs,
            out,
            params=params,
            per_element=per_element,
            generations=generations,
            epochs=epochs,
            lr=lr,
            device="cpu",
            progress=False,
            video=False,
        )
    wall = time.perf_counter() - t0
    values = {k: p["value"] for k, p in rep["params"].items()}
    p = pl.fit.Problem(cfg, obs, params=params, device="cpu")
    glob = p.split_errors(p.simulate(p.build(values), p.frames))
    nominal, fitted = rep["error_nominal"]["test"], rep["error"]["test"]
    return {
        "data": "synthetic, cross-engine (Newton 1.8 SolverSemiImplicit -> pliant)",
        "values": values,
        "start": {k: v["start"] for k, v in rep["params"].items()},  # a damping rate of 0 starts at 0.14
        "test_error_m": {"nominal": nominal, "global": glob["test"], "fitted": fitted},
        "train_error_m": {
            "nominal": rep["error_nominal"]["train"],
            "global": glob["train"],
            "fitted": rep["error"]["train"],
        },
        "ratio_fitted_to_nominal": fitted / nominal,
        "gradient_not_worse_on_test": bool(fitted <= glob["test"] * (1 + 1e-9)),
        "gradient_stage_kept": rep["gradient_stage_kept"],
        "evaluations": rep["evaluations"],
        "stage_wall_s": rep["stage_wall_time"],
        "total_s": wall,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", choices=list(CASES), help="cases to run (default: all)")
    ap.add_argument("--json", help="append the JSON lines to this file")
    args = ap.parse_args()
    for name in args.only or CASES:
        row = {"case": name, **run(name)}
        line = json.dumps(row, default=lambda v: v.item() if isinstance(v, np.generic) else str(v))
        print(line, flush=True)
        if args.json:
            with open(args.json, "a") as f:
                f.write(line + "\n")


if __name__ == "__main__":
    main()
