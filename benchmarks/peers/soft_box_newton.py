"""pliant's ``soft_box_drop_10_implicit`` scene in Newton (SolverVBD or SolverSemiImplicit), one JSON line.

Needs Newton 1.8 in its own venv (see README.md); not imported by pliant or its tests.

    taskset -c 0 /work/peers-venv/bin/python benchmarks/peers/soft_box_newton.py --solver vbd
    taskset -c 0 /work/peers-venv/bin/python benchmarks/peers/soft_box_newton.py --solver semi --substeps 50 \
        --collide-every 50 --contact-gap 0.05
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
from _scene import (  # noqa: E402
    DENSITY,
    FRAME_DT,
    FRAMES,
    FRICTION,
    GROUND_STIFFNESS,
    LAM,
    MU,
    RADIUS,
    box_tets,
    heights,
    peak_mem_mb,
)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--solver", choices=["vbd", "semi"], default="vbd")
    ap.add_argument("--n", type=int, default=10, help="cells per side (6 tets per cell)")
    ap.add_argument("--substeps", type=int, default=None, help="per 1/60 s frame (vbd: 10, semi: 50)")
    ap.add_argument("--iterations", type=int, default=10, help="VBD iterations per substep")
    ap.add_argument("--frames", type=int, default=FRAMES)
    ap.add_argument("--contact-ke", type=float, default=GROUND_STIFFNESS, help="particle-ground stiffness")
    ap.add_argument("--contact-kd", type=float, default=None, help="particle-ground damping")
    ap.add_argument("--k-damp", type=float, default=0.0, help="tet viscous damping [Pa s]")
    ap.add_argument("--collide-every", type=int, default=1, help="run collision detection every N substeps")
    ap.add_argument("--contact-gap", type=float, default=None, help="soft contact detection gap [m] (0.01)")
    ap.add_argument("--tile-solve", action="store_true", help="VBD tile solve (GPU-oriented; slower on CPU)")
    args = ap.parse_args(argv)

    import newton
    import warp as wp

    wp.config.quiet = True
    substeps = args.substeps or (10 if args.solver == "vbd" else 50)  # semi: 40 diverges, 50 is stable
    dt = FRAME_DT / substeps
    t0 = time.perf_counter()

    points, tets = box_tets(args.n)
    if args.solver == "vbd":
        # VBD's stable neo-Hookean takes Lamé parameters (mu_NH = mu, lambda_NH = lambda + mu, as pliant).
        k_mu, k_lambda = MU, LAM
    else:
        # SemiImplicit's kernel is Smith et al. 2018 eq. 14 on the raw arguments (alpha = 1 + 3mu/(4lambda)),
        # whose small-strain Lamé constants are (3/4 k_mu, k_lambda - 5/8 k_mu): pass Smith's §3.4 mapping so
        # that E and nu match.
        k_mu, k_lambda = 4.0 / 3.0 * MU, LAM + 5.0 / 6.0 * MU
    b = newton.ModelBuilder(up_axis=newton.Axis.Y)
    b.add_soft_mesh(
        pos=wp.vec3(0.0, 0.0, 0.0),
        rot=wp.quat_identity(),
        scale=1.0,
        vel=wp.vec3(0.0, 0.0, 0.0),
        vertices=[wp.vec3(*p) for p in points],
        indices=tets.ravel().tolist(),
        density=DENSITY,
        k_mu=k_mu,
        k_lambda=k_lambda,
        k_damp=args.k_damp,
        particle_radius=RADIUS,
    )
    b.add_ground_plane(cfg=newton.ModelBuilder.ShapeConfig(mu=FRICTION))
    if args.solver == "vbd":
        b.color()
    model = b.finalize(device="cpu")
    model.soft_contact_ke = args.contact_ke
    if args.contact_kd is not None:
        model.soft_contact_kd = args.contact_kd
    model.soft_contact_mu = FRICTION

    if args.solver == "vbd":
        solver = newton.solvers.SolverVBD(
            model,
            iterations=args.iterations,
            particle_enable_self_contact=False,
            particle_enable_tile_solve=args.tile_solve,
        )
    else:
        # pliant's scene has no self-contact: drop SemiImplicit's brute-force particle-triangle self-contact
        # (~100 ms/step here) and its particle-particle hash grid.
        model.particle_grid = None
        solver = newton.solvers.SolverSemiImplicit(model, enable_tri_contact=False)
    pipeline = newton.CollisionPipeline(model, soft_contact_gap=args.contact_gap)
    contacts = pipeline.contacts()
    control = model.control()

    def advance(s0, s1, steps):
        for i in range(steps):
            s0.clear_forces()
            if i % args.collide_every == 0:
                pipeline.collide(s0, contacts)
            solver.step(s0, s1, control, contacts, dt)
            s0, s1 = s1, s0
        return s0, s1

    advance(model.state(), model.state(), 2)  # warm-up: kernel compilation / cache load
    wp.synchronize_device("cpu")
    compile_s = time.perf_counter() - t0

    s0, s1 = model.state(), model.state()
    steps = args.frames * substeps
    mass = model.particle_mass.numpy().astype(np.float64)
    com = []
    wp.synchronize_device("cpu")
    t0 = time.perf_counter()
    for _ in range(args.frames):
        s0, s1 = advance(s0, s1, substeps)
        # The motion check, every frame as pliant's rows do (a copy of N positions: microseconds).
        com.append(float(mass @ s0.particle_q.numpy()[:, 1].astype(np.float64) / mass.sum()))
    wp.synchronize_device("cpu")
    wall = time.perf_counter() - t0

    sim_s = args.frames * FRAME_DT
    row = {
        "benchmark": f"newton_soft_box_drop_{args.n}_{args.solver}",
        "scene": f"soft_box_drop_{args.n}x{args.n}x{args.n}",
        "peer": f"newton {newton.__version__} (warp {wp.__version__})",
        "solver": type(solver).__name__,
        "material": "stable neo-Hookean (Smith 2018)",
        "k_mu": round(k_mu, 1),
        "k_lambda": round(k_lambda, 1),
        "device": "cpu",
        "dtype": "float32",
        "particles": model.particle_count,
        "elements": model.tet_count,
        "frames": args.frames,
        "substeps": substeps,
        "dt": dt,
        "iterations_per_step": args.iterations if args.solver == "vbd" else 0,
        "contact_ke": model.soft_contact_ke,
        "contact_kd": model.soft_contact_kd,
        "collide_every": args.collide_every,
        "contact_gap": pipeline.soft_contact_gap,
        "wall_s": round(wall, 4),
        "wall_per_sim_s": round(wall / sim_s, 4),
        "compile_s": round(compile_s, 3),
        "time_per_step_s": float(f"{wall / steps:.4g}"),
        "time_per_frame_s": float(f"{wall / args.frames:.4g}"),
        "particle_substeps_per_s": float(f"{model.particle_count * steps / wall:.4g}"),
        "peak_mem_mb": peak_mem_mb(),
        **heights(s0.particle_q.numpy(), s0.particle_qd.numpy(), mass),
        "com_curve": com,
    }
    print(json.dumps(row), flush=True)
    return row


if __name__ == "__main__":
    main()
