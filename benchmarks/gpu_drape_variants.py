"""The drape's gather-kernel variants side by side: frames per second and trajectory error per cloth size.

FastMassSpring's explicit step is one gather kernel per substep; on CUDA a small cloth's step is
latency-bound, and ``FastMassSpring(gather=...)`` offers variants that hide it ("loop", "unrolled",
"ell", "tiled", "tiled16"; :mod:`pliant.solvers.fast_mass_spring._explicit`). This script measures them on the
drape of the benchmark rows (:func:`pliant.bench._mass_spring.cloth_drape_model`, symplectic Euler at the
rows' substeps: 80, 160, 320, 640 for 64², 128², 256², 512²; 30 frames; float32; no damping), on CUDA with a
frame's substeps captured once in a CUDA graph and replayed (on the CPU the substeps are launched
directly), reading the sag after every frame. Each variant runs ``--rounds`` times, the variants
interleaved within a round; the row gives the median frames per second.

One JSON line per (n, variant), appended to OUT: ``fps`` (median), ``fps_rounds``, ``trajectory_error``
(against the stored converged reference, :mod:`pliant.bench._drape_motion`; None where none is stored),
``curve_dev_vs_loop`` (max |sag_k − sag_k(loop)| / sag_final(loop)), ``x_dev_vs_loop`` (max |x − x(loop)|
of the final positions over the loop's final sag) and ``bit_equal_loop`` (final positions identical), then
one summary line per n with each variant's speed-up over the loop. Run it from the repository root with
``PYTHONPATH=.`` (a script's own folder, not the working directory, heads sys.path):

    PYTHONPATH=. python benchmarks/gpu_drape_variants.py cuda:0 /tmp/variants.jsonl
    PYTHONPATH=. python benchmarks/gpu_drape_variants.py cpu /tmp/v.jsonl --sizes 16 --substeps 20 \\
        --frames 3 --rounds 1
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
import traceback
from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

if TYPE_CHECKING:
    from pliant.model import Model

#: Substeps per frame of the benchmark rows' symplectic drape (the stability bound: 1.25 n).
ROW_SUBSTEPS = {64: 80, 128: 160, 256: 320, 512: 640}
VARIANTS = ("loop", "unrolled", "ell", "tiled", "tiled16")


class DrapeRun:
    """One variant's drape on ``device`` (the drape ``model``, shared by the variants): solver, two states
    and (on CUDA) a frame's graph."""

    def __init__(self, model: Model, substeps: int, variant: str, device: str) -> None:
        from pliant.bench._mass_spring import FRAME_DT
        from pliant.solvers import FastMassSpring

        if substeps % 2:
            raise ValueError(f"substeps must be even (a frame swaps the states back), got {substeps}")
        self.model = model
        # make_solver(model, "symplectic")'s solver (undamped), with the gather variant picked
        self.solver = FastMassSpring(
            self.model, method="symplectic", kernel="gather", gather=variant, damping_rate=0.0
        )
        self.control = self.model.control()
        self.dt = FRAME_DT / substeps
        self.substeps = substeps
        self.device = device
        self.s0, self.s1 = self.model.state(), self.model.state()
        self._frame_direct()  # compiles and records the launches outside the graph
        self.graph = None
        if wp.get_device(device).is_cuda:
            with wp.ScopedCapture(device=device) as cap:
                self._frame_direct()
            self.graph = cap.graph

    def _frame_direct(self) -> None:
        a, b = self.s0, self.s1
        for _ in range(self.substeps):
            self.solver.step(a, b, self.control, self.dt)
            a, b = b, a

    def run(self, frames: int) -> tuple[float, list[float], np.ndarray]:
        """(wall [s], sag per frame [m] from frame 0, final positions [m]) of ``frames`` frames from rest."""
        from pliant.bench._mass_spring import sag

        rest = self.model.state()
        self.s0.assign(rest)
        self.s1.assign(rest)
        wp.synchronize_device(self.device)
        curve = [sag(self.model, self.s0.particle_q.numpy())]
        t = time.perf_counter()
        for _ in range(frames):
            if self.graph is not None:
                wp.capture_launch(self.graph)
            else:
                self._frame_direct()
            curve.append(sag(self.model, self.s0.particle_q.numpy()))
        wp.synchronize_device(self.device)
        return time.perf_counter() - t, curve, self.s0.particle_q.numpy()


