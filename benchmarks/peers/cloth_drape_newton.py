"""pliant's cloth drape (``pliant.bench._mass_spring``) in Newton 1.8 with the *same* spring network: one
JSON line with the timing and the sag per frame, for the equal-accuracy comparison of
``cloth_side_by_side.py``.

The network (positions, lumped masses, pins, springs with their rest lengths and stiffnesses) comes from an
NPZ that pliant writes (``python -m pliant.bench._drape_motion export N FILE``), so both codes simulate one
physics: undamped springs, gravity, two pinned corners, no ground; Newton's own cloth models (triangle
membranes, Style3D) would be another physics with another converged motion. Solvers: ``semi``
(SolverSemiImplicit: symplectic Euler on the springs), ``xpbd`` (SolverXPBD: springs as distance constraints)
and ``vbd`` (SolverVBD). Needs Newton in its own venv (see README.md); never imported by pliant.

    /work/peers-venv/bin/python benchmarks/peers/cloth_drape_newton.py --network /tmp/drape64.npz \\
        --solver semi --substeps 80
"""

from __future__ import annotations

import argparse
import json
import resource
import time

import numpy as np

FRAME_DT = 1.0 / 60.0


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--network", required=True, help="NPZ from `python -m pliant.bench._drape_motion export`")
    ap.add_argument("--solver", choices=["semi", "xpbd", "vbd"], default="semi")
    ap.add_argument("--substeps", type=int, default=80)
    ap.add_argument("--iterations", type=int, default=1, help="XPBD / VBD iterations per substep")
    ap.add_argument("--frames", type=int, default=30)
    args = ap.parse_args(argv)

    import newton
    import warp as wp

    wp.config.quiet = True
    d = np.load(args.network)
    x, mass, free = d["x"], d["mass"], d["free"]
    springs, rest, k = d["springs"], d["rest"], d["stiffness"]
    started = time.perf_counter()
    b = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=(0.0, -9.81, 0.0))
    # Radius 0 under XPBD: its particle-particle contact (which needs a hash grid) is off, as in pliant.
    radius = 0.0 if args.solver == "xpbd" else 0.005
    for p, m, f in zip(x, mass, free, strict=True):
        b.add_particle(wp.vec3(*p), wp.vec3(0.0, 0.0, 0.0), float(m) if f else 0.0, radius=radius)
    for (i, j), kk in zip(springs, k, strict=True):
        b.add_spring(int(i), int(j), float(kk), 0.0, 0.0)
    b.spring_rest_length = [float(r) for r in rest]  # pliant's rest lengths (the flat start: the same)
    if args.solver == "vbd":
        b.color()
    model = b.finalize(device="cpu")
    model.particle_grid = None  # no self-contact, no ground: the scene has neither
    if args.solver == "semi":
        solver = newton.solvers.SolverSemiImplicit(model)
    elif args.solver == "xpbd":
        solver = newton.solvers.SolverXPBD(model, iterations=args.iterations)
    else:
        solver = newton.solvers.SolverVBD(model, iterations=args.iterations, particle_enable_tile_solve=False)
    s0, s1, control = model.state(), model.state(), model.control()
    dt = FRAME_DT / args.substeps
    pinned = ~free

    def sag(q: np.ndarray) -> float:
        return float(q[pinned, 1].mean() - q[:, 1].min())

    # Warm-up: compile (as pliant's rows do), then start again from the initial state.
    s0.clear_forces()
    solver.step(s0, s1, control, None, dt)
    s0, s1 = model.state(), model.state()
    compile_s = time.perf_counter() - started
    curve = [sag(s0.particle_q.numpy())]
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(args.frames):
        for _ in range(args.substeps):
            s0.clear_forces()
            solver.step(s0, s1, control, None, dt)
            s0, s1 = s1, s0
        curve.append(sag(s0.particle_q.numpy()))  # one read per frame, as pliant's motion check does
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    row = {
        "engine": f"newton {newton.__version__}",
        "solver": args.solver,
        "particles": model.particle_count,
        "springs": model.spring_count,
        "frames": args.frames,
        "substeps": args.substeps,
        "iterations": args.iterations if args.solver != "semi" else 0,
        "wall_s": round(wall, 4),
        "compile_s": round(compile_s, 3),
        "fps": round(args.frames / wall, 3),
        # Frames per second of this process's CPU time: less sensitive to other jobs on a shared core.
        "fps_cpu_time": round(args.frames / max(cpu, 1e-9), 3),
        # Peak resident memory of the process [MB] (Linux reports kB), as pliant's rows report it.
        "peak_mem_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
        "sag_curve": [round(v, 7) for v in curve],
    }
    print(json.dumps(row), flush=True)
    return row


if __name__ == "__main__":
    main()
