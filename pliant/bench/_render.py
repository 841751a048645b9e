"""Renderer benchmark: frames per second of the headless preview rasterizer on a waving cloth."""

from __future__ import annotations

import time

import numpy as np


def render_cloth(quick: bool = False) -> dict:
    """Render a waving n x n cloth (64 x 64 cells, 16 x 16 with quick) at 640 x 480; frames per second."""
    from ..geometry import cloth_grid
    from ..render import Camera, Renderer

    n = 16 if quick else 64
    frames = 5 if quick else 30
    g = cloth_grid(n, n, size=1.0, origin=(-0.5, 0.5, -0.5), plane="xz")
    base = g.points
    x = np.empty((frames, *base.shape))
    for k in range(frames):  # a travelling wave: every frame differs, as in a simulation
        x[k] = base
        x[k, :, 1] += 0.1 * np.sin(6.0 * base[:, 0] + 0.3 * k) * np.cos(4.0 * base[:, 2])
    cam = Camera.fit(x, width=640, height=480)
    r = Renderer(cam, ground=0.0)
    t0 = time.perf_counter()
    first = r.render(x[0], g.triangles)  # warm-up: kernel compilation or cache load
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    for k in range(frames):
        img = r.render(x[k], g.triangles)
    wall = time.perf_counter() - t0
    changed = float(np.mean(np.any(img != first, axis=2)))
    return {
        "scene": f"render_cloth_{n}x{n}",
        "device": "cpu",
        "triangles": int(len(g.triangles)),
        "frames": frames,
        "width": 640,
        "height": 480,
        "wall_s": round(wall, 4),
        "compile_s": round(compile_s, 4),
        "frames_per_s": round(frames / wall, 2),
        "sanity_changed_pixel_fraction": round(changed, 4),
    }


BENCHMARKS = {"render_cloth": render_cloth}
