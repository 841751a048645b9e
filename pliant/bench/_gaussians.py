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


def _cloth_sim(k: float, implicit: bool = False):
    """The 8 x 8-cell cloth (1 m, 0.2 kg, pinned at two corners) with springs of stiffness ``k`` [N/m]:
    symplectic Euler, 40 substeps per frame, or backward Euler with 4 (``implicit``)."""
    from .. import energies, integrators, solvers
    from ..model import ModelBuilder
    from ..sim import Simulator

    b = ModelBuilder()
    b.add_cloth_grid(
        nx=8, ny=8, size=1.0, mass=0.2, stiffness=k, bend_stiffness=k / 50, damping=0.002,
        origin=(-0.5, 0.5, -0.5), plane="xz", pin=[0, 8],
    )  # fmt: skip
    m = b.finalize(device="cpu", dtype="float32")
    integrator = integrators.BackwardEuler() if implicit else integrators.SymplecticEuler()
    s = solvers.ForceSolver(m, energies.mass_spring(), integrator, damping_rate=0.5, contact=False)
    return Simulator(m, s, frame_dt=1 / 30, substeps=4 if implicit else 40)


def _cloth_sim_implicit(k: float):
    """:func:`_cloth_sim` with backward Euler."""
    return _cloth_sim(k, implicit=True)


def _beam_sim(k_s: float):
    """A soft beam of 7 x 3 x 3 particles (0.1 m apart, 0.3 kg) clamped at one end, held together by
    overlapping 3 x 3 x 3 shape-matching clusters of stiffness k_S under XPBD."""
    from ..constraints import ShapeMatching
    from ..model import ModelBuilder
    from ..sim import Simulator
    from ..solvers import XPBD

    nx, ny, nz = 7, 3, 3
    idx = np.arange(nx * ny * nz).reshape(nx, ny, nz)
    grid = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"), -1)
    X = grid.reshape(-1, 3) * 0.1 + np.array([-0.3, 0.3, -0.1])
    b = ModelBuilder()
    b.add_particles(X, 0.3 / len(X), radius=0.02)
    b.pin(idx[0].reshape(-1))
    m = b.finalize(device="cpu", dtype="float32")
    clusters = [idx[i : i + 3].reshape(-1) for i in range(nx - 2)]
    s = XPBD(m, iterations=4, constraints=[ShapeMatching(clusters, stiffness=k_s)], damping=0.5)
    return Simulator(m, s, frame_dt=1 / 30, substeps=10)


def visual_correction_drift(make, k_true: float, k_sim: float, frames: int, **corrector) -> dict:
    """Mean particle drift from a "real" twin (parameter ``k_true``) of a simulation with ``k_sim``, with
    and without visual correction from 3 cameras (96 x 72) rendering the twin each frame.

    ``make(k)`` builds a :class:`pliant.Simulator`; one Gaussian per particle (σ = 4 cm, random colours),
    LBS binding (k = 4). The corrector (``corrector`` are :class:`pliant.gaussians.VisualCorrector`'s
    keyword arguments) sees the images of the current time before each frame. Drift is the mean distance
    [m] between simulated and real particles after each frame; reported over the whole run and at the end.
    """
    from ..gaussians import Camera, Gaussians, VisualCorrector, bind, render

    real = make(k_true)
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
        sim = make(k_sim)
        vc = VisualCorrector(binding, cams, **corrector)
        out = []
        for f in range(frames):
            if correct and f > 0:  # images of the current time: after f frames
                vc.correct(sim, images[f - 1])
            sim.step_frame()
            out.append(np.linalg.norm(sim.state_0.particle_q.numpy() - truth[f], axis=1).mean())
        return np.asarray(out)

    plain = drift(False)
    t0 = time.process_time()
    corrected = drift(True)
    cpu = time.process_time() - t0
    return {
        "mean_drift_uncorrected_m": round(float(plain.mean()), 5),
        "mean_drift_corrected_m": round(float(corrected.mean()), 5),
        "final_drift_uncorrected_m": round(float(plain[-1]), 5),
        "final_drift_corrected_m": round(float(corrected[-1]), 5),
        "mean_drift_reduction": round(float(1.0 - corrected.mean() / plain.mean()), 4),
        "final_drift_reduction": round(float(1.0 - corrected[-1] / plain[-1]), 4),
        "corrected_cpu_s_per_frame": round(cpu / frames, 4),
    }


def gaussians_visual_correction(quick: bool = False) -> dict:
    """Drift of simulations with 3x wrong stiffness, with and without visual correction (3 cameras).

    Three cases: the 8 x 8-cell cloth pinned at two corners (ForceSolver, k = 300 N/m "real" and 100 N/m
    simulated) with symplectic Euler and with backward Euler, and a clamped soft beam under XPBD shape
    matching (k_S = 0.3 real, 0.1 simulated). Each reports the default corrector ("state") and Embodied
    Gaussians' visual forces ("forces", 3 Adam steps, lr 1.5e-3, k_p = 4 N/m) against the uncorrected run
    (see :func:`visual_correction_drift`).
    """
    frames = 10 if quick else 30
    out: dict = {"device": "cpu", "frames": frames, "cameras": 3}
    for name, make, k_true, k_sim in (
        ("cloth_force_solver_k300_vs_k100", _cloth_sim, 300.0, 100.0),
        ("cloth_backward_euler_k300_vs_k100", _cloth_sim_implicit, 300.0, 100.0),
        ("beam_xpbd_shape_matching_ks0.3_vs_ks0.1", _beam_sim, 0.3, 0.1),
    ):
        for method in ("state", "forces"):
            r = visual_correction_drift(make, k_true, k_sim, frames, method=method)
            out.update({f"{name}/{method}/{k}": v for k, v in r.items()})
    return out


BENCHMARKS = {
    "gaussians_raster": gaussians_raster,
    "gaussians_visual_correction": gaussians_visual_correction,
}
