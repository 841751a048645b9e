"""Benchmark of pl.gaussians.splats_from_particles at the size of issue 37's footage.

A 0.4 m × 5 cm × 5 cm beam of small opaque splats (a 5 cm colour stripe along it) seen by four cameras of
200×150 px (alternately above and below it, 0.6 m away) over a grey background; the points are a 1 cm grid
filling a box 1.2× the beam (carved slightly too large), particle radius 5 mm. Prints one JSON line with
the wall and CPU seconds, the counts pruned (of the true points and of the extra ones), PSNR and IoU before
and after. NumPy/BLAS are pinned to one thread; Warp CPU kernels are single-threaded anyway.

Usage: python benchmarks/bench_splat_init.py [--iterations 200] [--visual-iterations 100] [--device cpu]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one CPU core; must precede the NumPy import

import argparse  # noqa: E402
import json  # noqa: E402

import numpy as np  # noqa: E402

HALF = np.array([0.2, 0.025, 0.025])  # the beam's half extents [m]


def scene():
    """(cameras, images, masks, points, true) of the benchmark."""
    from pliant.gaussians import Camera, Gaussians, render

    h = 0.005
    axes = [np.arange(-a + h / 2, a, h) for a in HALF]
    X = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    stripe = (np.floor(X[:, 0] / 0.05) % 2 == 0)[:, None]
    truth = Gaussians.from_values(
        X, scales=0.5 * h, opacities=0.95, colors=np.where(stripe, [0.8, 0.35, 0.2], [0.9, 0.8, 0.6])
    )
    cams = []
    for i, t in enumerate(np.linspace(0, 2 * np.pi, 4, endpoint=False) + 0.3):
        eye = [0.6 * np.sin(t), 0.25 if i % 2 == 0 else -0.15, 0.6 * np.cos(t)]
        cams.append(Camera.look_at(eye, [0, 0, 0], width=200, height=150))
    images, masks = [], []
    for c in cams:
        colour, alpha, _ = render(truth, c, (0.3, 0.3, 0.35))
        images.append(colour.numpy())
        masks.append(alpha.numpy() > 0.5)
    axes = [np.arange(-a, a + 1e-9, 0.01) for a in HALF * 1.2]
    points = np.stack(np.meshgrid(*[a - a.mean() for a in axes], indexing="ij"), -1).reshape(-1, 3)
    return cams, images, masks, points, np.all(np.abs(points) <= HALF, axis=1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iterations", type=int, default=200)
    ap.add_argument("--visual-iterations", type=int, default=100)
    ap.add_argument("--device", default="cpu")
    a = ap.parse_args()
    import warp as wp

    from pliant.gaussians import splats_from_particles

    wp.config.quiet = True
    cams, images, masks, points, true = scene()
    kw = dict(radius=0.005, device=a.device)
    splats_from_particles(
        points[:50], cams, images, masks, iterations=2, visual_iterations=2, **kw
    )  # compile
    res = splats_from_particles(
        points, cams, images, masks, iterations=a.iterations, visual_iterations=a.visual_iterations, **kw
    )
    out = {
        "points": len(points),
        "wall_s": round(res.wall_time, 2),
        "cpu_s": round(res.cpu_time, 2),
        "timings_s": {k: round(v, 2) for k, v in res.timings.items()},
        "pruned": res.pruned,
        "buried_kept": res.buried,
        "true_removed": round(float(1 - res.kept[true].mean()), 4),
        "extra_removed": round(float(1 - res.kept[~true].mean()), 4),
        "psnr": [round(res.psnr_before, 2), round(res.psnr_particles, 2), round(res.psnr_after, 2)],
        "iou": [round(res.iou_before, 4), round(res.iou_particles, 4), round(res.iou_after, 4)],
        "visual_splats": res.gaussians.count,
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