def measure(
    n: int, substeps: int, variants: tuple[str, ...], device: str, frames: int, rounds: int
) -> list[dict[str, Any]]:
    """The rows of one cloth size: every variant ``rounds`` times, interleaved (see the module doc)."""
    from pliant.bench._common import REFERENCES
    from pliant.bench._drape_motion import reference_curve, trajectory_error
    from pliant.bench._mass_spring import cloth_drape_model

    rows: list[dict[str, Any]] = []
    runs: dict[str, DrapeRun] = {}
    model = cloth_drape_model(n, device=device, dtype="float32")
    for v in variants:
        try:
            runs[v] = DrapeRun(model, substeps, v, device)
        except Exception as e:  # noqa: BLE001 - a variant that fails to build is reported, the rest go on
            rows.append({"n": n, "variant": v, "error": repr(e)[:400], "tb": traceback.format_exc()[-800:]})
    walls: dict[str, list[float]] = {v: [] for v in runs}
    results: dict[str, tuple[list[float], np.ndarray]] = {}
    for _ in range(rounds):
        for v, r in runs.items():
            wall, curve, x = r.run(frames)
            walls[v].append(wall)
            results[v] = (curve, x)
    has_ref = (REFERENCES / f"cloth_drape_{n}.npz").exists()
    ref = reference_curve(n) if has_ref else None
    base = results.get("loop")
    fps = {v: frames / statistics.median(w) for v, w in walls.items()}
    for v, (curve, x) in results.items():
        c = np.asarray(curve)
        row: dict[str, Any] = {
            "n": n,
            "substeps": substeps,
            "frames": frames,
            "variant": v,
            "device": device,
            "fps": round(fps[v], 3),
            "fps_rounds": [round(frames / w, 3) for w in walls[v]],
            "graph": runs[v].graph is not None,
            "final_sag": round(float(c[-1]), 6),
            "trajectory_error": None if ref is None else round(float(trajectory_error(c, ref)), 6),
        }
        if base is not None:
            bc, bx = np.asarray(base[0]), base[1]
            row["curve_dev_vs_loop"] = float(np.max(np.abs(c - bc)) / abs(bc[-1]))
            row["x_dev_vs_loop"] = float(np.max(np.abs(x - bx)) / abs(bc[-1]))
            row["bit_equal_loop"] = bool(np.array_equal(x, bx))
        rows.append(row)
    if "loop" in fps:
        rows.append(
            {
                "n": n,
                "summary": True,
                "speedup_vs_loop": {v: round(f / fps["loop"], 3) for v, f in fps.items()},
                "best": max(fps, key=lambda v: fps[v]),
            }
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("device", help="cuda:0 or cpu")
    ap.add_argument("out", help="JSON lines are appended here")
    ap.add_argument("--sizes", default="64,128,256,512", help="cells per side, comma-separated")
    ap.add_argument("--substeps", type=int, default=None, help="substeps per frame (default: the rows')")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    args = ap.parse_args()
    wp.config.quiet = True
    import pliant  # noqa: F401  (initialises Warp)

    variants = tuple(args.variants.split(","))
    t0 = time.perf_counter()
    dev = wp.get_device(args.device)
    with open(args.out, "a") as out:

        def emit(row: dict[str, Any]) -> None:
            line = json.dumps({"t": round(time.perf_counter() - t0, 1), **row})
            print(line, flush=True)
            out.write(line + "\n")
            out.flush()

        emit({"env": True, "warp": wp.__version__, "device": args.device, "name": dev.name})
        for n in (int(s) for s in args.sizes.split(",")):
            substeps = args.substeps or ROW_SUBSTEPS.get(n, 80 * n // 64)
            try:
                for row in measure(n, substeps, variants, args.device, args.frames, args.rounds):
                    emit(row)
            except Exception as e:  # noqa: BLE001 - one size failing does not stop the others
                emit({"n": n, "error": repr(e)[:400], "tb": traceback.format_exc()[-800:]})
        emit({"done_s": round(time.perf_counter() - t0, 1)})


if __name__ == "__main__":
    main()
