"""FastMassSpring's two symplectic spring kernels side by side on the CPU: scatter (each spring once, its
force added to both ends; the CPU default) against gather (each particle sums its own springs, every spring
evaluated from both ends; the CUDA default), on the drape of ``pliant.bench._mass_spring``.

Both run in one process, interleaved round by round on the same core; each run times the 30-frame fall and
reports its ``trajectory_error`` against the stored converged reference (the two kernels give the same
motion to round-off, so the ratio is a ratio at equal accuracy).

Usage (one core):
    taskset -c 1 .venv/bin/python benchmarks/bench_cloth_kernels.py --n 64 128 --rounds 5
"""

from __future__ import annotations

import argparse
import json
import statistics
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[64, 128], help="cells per side (64, 128)")
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds per kernel")
    args = ap.parse_args()

    import warp as wp

    wp.config.quiet = True
    from pliant.bench._drape_motion import REFERENCE_FRAMES, reference_curve, solver_curve, trajectory_error
    from pliant.bench._mass_spring import SYMPLECTIC_SUBSTEPS, cloth_drape_model
    from pliant.solvers import FastMassSpring

    for n in args.n:
        model = cloth_drape_model(n)
        ref = reference_curve(n)
        sub = SYMPLECTIC_SUBSTEPS[n]  # the benchmark rows' stable, <= 2 % setting
        # Step by step: the kernels themselves (the scatter's frame is otherwise one fused launch).
        solvers = {
            k: FastMassSpring(model, method="symplectic", kernel=k, fused_frame=False)
            for k in ("scatter", "gather")
        }
        for s in solvers.values():  # compile and warm up outside the timing
            solver_curve(model, s, substeps=sub, frames=1)
        fps: dict[str, list[float]] = {k: [] for k in solvers}
        err: dict[str, float] = {}
        for _ in range(args.rounds):
            for k, s in solvers.items():
                t = time.perf_counter()
                curve = solver_curve(model, s, substeps=sub, frames=REFERENCE_FRAMES)
                fps[k].append(REFERENCE_FRAMES / (time.perf_counter() - t))
                err[k] = trajectory_error(curve, ref)
        ratios = [a / b for a, b in zip(fps["scatter"], fps["gather"], strict=True)]
        print(
            json.dumps(
                {
                    "n": n,
                    "substeps": sub,
                    "rounds": args.rounds,
                    "fps_scatter": round(statistics.median(fps["scatter"]), 2),
                    "fps_gather": round(statistics.median(fps["gather"]), 2),
                    "scatter_over_gather": round(statistics.median(ratios), 3),
                    "ratio_min_max": [round(min(ratios), 3), round(max(ratios), 3)],
                    "trajectory_error_scatter": round(err["scatter"], 5),
                    "trajectory_error_gather": round(err["gather"], 5),
                }
            ),
            flush=True,
        )


if __name__ == "__main__":
    main()
