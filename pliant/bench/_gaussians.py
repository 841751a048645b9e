"""Gaussian-splat rasteriser throughput: forward and forward + backward, Gaussians × pixels per second."""

from __future__ import annotations

import time

import numpy as np


def gaussians_raster(device: str | None = None, quick: bool = False) -> dict:
    """Render 5000 Gaussians at 320 x 240 (500 at 64 x 48 with quick), forward and with gradients."""
    import warp as wp

    from .._warp import resolve_device
    from ..gaussians import Camera, Gaussians, render

    dev = resolve_device(device)
    n, W, H, reps = (500, 64, 48, 3) if quick else (5000, 320, 240, 5)
    rng = np.random.default_rng(0)
    g = Gaussians.from_values(
        rng.uniform(-0.5, 0.5, (n, 3)),
        scales=rng.uniform(0.005, 0.03, (n, 3)),
        rotations=rng.normal(size=(n, 4)),
        opacities=rng.uniform(0.3, 0.9, n),
        colors=rng.uniform(0, 1, (n, 3)),
        sh_degree=3,
        device=dev,
        requires_grad=True,
    )
    cam = Camera.look_at([0.0, 0.4, 2.0], [0.0, 0.0, 0.0], width=W, height=H)
    grad_c = wp.full((H, W), wp.vec3(1.0, 1.0, 1.0), dtype=wp.vec3, device=dev)

    def forward():
        out = render(g, cam)
        wp.synchronize_device(dev)
        return out

    def both():
        tape = wp.Tape()
        with tape:
            c, _, _ = render(g, cam)
        tape.backward(grads={c: grad_c})
        wp.synchronize_device(dev)

    t0 = time.perf_counter()
    out = forward()
    both()  # warm-up: kernel compilation or cache load
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(reps):
        forward()
    fwd = (time.perf_counter() - t0) / reps
    t0 = time.perf_counter()
    for _ in range(reps):
        both()
    fb = (time.perf_counter() - t0) / reps
    coverage = float(np.mean(out.alpha.numpy() > 0.5))
    return {
        "scene": f"random_splats_{n}",
        "device": dev,
        "gaussians": n,
        "width": W,
        "height": H,
        "forward_s": round(fwd, 5),
        "forward_backward_s": round(fb, 5),
        "compile_s": round(compile_s, 3),
        "gaussian_pixels_per_s_forward": float(f"{n * W * H / fwd:.4g}"),
        "gaussian_pixels_per_s_forward_backward": float(f"{n * W * H / fb:.4g}"),
        "sanity_covered_fraction": round(coverage, 4),
    }


BENCHMARKS = {"gaussians_raster": gaussians_raster}
