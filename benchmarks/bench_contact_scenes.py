"""Issue 39's contact scenes (pliant/examples/_contact_scenes.py): frame rate on one CPU core, one JSON line
per run, with the cost of the step bound (the same scene with SelfCollision alone).

Each line has the scene, the solver family, frames, substeps, particles, seconds, frames/s and steps/s;
``--baseline`` adds a run without the StepBound handler (``bound_share``: the fraction of the time the
bound costs).

Usage:
    python benchmarks/bench_contact_scenes.py                      # every scene, force family, 10 frames
    python benchmarks/bench_contact_scenes.py --scene twist --family force fms xpbd --frames 30
    python benchmarks/bench_contact_scenes.py --baseline
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one CPU core; must precede the NumPy import

import argparse  # noqa: E402
import json  # noqa: E402


def main() -> None:
    from pliant.examples import _contact_scenes as cs

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", nargs="+", default=list(cs.SCENES), help="scenes to run")
    ap.add_argument("--family", nargs="+", default=["force"], help="force | fms | xpbd")
    ap.add_argument("--frames", type=int, default=10, help="frames per run (after one warm-up frame)")
    ap.add_argument("--baseline", action="store_true", help="also run without the step bound")
    args = ap.parse_args()
    for name in args.scene:
        for family in args.family:
            rows = {}
            for bound in (True, False) if args.baseline else (True,):
                scene = cs.SCENES[name](family=family)
                if not bound:
                    scene.solver.collisions = [
                        c for c in scene.solver.collisions if type(c).__name__ != "StepBound"
                    ]
                scene.run(1)  # compiles the kernels
                scene.run(args.frames)
                rows[bound] = scene.wall
            row = {
                "scene": name,
                "family": family,
                "frames": args.frames,
                "substeps": scene.substeps,
                "particles": scene.model.particle_count,
                "seconds": round(rows[True], 3),
                "fps": round(args.frames / rows[True], 3),
                "steps_per_s": round(args.frames * scene.substeps / rows[True], 1),
            }
            if args.baseline:
                row["seconds_without_bound"] = round(rows[False], 3)
                row["bound_share"] = round(1.0 - rows[False] / rows[True], 3)
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
