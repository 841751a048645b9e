"""Known-truth fitting figures (pliant → pliant, synthetic data): how well `pliant fit` recovers the
parameters that made its own observations, and how long a 17×17 cloth takes.

    python benchmarks/fit_known_truth.py [--only NAME ...] [--json out.jsonl]

Cases (each prints one JSON line):
- rope_clean: fit_rope, all 13 particles tracked, no noise; start at 1.6× stiffness and 0.5× damping rate.
- rope_noisy: the same with 1 mm noise and 30 % of the tracks hidden at each frame.
- rope_dashpot: stiffness and the dashpot γ (instead of the damping rate).
- fem_box: a 2×2×2-cell FEM box dropped on the ground; start at 2× E and ν = 0.2 (truth 0.35).
- cloth17: 17×17 mass-spring cloth, 90 frames, 60 tracks (1 mm noise, 30 % hidden): `pl.fit.fit` with
  CMA-ES (stiffness, damping rate; 20 generations) then one Adam epoch on per-spring stiffness, outputs
  but no video; the wall time of the whole fit (the goal is ≤ 2 min on one core).
- two_materials: an 8×8 cloth whose left springs are 100 N/m and right ones 1000 N/m, every particle
  tracked; 15 Adam epochs of per-spring stiffness with the total-variation prior (smoothness 1e-4); the
  fraction of springs on the right side of √(100·1000). two_materials_no_prior: the same without the prior.
- fem_box_noisy, xpbd_noisy: 1 mm noise and 30 % of the tracks hidden at each frame.
- xpbd: an XPBD cloth's compliance from 3× back.
- points_topology: a point cloud's spring radius and neighbour count (CMA-ES; Jaccard index of the springs).
This is synthetic data from pliant itself: it checks the optimisers and the plumbing, not model mismatch.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import pliant as pl
import pliant.fit
import pliant.scene
from pliant.bench._fit import CLOTH17, CLOTH17_OBSERVE, CLOTH17_START, CLOTH17_TRUTH

FEM = """
[scene]
name = "fem_box"
frame_dt = 0.03333333333333333
substeps = 40
frames = 30
dtype = "float64"
[[objects]]
kind = "soft_box"
model = "fem"
cells = [2, 2, 2]
size = [0.2, 0.2, 0.2]
origin = [0.0, 0.25, 0.0]
density = 500.0
velocity = [0.5, 0.0, 0.0]
[objects.material]
E = 2e4
nu = 0.35
[ground]
height = 0.0
friction = 0.5
[solver]
integrator = "SymplecticEuler"
damping_rate = 1.0
"""


def _rel(a: float, b: float) -> float:
    return abs(a - b) / abs(b)


def _case(
    cfg, truth: dict, start: dict, *, tracks: int, noise: float, dropout: float, generations: int, **kw
):
    obs = pl.fit.observe(
        pl.scene.build_scene(cfg, device="cpu"), tracks=tracks, noise=noise, dropout=dropout, seed=3
    )
    p = pl.fit.Problem(pl.fit.apply_globals(cfg, start), obs, params=list(truth), device="cpu", **kw)
    t0 = time.perf_counter()
    r = pl.fit.cmaes(p, generations=generations)
    wall = time.perf_counter() - t0
    x = p.simulate(p.build(r.values), p.frames)
    x0 = p.simulate(p.build(p.nominal), p.frames)
    return {
        "values": r.values,
        "truth": truth,
        "rel_error": {k: _rel(r.values[k], v) for k, v in truth.items()},
        "abs_error": {k: abs(r.values[k] - v) for k, v in truth.items()},
        "test_error_m": p.split_errors(x)["test"],
        "test_error_start_m": p.split_errors(x0)["test"],
        "evaluations": r.evaluations,
        "wall_s": wall,
    }


def rope(noise: float, dropout: float, damping: str = "damping_rate") -> dict:
    cfg = pl.scene.load_scene("fit_rope")
    cfg.scene.dtype = "float64"
    truth = {"stiffness": 300.0, damping: 0.5 if damping == "damping_rate" else 0.01}
    start = {"stiffness": 480.0, damping: 0.5 * truth[damping]}
    return _case(cfg, truth, start, tracks=13, noise=noise, dropout=dropout, generations=40)


def fem_box(noise: float = 0.0, dropout: float = 0.0) -> dict:
    cfg = pl.scene.parse_scene(FEM)
    return _case(
        cfg,
        {"E": 2e4, "nu": 0.35},
        {"E": 4e4, "nu": 0.2},
        tracks=27,
        noise=noise,
        dropout=dropout,
        generations=30,
    )


def cloth17() -> dict:
    import tempfile

    cfg = pl.scene.parse_scene(CLOTH17)  # shared with the `pliant bench fit_cloth_17` row
    obs = pl.fit.observe(pl.scene.build_scene(cfg, device="cpu"), **CLOTH17_OBSERVE)
    wrong = pl.fit.apply_globals(cfg, CLOTH17_START)
    with tempfile.TemporaryDirectory() as out:
        rep = pl.fit.fit(
            wrong,
            obs,
            out,
            params=list(CLOTH17_TRUTH),
            per_element="stiffness",
            generations=20,
            epochs=1,
            device="cpu",
            progress=False,
            video=False,
        )
    v = {k: p["value"] for k, p in rep["params"].items()}
    return {
        "values": v,
        "rel_error": {k: _rel(v[k], t) for k, t in CLOTH17_TRUTH.items()},
        "test_error_m": rep["error"]["test"],
        "test_error_start_m": rep["error_nominal"]["test"],
        "gradient_stage_kept": rep["gradient_stage_kept"],
        "stage_wall_s": rep["stage_wall_time"],
        "evaluations": rep["evaluations"],
        "total_s": rep["wall_time"],
        "frames": obs.frames,
        "tracks": obs.tracks,
    }


TWO = """
[scene]
name = "two_materials"
frame_dt = 0.03333333333333333
substeps = 50
frames = 30
dtype = "float64"
[[objects]]
kind = "cloth"
nx = 8
ny = 8
size = 0.6
origin = [-0.3, 0.8, -0.3]
plane = "xz"
mass = 0.5
pin = "top-corners"
[objects.material]
stiffness = 300.0
[solver]
integrator = "SymplecticEuler"
damping_rate = 0.5
"""


def two_materials(epochs: int = 15, smoothness: float = 1e-4) -> dict:
    """Springs left of x = 0 at 100 N/m, right of it at 1000 N/m; per-spring Adam from a uniform 300 N/m,
    with the total-variation prior ``smoothness`` over springs that share a particle (0: none). The springs
    that lie on the seam x = 0 (8 of 272) are counted as the left material."""
    cfg = pl.scene.parse_scene(TWO)
    truth = pl.scene.build_scene(cfg, device="cpu")
    m = truth.model
    mid = m.particle_q.numpy()[m.spring_indices.numpy()].mean(axis=1)[:, 0]
    right = mid > 0.0
    m.spring_stiffness.assign(np.where(right, 1000.0, 100.0))
    obs = pl.fit.observe(truth, tracks=m.particle_count)
    p = pl.fit.Problem(cfg, obs, params=[], per_element="stiffness", device="cpu")
    t0 = time.perf_counter()
    r = pl.fit.gradient_stage(p, {}, iterations=epochs, lr=0.05, smoothness=smoothness)
    k = r.per_element["model.spring_stiffness"]
    return {
        "right_side_fraction": float(np.mean((k > np.sqrt(100.0 * 1000.0)) == right)),
        "median_left": float(np.median(k[~right])),
        "median_right": float(np.median(k[right])),
        "epochs": epochs,
        "smoothness": smoothness,
        "wall_s": time.perf_counter() - t0,
    }


XPBD = """
[scene]
name = "xpbd_cloth"
frame_dt = 0.03333333333333333
substeps = 10
frames = 30
dtype = "float64"
[[objects]]
kind = "cloth"
model = "pbd"
nx = 6
ny = 6
size = 0.6
origin = [-0.3, 0.8, -0.3]
plane = "xz"
mass = 0.2
pin = "top-corners"
[objects.material]
compliance = 2e-3
[solver]
kind = "xpbd"
iterations = 20
damping_rate = 0.5
"""


def xpbd(noise: float = 0.0, dropout: float = 0.0) -> dict:
    """XPBD cloth: the distance constraints' compliance α from 3× back (its "stiffness" 1/α)."""
    cfg = pl.scene.parse_scene(XPBD)
    return _case(
        cfg,
        {"compliance": 2e-3},
        {"compliance": 6e-3},
        tracks=30,
        noise=noise,
        dropout=dropout,
        generations=30,
    )


