"""Cloth drape benchmark: a 1 m cloth pinned at two adjacent corners falls (30 frames, the fall).

Scene (fixed, so that equal speed means equal behaviour): n × n cells, side 1 m, starting flat in the
horizontal xz plane at y = 0 (near the origin: see the float32 pitfall in DESIGN.md), total mass 0.5 kg,
membrane stiffness E·t = 1000 N/m with ν = 0.3 mapped by :func:`pliant.energies.cloth_spring_stiffness`
(structural and shear springs, no bending, no damping: the peers' scene), pinned at "top-corners", gravity
−9.81 m/s² along y, no ground. The rows time the fall, frames 0–30 of 1/60 s, and judge the **whole
motion**: ``trajectory_error`` is the largest deviation of the sag per frame (pin height minus the lowest
particle) from a converged float64 reference (:mod:`pliant.bench._drape_motion`), relative to its final sag.
A row's settings are the cheapest found with ``trajectory_error`` ≤ 2 %; no row adds damping. Symplectic
rows also state the memory traffic of a substep (``bytes_per_substep``, :mod:`pliant.bench._bandwidth`) and,
on CUDA, the fraction of the device's peak bandwidth the timed run reached (launch by launch, no graph).
:data:`REFERENCE_SAG` (the sag at rest, with damping) remains for the equilibrium tests.

Each benchmark returns one JSON-serialisable dict; ``python -m pliant.bench._mass_spring`` prints them.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

import numpy as np

from .._time import substep_dt
from ._bandwidth import bandwidth_fields
from ._common import print_rows, run_timed, speed_fields
from ._drape_motion import motion_fields, reference_for

# The scene and its solvers live one module down, where the motion references (._drape_motion) build them
# too; they are re-exported here, the drape benchmark's public home.
from ._drape_scene import FRAME_DT, FRAMES, cloth_drape_model, make_solver, sag, sag_fields

#: Converged sag [m] of the drape at equilibrium, per cells per side, from :func:`reference_sag`: float64,
#: Baraff–Witkin steps of 1/60 s with 200–300 CG iterations (relative tolerance 1e-9) and damping 3/s, run
#: to rest. 64: 1800 frames, max |v| 1e-6 m/s, force residual 1.5e-4 of a particle's weight (CPU);
#: 128: 1200 frames, max |v| 6e-4 m/s, sag changing < 1e-5 m per 100 frames (CPU); 256: 3000 frames on
#: an H100 (CPU and CUDA agree to 1e-11 on this solver). At rest the sag depends neither on the damping nor
#: on the integrator: converged symplectic Euler agrees (tests/test_mass_spring.py), and so does the 256
#: symplectic run at 320 substeps/frame (1.01402, 0.1%).
REFERENCE_SAG: dict[int, float] = {16: 1.008378, 64: 1.011910, 128: 1.013470, 256: 1.014877}


def cloth_drape(
    n: int = 64,
    method: str = "implicit",
    substeps: int = 1,
    cg_iterations: int = 100,
    damping_rate: float = 0.0,
    frames: int = FRAMES,
    device: str | None = "cpu",
    dtype: str = "float32",
    quick: bool = False,
    fused_frame: bool | None = None,
) -> dict:
    """Run the drape for ``frames`` frames of 1/60 s; one dict of speed and motion figures.

    Args:
        n: cells per side.
        method: "implicit", "symplectic" or "force" (:func:`make_solver`).
        substeps: solver steps per frame.
        cg_iterations: the most CG iterations per implicit step (it stops at ``cg_tol`` = 1e-2 before).
        damping_rate: velocity damping c [1/s] (0: the benchmark's physics).
        frames: frames of 1/60 s timed.
        device: Warp device.
        dtype: "float32" or "float64".
        quick: a 16 × 16 cloth (a smoke run).
        fused_frame: FastMassSpring's one-launch CPU frame (None: where it applies; False: step by step,
            the rows before it; the same motion bit for bit).
    """
    from .._warp import resolve_device
    from ..solvers import FastMassSpring

    if quick:
        n, frames = min(n, 16), min(frames, 30)
    device = str(resolve_device(device))
    started = time.perf_counter()
    model = cloth_drape_model(n, device=device, dtype=dtype)
    solver = make_solver(
        model, method, cg_iterations=cg_iterations, damping_rate=damping_rate, fused_frame=fused_frame
    )
    dt = substep_dt(FRAME_DT, substeps)
    state, timing = run_timed(
        model, solver, model.control(), dt, frames=frames, substeps=substeps, device=device, started=started
    )
    d = solver.describe()
    traffic = (
        bandwidth_fields(solver, frames * substeps, timing.wall, device)
        if method == "symplectic" and isinstance(solver, FastMassSpring)
        else {"bytes_per_substep": None}
    )
    # The whole fall against the converged curve (pliant.bench._drape_motion), not only the rest; it
    # resolves (or computes on this device) the reference the final sag is compared with too.
    motion = motion_fields(n, method, substeps, cg_iterations, damping_rate, dtype=dtype, device=device)
    return {
        "scene": f"cloth_drape_{n}x{n}",
        "solver": d["solver"],
        "integrator": d["integrator"],
        "device": device,
        "dtype": dtype,
        "particles": model.particle_count,
        "elements": model.spring_count,
        "frames": frames,
        "substeps": substeps,
        "iterations": cg_iterations if method == "implicit" else 0,
        "fused_frame": bool(d.get("fused_frame", False)),
        # What the tolerance stop actually used: mean CG iterations per implicit step.
        "cg_iterations_mean": (
            round(solver.cg_iterations_total / max(solver.cg_steps, 1), 2)
            if method == "implicit" and isinstance(solver, FastMassSpring)
            else 0
        ),
        "damping_rate": damping_rate,
        **speed_fields(timing, model.particle_count),
        **traffic,
        **sag_fields(model, state, _reference_at(n, frames, device)),
        **motion,
    }


def _reference_at(n: int, frame: int, device: str | None = "cpu") -> float:
    """The converged sag [m] at ``frame`` (NaN beyond the reference or without one; see
    :func:`pliant.bench._drape_motion.reference_for`)."""
    ref, _ = reference_for(n, device)
    return float(ref[frame]) if ref is not None and frame < len(ref) else float("nan")


def reference_sag(
    n: int, *, max_frames: int = 4000, cg_iterations: int = 300, device: str | None = "cpu"
) -> float:
    """Converged float64 sag [m] of the n × n drape (slow on a CPU: 20 minutes at n = 128)."""
    import warp as wp

    from ..energies import Gravity, Springs
    from ..solvers import FastMassSpring

    model = cloth_drape_model(n, device=device, dtype="float64")
    solver = FastMassSpring(
        model, method="implicit", cg_iterations=cg_iterations, cg_tol=1e-9, damping_rate=3.0
    )
    control = model.control()
    s0, s1 = model.state(), model.state()
    grad = wp.zeros(model.particle_count, dtype=model.vec3, device=model.device)
    free = model.particle_inv_mass.numpy() > 0
    weight = model.particle_mass.numpy()[free] * 9.81
    for f in range(max_frames):
        solver.step(s0, s1, control, FRAME_DT)
        s0, s1 = s1, s0
        if f % 100 == 99:
            grad.zero_()
            for e in (Springs(), Gravity()):
                e.gradient(model, s0.particle_q, grad)
            res = float(np.max(np.linalg.norm(grad.numpy()[free], axis=1) / weight))
            vmax = float(np.abs(s0.particle_qd.numpy()).max())
            if vmax < 1e-4 and res < 1e-2:
                break
    return sag(model, s0.particle_q.numpy())


def _bench(
    n: int, method: str, substeps: int = 1, cg_iterations: int = 100, fused_frame: bool | None = None
) -> Callable[..., dict]:
    def run(device: str | None = "cpu", quick: bool = False, dtype: str = "float32") -> dict:
        return cloth_drape(
            n,
            method,
            substeps,
            cg_iterations,
            device=device,
            quick=quick,
            dtype=dtype,
            frames=FRAMES,
            fused_frame=fused_frame,
        )

    how = ", step by step" if fused_frame is False else ""
    run.__doc__ = (
        f"Cloth drape {n}×{n}, {method}, {substeps} substep(s)/frame{how}, the 30-frame fall, undamped."
    )
    return run


#: Substeps per frame that keep symplectic Euler stable on the pinned drape (measured; see the report):
#: trajectory_error 0.04 % at 64 (the stability limit, not accuracy, sets them).
#: 512: 640, the same Δt·n (the H200 run of 2026-11-26 was within 0.05 % of a converged curve there).
SYMPLECTIC_SUBSTEPS = {64: 80, 128: 160, 256: 320, 512: 640}

#: Baraff–Witkin steps per frame for trajectory_error ≤ 2 %. Backward Euler's own damping sets them, not
#: CG: at 64 × 64 (CG to 1e-2) 1 step/frame is 7.6 % off, 16 steps 3.3 %, 32 steps 1.8 % (mean 5.8 CG
#: iterations). Before issue #15 the row ran 1 step with 20 CG iterations: 32.6 %.
IMPLICIT_STEPS = {64: 32, 128: 32, 256: 32}
#: CG's cap per step (the tolerance 1e-2 stops it first: 6-10 iterations at 32 steps/frame).
IMPLICIT_ITERATIONS = {64: 100, 128: 100, 256: 100}

BENCHMARKS: dict[str, Callable[..., dict]] = {
    "cloth_drape_64_implicit": _bench(64, "implicit", IMPLICIT_STEPS[64], IMPLICIT_ITERATIONS[64]),
    "cloth_drape_128_implicit": _bench(128, "implicit", IMPLICIT_STEPS[128], IMPLICIT_ITERATIONS[128]),
    "cloth_drape_256_implicit": _bench(256, "implicit", IMPLICIT_STEPS[256], IMPLICIT_ITERATIONS[256]),
    "cloth_drape_64_symplectic": _bench(64, "symplectic", SYMPLECTIC_SUBSTEPS[64]),
    "cloth_drape_128_symplectic": _bench(128, "symplectic", SYMPLECTIC_SUBSTEPS[128]),
    # The GPU sizes (issue 24): their references are computed on the row's device (_drape_motion).
    "cloth_drape_256_symplectic": _bench(256, "symplectic", SYMPLECTIC_SUBSTEPS[256]),
    "cloth_drape_512_symplectic": _bench(512, "symplectic", SYMPLECTIC_SUBSTEPS[512]),
    "cloth_drape_64_forcesolver": _bench(64, "force", SYMPLECTIC_SUBSTEPS[64]),
    # The CPU rows before the one-launch frame (issue 42 item 4): the same motion bit for bit, for the
    # side-by-side's fused / step-by-step ratio (benchmarks/peers/cloth_side_by_side.py).
    "cloth_drape_64_symplectic_stepwise": _bench(
        64, "symplectic", SYMPLECTIC_SUBSTEPS[64], fused_frame=False
    ),
    "cloth_drape_128_symplectic_stepwise": _bench(
        128, "symplectic", SYMPLECTIC_SUBSTEPS[128], fused_frame=False
    ),
}


if __name__ == "__main__":
    print_rows(BENCHMARKS, sys.argv[1:])
