"""Frames replayed as captured graphs against launch-by-launch frames, side by side (Simulator(graph=...)).

For each built-in scene whose solver allows replay, two simulators of the same scene run in one process,
interleaved round by round on the same core: ``graph=False`` (every kernel launched from Python) and the
default (the frame captured once, then replayed). Each row prints the median wall milliseconds per frame of
both, their ratio per round (median, min, max), and the accuracy figure of the whole motion: the largest
difference between the two runs' positions over every frame (0.0: the same trajectory bit for bit, so the
ratio is at equal accuracy by construction).

A row named ``<scene>+tolerance`` runs the scene's XPBD solver with a tolerance and a higher sweep cap
(:data:`TOLERANCE`): its sweeps stop when a device-side check finds the residual small enough, in the
graph as launched directly. Such a row adds the mean sweeps per step and ``trajectory_error_m``, the largest
position difference [m] at the end of each round from a converged run (:data:`REFERENCE_ITERATIONS` fixed
sweeps, same frames), beside ``fixed_error_m``, that of the scene's own fixed sweep count.

Usage (one core):
    taskset -c 1 .venv/bin/python benchmarks/bench_graph.py --rounds 5 --frames 10
    taskset -c 1 .venv/bin/python benchmarks/bench_graph.py --scenes rope cloth --device cuda:0
    taskset -c 1 .venv/bin/python benchmarks/bench_graph.py --scenes cloth_xpbd+tolerance
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

DEFAULT_SCENES = [
    "rope",
    "rope_swing",
    "fit_rope",
    "soft_box",
    "cloth",
    "cloth_xpbd",
    "xpbd_soft_body",
    "cloth_xpbd+tolerance",
    "pendulum_chain+tolerance",
]
#: XPBD solver settings of the ``<scene>+tolerance`` rows: a tolerance [m] that stops the sweeps early in
#: most steps (mean sweeps printed) under a cap well above the scene's fixed count.
TOLERANCE = {
    "cloth_xpbd": {"tolerance": 1e-3, "iterations": 60},
    "pendulum_chain": {"tolerance": 1e-5, "iterations": 60},
}
#: Fixed sweeps of the converged run the tolerance rows are compared with.
REFERENCE_ITERATIONS = 400


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=DEFAULT_SCENES, help="built-in scene names")
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds")
    ap.add_argument("--frames", type=int, default=10, help="frames per round and simulator")
    ap.add_argument("--device", default="cpu", help="Warp device (cpu, cuda:0)")
    args = ap.parse_args()

    import numpy as np
    import warp as wp

    wp.config.quiet = True
    import pliant.scene as ps

    def simulator(cfg, **solver):
        sim = ps.build_scene(cfg).simulator()
        for key, value in solver.items():  # before the first step: nothing recorded or captured yet
            setattr(sim.solver, key, value)
        return sim

    def round_ends(sim, rounds):
        """Positions at the end of each round of a timed run (3 warm-up frames, then ``frames`` each)."""
        for _ in range(3):
            sim.step_frame()
        out = []
        for _ in range(rounds):
            for _ in range(args.frames):
                sim.step_frame()
            out.append(sim.state_0.particle_q.numpy())
        return out

    def deviation(xs, ref):
        return max(float(np.abs(a - b).max()) for a, b in zip(xs, ref, strict=True))

    for name in args.scenes:
        base, _, variant = name.partition("+")
        if variant not in ("", "tolerance") or (variant and base not in TOLERANCE):
            raise SystemExit(f"{name}: unknown row; tolerance rows: {[f'{k}+tolerance' for k in TOLERANCE]}")
        settings = TOLERANCE[base] if variant else {}
        cfg = ps.load_scene(base, overrides=[f"scene.device={args.device}"])
        sims = {}
        for mode in ("direct", "graph"):
            sim = simulator(cfg, **settings)
            if mode == "direct":
                sim.set_graph(False)
            for _ in range(3):  # compile, warm up and capture outside the timing
                sim.step_frame()
            sims[mode] = sim
        if sims["graph"].graph_reason is not None:
            print(json.dumps({"scene": name, "skipped": sims["graph"].graph_reason}))
            continue
        times: dict[str, list[float]] = {"direct": [], "graph": []}
        max_dx = 0.0
        rounds_x = []  # positions at the end of each round (the tolerance rows' error)
        for _ in range(args.rounds):
            for mode, sim in sims.items():
                wp.synchronize_device(sim.model.device)
                t0 = time.perf_counter()
                for _ in range(args.frames):
                    sim.step_frame()
                wp.synchronize_device(sim.model.device)
                times[mode].append((time.perf_counter() - t0) / args.frames)
            dx = np.abs(sims["graph"].state_0.particle_q.numpy() - sims["direct"].state_0.particle_q.numpy())
            max_dx = max(max_dx, float(dx.max()))
            rounds_x.append(sims["graph"].state_0.particle_q.numpy())
        extra = {}
        if variant:
            steps, sweeps = sims["graph"].solver.sweep_counts()
            ref = round_ends(simulator(cfg, iterations=REFERENCE_ITERATIONS), len(rounds_x))
            fixed_sim = simulator(cfg)
            extra = {
                **settings,
                "mean_sweeps_per_step": round(sweeps / steps, 2),
                "fixed_iterations": fixed_sim.solver.iterations,
                "reference_iterations": REFERENCE_ITERATIONS,
                "trajectory_error_m": deviation(rounds_x, ref),
                "fixed_error_m": deviation(round_ends(fixed_sim, len(rounds_x)), ref),
            }
        ratios = [d / g for d, g in zip(times["direct"], times["graph"], strict=True)]
        print(
            json.dumps(
                {
                    "scene": name,
                    "device": str(sims["graph"].model.device),
                    "particles": sims["graph"].model.particle_count,
                    "substeps": sims["graph"].substeps,
                    "direct_ms_per_frame": round(1e3 * statistics.median(times["direct"]), 3),
                    "graph_ms_per_frame": round(1e3 * statistics.median(times["graph"]), 3),
                    "ratio_median": round(statistics.median(ratios), 2),
                    "ratio_min": round(min(ratios), 2),
                    "ratio_max": round(max(ratios), 2),
                    "max_position_difference_m": max_dx,
                    **extra,
                }
            )
        )


if __name__ == "__main__":
    main()