POINTS = """
[scene]
name = "points_drop"
frame_dt = 0.03333333333333333
substeps = 40
frames = 30
dtype = "float64"
[[objects]]
kind = "points"
shape = "sphere"
size = [0.24, 0.24, 0.24]
spacing = 0.05
jitter = 0.2
origin = [0.0, 0.2, 0.0]
mass = 0.3
radius = 0.085
max_neighbors = 8
[objects.material]
stiffness = 200.0
damping = 0.02
[ground]
height = 0.0
friction = 0.5
[solver]
integrator = "SymplecticEuler"
damping_rate = 0.5
"""


def _springs(cfg) -> set:
    m = pl.scene.build_scene(cfg, device="cpu").model
    return {tuple(sorted(e)) for e in m.spring_indices.numpy().reshape(-1, 2).tolist()}


def points_topology() -> dict:
    """A PhysTwin-style point cloud (radius springs) dropped on the ground: its spring radius and neighbour
    count (topology: CMA-ES only; every candidate rebuilds the springs) from 0.75× and 1.5× back. The loss is
    piecewise constant in both (a spring appears when the radius passes a pair's distance), so the figure
    that matters is whether the fitted topology is the true one: the Jaccard index of the spring sets."""
    cfg = pl.scene.parse_scene(POINTS)
    row = _case(
        cfg,
        {"radius": 0.085, "neighbours": 8.0},
        {"radius": 0.064, "neighbours": 12.0},
        tracks=30,
        noise=0.0,
        dropout=0.0,
        generations=30,
    )
    a, b = _springs(cfg), _springs(pl.fit.apply_globals(cfg, row["values"]))
    row["springs_true"], row["springs_fitted"] = len(a), len(b)
    row["topology_jaccard"] = len(a & b) / len(a | b)
    return row


CASES = {
    "rope_clean": lambda: rope(0.0, 0.0),
    "rope_noisy": lambda: rope(0.001, 0.3),
    "rope_dashpot": lambda: rope(0.0, 0.0, "damping"),
    "fem_box": fem_box,
    "fem_box_noisy": lambda: fem_box(0.001, 0.3),
    "xpbd": xpbd,
    "xpbd_noisy": lambda: xpbd(0.001, 0.3),
    "points_topology": points_topology,
    "cloth17": cloth17,
    "two_materials": two_materials,
    "two_materials_no_prior": lambda: two_materials(smoothness=0.0),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--only", nargs="*", choices=list(CASES), help="cases to run (default: all)")
    ap.add_argument("--json", help="append the JSON lines to this file")
    args = ap.parse_args()
    for name in args.only or CASES:
        row = {"case": name, **CASES[name]()}
        line = json.dumps(row, default=lambda v: v.item() if isinstance(v, np.generic) else str(v))
        print(line, flush=True)
        if args.json:
            with open(args.json, "a") as f:
                f.write(line + "\n")


if __name__ == "__main__":
    main()
