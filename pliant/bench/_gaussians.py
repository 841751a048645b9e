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


def gaussians_visual_correction(quick: bool = False) -> dict:
    """Drift of a cloth simulated with 3x too soft springs, with and without visual correction.

    A 8 x 8-cell cloth pinned at two corners falls and swings (k = 300 N/m "real", 100 N/m simulated). The
    real twin is rendered by 3 cameras at 96 x 72 each frame; one Gaussian per particle, LBS binding (k = 4).
    The corrector uses Embodied Gaussians' settings (3 Adam steps, lr 1.5e-3, k_p = 4 N/m) on the images of
    the current time. Reports the mean particle distance to the real twin over the frames [m].
    """
    import warp as wp

    from .. import energies, integrators, solvers
    from ..gaussians import Camera, Gaussians, VisualCorrector, bind, render
    from ..model import ModelBuilder
    from ..sim import Simulator

    frames = 10 if quick else 30

    def make(k: float):
        b = ModelBuilder()
        b.add_cloth_grid(
            nx=8, ny=8, size=1.0, mass=0.2, stiffness=k, bend_stiffness=k / 50, damping=0.002,
            origin=(-0.5, 0.5, -0.5), plane="xz", pin=[0, 8],
        )  # fmt: skip
        m = b.finalize(device="cpu", dtype="float32")
        s = solvers.ForceSolver(
            m, energies.mass_spring(), integrators.SymplecticEuler(), damping_rate=0.5, contact=False
        )
        return Simulator(m, s, frame_dt=1 / 30, substeps=40)

    real = make(300.0)
    X = real.model.particle_q.numpy().astype(np.float64)
    rng = np.random.default_rng(0)
    g = Gaussians.from_values(X, scales=0.04, opacities=0.8, colors=rng.uniform(0, 1, X.shape), device="cpu")
    binding = bind(g, X, method="lbs", k=4, neighbours=9)
    cams = [
        Camera.look_at([2.2 * np.sin(a), 1.2, 2.2 * np.cos(a)], [0, 0.1, 0], width=96, height=72)
        for a in (0.3, 2.4, 4.5)
    ]
    truth, images = [], []
    for _ in range(frames):
        real.step_frame()
        x = real.state_0.particle_q
        truth.append(x.numpy().copy())
        images.append([render(binding.deform(x), c).colour.numpy() for c in cams])

    def drift(correct: bool) -> np.ndarray:
        sim = make(100.0)
        vc = VisualCorrector(binding, cams)
        out = []
        for f in range(frames):
            sim.control.particle_f.zero_()
            if correct and f > 0:  # images of the current time: after f frames
                vc.apply(sim.state_0.particle_q, sim.control, images[f - 1])
            sim.step_frame()
            out.append(np.linalg.norm(sim.state_0.particle_q.numpy() - truth[f], axis=1).mean())
        return np.asarray(out)

    t0 = time.perf_counter()
    plain = drift(False)
    corrected = drift(True)
    wall = time.perf_counter() - t0
    wp.synchronize()
    return {
        "scene": "cloth_8x8_pinned_k300_vs_k100",
        "device": "cpu",
        "frames": frames,
        "cameras": 3,
        "mean_drift_uncorrected_m": round(float(plain.mean()), 5),
        "mean_drift_corrected_m": round(float(corrected.mean()), 5),
        "final_drift_uncorrected_m": round(float(plain[-1]), 5),
        "final_drift_corrected_m": round(float(corrected[-1]), 5),
        "drift_reduction": round(float(1.0 - corrected.mean() / plain.mean()), 4),
        "wall_s": round(wall, 3),
    }


BENCHMARKS = {
    "gaussians_raster": gaussians_raster,
    "gaussians_visual_correction": gaussians_visual_correction,
}
