"""Photometric system identification (issue 14's figure): the global stiffness of a synthetic cloth fitted
from three camera videos alone — no tracks, no point clouds; gradients image → Gaussians → binding →
particles → stiffness.

    python benchmarks/fit_photometric.py [--only NAME ...] [--json out.jsonl]

The "real" cloth (10×10 cells, 0.6 m, mass-spring, symplectic Euler, float64, pinned at two corners and
swinging down from horizontal; stiffness 200 N/m) is rendered by ``pl.fit.observe_images`` from 3 cameras at
96×72 px for 31 frames (1 s at 30 fps); the scene to fit starts at 1.6× the stiffness (320 N/m).
``pl.fit.fit`` runs CMA-ES on log stiffness (10 generations, photometric loss of the first 70 % of the
frames), then L-BFGS-B on the image gradient of the same loss through the whole training rollout (10
iterations).

Cases (each prints one JSON line: the recovered stiffness, its error, the image loss and PSNR on the held-out
frames, the wall time of each stage):
- clean: float32 images as rendered.
- noisy: 8-bit images with Gaussian pixel noise σ = 0.02 (about 5 grey levels).
- gradient_only: clean images, no CMA-ES: the image-gradient stage alone from 1.6× the stiffness.
- other_splats: the images drawn with other Gaussians than the fit's (3 smaller splats per triangle, so
  other sizes and texture samples; frame-0 PSNR of the fit's splats against them 33.7 dB): a
  model-appearance mismatch, one step away from the inverse crime.

This is pliant → pliant synthetic data, made with the same Gaussians and the same renderer the fit uses (an
"inverse crime"): it measures the gradient path and the identifiability of the stiffness from images.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time

import pliant as pl
import pliant.fit
import pliant.scene
from pliant.fit._params import apply_globals

CLOTH = """
[scene]
name = "photometric_cloth"
frame_dt = 0.03333333333333333
substeps = 30
frames = 30
dtype = "float64"
device = "cpu"
[[objects]]
kind = "cloth"
model = "mass_spring"
nx = 10
ny = 10
size = 0.6
origin = [-0.3, 0.6, -0.3]
plane = "xz"
mass = 0.5
pin = "top-corners"
[objects.material]
stiffness = 200.0
damping = 0.002
[solver]
kind = "force"
integrator = "SymplecticEuler"
damping_rate = 0.5
"""

TRUTH, START = 200.0, 320.0


def run(name: str, noise: float, uint8: bool, generations: int, obs_per_triangle: int = 1) -> dict:
    cfg = pl.scene.parse_scene(CLOTH)
    t0 = time.perf_counter()
    obs = pl.fit.observe_images(
        pl.scene.build_scene(cfg),
        cameras=3,
        image_size=(96, 72),
        noise=noise,
        uint8=uint8,
        seed=1,
        per_triangle=obs_per_triangle,
    )
    t_obs = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as out:
        rep = pl.fit.fit(
            apply_globals(cfg, {"stiffness": START}),
            obs,
            out,
            params=["stiffness"],
            generations=generations,
            epochs=10,
            optimizer="lbfgs",
            progress=False,
            video=False,
            # the table in docs/gaussians.md measures the physics from pliant's own splats: no appearance
            # stage (the MuJoCo footage's figures there measure it)
            appearance=False,
        )
    k = rep["params"]["stiffness"]["value"]
    ph = rep["photometric"]
    return {
        "case": name,
        "truth": TRUTH,
        "start": START,
        "stiffness": k,
        "error_rel": abs(k - TRUTH) / TRUTH,
        "within_5pct": abs(k - TRUTH) <= 0.05 * TRUTH,
        "image_loss_test": ph["fitted"]["loss_test"],
        "image_loss_test_nominal": ph["nominal"]["loss_test"],
        "psnr_test_db": ph["fitted"].get("psnr_test_db"),
        "psnr_test_db_nominal": ph["nominal"].get("psnr_test_db"),
        "generations": generations,
        "evaluations": rep["evaluations"],
        "stage_wall_time_s": rep["stage_wall_time"],
        "fit_wall_time_s": rep["wall_time"],
        "observe_wall_time_s": t_obs,
        "gaussians": ph["gaussians"],
        "cameras": ph["cameras"],
        "image_size": ph["image_size"],
        "obs_gaussians_per_triangle": obs_per_triangle,
        "frames": rep["frames"],
        "train_frames": rep["train_frames"],
    }


CASES = {
    "clean": (0.0, False, 10),
    "noisy": (0.02, True, 10),
    "gradient_only": (0.0, False, 0),
    "other_splats": (0.0, False, 10, 3),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", choices=sorted(CASES), help="run only these cases")
    ap.add_argument("--json", help="append the JSON lines to this file")
    args = ap.parse_args()
    for name in args.only or list(CASES):
        row = run(name, *CASES[name])
        line = json.dumps(row)
        print(line, flush=True)
        if args.json:
            with open(args.json, "a") as f:
                f.write(line + "\n")


if __name__ == "__main__":
    main()
