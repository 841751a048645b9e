"""Benchmark of the headless preview renderer (pliant.render.Renderer).

Renders a waving 20k-triangle cloth (101 x 101 grid) at 640x480 with the default settings
(smooth shading, checkerboard ground, ground shadow) and prints one JSON line:

    {"triangles": 20000, "width": 640, "height": 480, "frames": 30, "ms_per_frame": ..., ...}

``ms_per_frame`` is the median over the timed frames, after a first frame that compiles the
Warp kernels (``compile_s``; measured with an empty kernel cache unless ``--warm-cache``).
NumPy/BLAS are pinned to one thread; Warp CPU kernels are single-threaded anyway.

Usage: python benchmarks/bench_render.py [--frames 30] [--grid 101] [--warm-cache]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one CPU core; must precede the NumPy import

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402


def cloth(grid: int, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Waving square cloth, 1 m wide: positions [T, grid^2, 3] and faces [2 (grid-1)^2, 3]."""
    u, v = np.meshgrid(np.linspace(-0.5, 0.5, grid), np.linspace(-0.5, 0.5, grid))
    frames = []
    for k in range(n_frames):
        ph = 2.0 * np.pi * k / n_frames
        y = 0.6 + 0.08 * np.sin(6 * u + ph) * np.cos(5 * v - ph) - 0.3 * (u**2 + v**2)
        frames.append(np.stack([u, y, v], -1).reshape(-1, 3))
    idx = np.arange(grid * grid).reshape(grid, grid)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int32)
    return np.asarray(frames), faces


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=30, help="timed frames (>= 20)")
    ap.add_argument("--grid", type=int, default=101, help="vertices per cloth side")
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--warm-cache", action="store_true", help="use the normal Warp kernel cache")
    args = ap.parse_args()

    import warp as wp

    wp.config.log_level = wp.LOG_WARNING  # keep stdout to the one JSON line
    if not args.warm_cache:
        wp.config.kernel_cache_dir = tempfile.mkdtemp(prefix="pliant_bench_warp_")

    from pliant.render import Camera, Renderer

    n_frames = max(args.frames, 20)
    x, faces = cloth(args.grid, n_frames)
    cam = Camera.fit(x, width=args.width, height=args.height)
    renderer = Renderer(cam)

    t0 = time.perf_counter()
    renderer.render(x[0], faces)
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    renderer.render(x[0], faces)  # same frame again: compile-free cost of frame 0
    compile_s = first - (time.perf_counter() - t0)

    times = []
    for k in range(n_frames):
        t0 = time.perf_counter()
        img = renderer.render(x[k], faces)
        times.append(time.perf_counter() - t0)
    assert img.shape == (args.height, args.width, 3)

    pts = x[0][:: max(1, len(x[0]) // 5000)]  # ~5k particles as shaded spheres
    renderer.render(pts)
    ptimes = []
    for _ in range(10):
        t0 = time.perf_counter()
        renderer.render(pts, point_radius=0.006)
        ptimes.append(time.perf_counter() - t0)

    ms = np.asarray(times) * 1e3
    print(
        json.dumps(
            {
                "triangles": int(len(faces)),
                "width": args.width,
                "height": args.height,
                "frames": n_frames,
                "ms_per_frame": round(float(np.median(ms)), 2),
                "ms_p90": round(float(np.percentile(ms, 90)), 2),
                "ms_min": round(float(ms.min()), 2),
                "compile_s": round(compile_s, 2),
                "kernel_cache": "warm" if args.warm_cache else "empty",
                "particles": int(len(pts)),
                "ms_per_frame_particles": round(float(np.median(ptimes)) * 1e3, 2),
                "device": "cpu",
            }
        )
    )


if __name__ == "__main__":
    main()
