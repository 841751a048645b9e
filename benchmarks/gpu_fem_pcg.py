"""The device Newton (``linear_solver="pcg"``) on the soft box drop, CG's dot products reduced by per-thread
atomics against block sums (``pliant.solvers.minimizers._pcg.REDUCTION``), side by side in one process.

Rows: the soft box drop of :mod:`pliant.bench._fem` (ImplicitMidpoint, ``implicit_substeps(n)``, float64,
Newton tolerance 1e-4 m/s per frame, the 24 judged frames, frames replayed as graphs) at each size, for
each reduction, in interleaved rounds (so that a clock or thermal drift touches both alike). Each row has
the benchmark's ``time_per_step_s``, ``iterations_per_step`` (Newton) and ``trajectory_error``, with
``reduction`` and ``round``. ``--cpu-baseline`` adds ``soft_box_drop_30_implicit`` (L-BFGS with a multigrid
V-cycle: the CPU's best) on the CPU in the same process; run the script under ``taskset -c 0`` so that it
is one core. The summary (last line, ``"summary": true``) has the median ms per step of each (size,
reduction), the tile/atomic ratio and, with the baseline, the CPU-to-device ratio at 30³.

Usage (from the repository root; on the device machine ``source $HOME/gpu/env.sh`` first):
    PYTHONPATH=. taskset -c 0 python3 benchmarks/gpu_fem_pcg.py cuda:0 out/pcg.jsonl --cpu-baseline
    PYTHONPATH=. python3 benchmarks/gpu_fem_pcg.py cpu /tmp/pcg.jsonl --sizes 4 --frames 4 --rounds 1
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

from pliant.bench._fem import BENCHMARKS, FRAMES_30, IMPLICIT_DTYPE, implicit_substeps, soft_box_drop
from pliant.solvers.minimizers import _pcg


def pcg_row(n: int, device: str, reduction: str, frames: int) -> dict:
    """One soft-box row of the device Newton with ``reduction`` (the ``soft_box_drop_N_implicit_pcg``
    setting at any size n)."""
    default = _pcg.REDUCTION
    _pcg.REDUCTION = reduction  # read when the row's solver sets up its device Newton
    try:
        row = soft_box_drop(
            n,
            "implicit",
            implicit_substeps(n),
            frames,
            device=device,
            dtype=IMPLICIT_DTYPE,
            minimizer="pcg",
            integrator="ImplicitMidpoint",
        )
    finally:
        _pcg.REDUCTION = default
    return {"benchmark": f"soft_box_drop_{n}_implicit_pcg", "reduction": reduction, **row}


def summary(rows: list[dict], baseline: dict | None) -> dict:
    """Median ms per step per (size, reduction), tile/atomic ratios, and the CPU baseline's ratio."""
    out: dict = {"summary": True, "ms_per_step": {}, "tile_over_atomic": {}}
    sizes = sorted({r["particles"] for r in rows})
    for p in sizes:
        med = {}
        for red in _pcg.REDUCTIONS:
            sel = [r["time_per_step_s"] for r in rows if r["particles"] == p and r["reduction"] == red]
            if sel:
                med[red] = statistics.median(sel) * 1e3
        name = next(r["scene"] for r in rows if r["particles"] == p)
        out["ms_per_step"][name] = {k: round(v, 4) for k, v in med.items()}
        if len(med) == 2:
            out["tile_over_atomic"][name] = round(med["tile"] / med["atomic"], 4)
        if baseline is not None and name == baseline["scene"]:
            cpu = baseline["time_per_step_s"] * 1e3
            out["cpu_ms_per_step"] = round(cpu, 3)
            out["cpu_over_device"] = {k: round(cpu / v, 3) for k, v in med.items()}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("device", help="Warp device of the device Newton rows: cuda:0 (cpu: a smoke test)")
    ap.add_argument("out", help="JSON lines file written with every row and the summary")
    ap.add_argument("--sizes", default="10,20,30", help="box sizes n (n³ cells), comma-separated")
    ap.add_argument("--rounds", type=int, default=2, help="interleaved rounds of every (size, reduction)")
    ap.add_argument("--frames", type=int, default=FRAMES_30, help="frames of 1/60 s per row")
    ap.add_argument("--reductions", default=",".join(_pcg.REDUCTIONS), help="reductions to compare")
    ap.add_argument("--cpu-baseline", action="store_true", help="also soft_box_drop_30_implicit on the CPU")
    args = ap.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    reductions = args.reductions.split(",")
    for red in reductions:
        if red not in _pcg.REDUCTIONS:
            ap.error(f"--reductions: {red!r} is not one of {_pcg.REDUCTIONS}")
    if args.rounds < 1 or args.frames < 1:
        ap.error("--rounds and --frames must be at least 1")
    t0 = time.perf_counter()
    rows: list[dict] = []
    baseline = None
    with open(args.out, "w") as f:

        def emit(row: dict) -> None:
            print(json.dumps(row), flush=True)
            f.write(json.dumps(row) + "\n")
            f.flush()

        for rnd in range(args.rounds):
            for n in sizes:
                order = reductions if rnd % 2 == 0 else reductions[::-1]  # neither always runs first
                for red in order:
                    row = {**pcg_row(n, args.device, red, args.frames), "round": rnd}
                    rows.append(row)
                    emit(row)
        if args.cpu_baseline:
            baseline = {"benchmark": "soft_box_drop_30_implicit", **BENCHMARKS["soft_box_drop_30_implicit"]()}
            emit(baseline)
        emit({**summary(rows, baseline), "total_s": round(time.perf_counter() - t0, 1)})


if __name__ == "__main__":
    main()
