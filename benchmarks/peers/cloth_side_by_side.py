"""The cloth drape at equal accuracy: pliant's rows and Newton 1.8 on the same spring network, interleaved
on one core; every run's speed beside its ``trajectory_error`` (the sag over the 30-frame fall against
pliant's converged float64 reference), medians and paired ratios.

Run from the repository root with pliant's venv (Newton runs from ``--peers-python``, a venv with
newton==1.8.0; see README.md):

    .venv/bin/python benchmarks/peers/cloth_side_by_side.py --n 64 128 --rounds 3

A speed claim stands only where both sides are at ``trajectory_error`` ≤ 2 %.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

PEERS = Path(__file__).resolve().parent

#: (label, pliant benchmark row or None, Newton solver or "taichi" / "taichi-substep" (Taichi's launches per
#: frame / per substep), substeps, iterations) per cloth size.
CONFIGS = {
    64: [
        ("pliant FastMassSpring symplectic, 80 substeps", "cloth_drape_64_symplectic", None, 0, 0),
        ("pliant ... step by step (before 1 launch/frame)", "cloth_drape_64_symplectic_stepwise", None, 0, 0),
        ("pliant XPBD colouring, 50 x 1, omega 1.6", "xpbd_cloth_drape_64_coloring", None, 0, 0),
        ("pliant Baraff-Witkin, 32 steps, CG 1e-2", "cloth_drape_64_implicit", None, 0, 0),
        ("newton SemiImplicit, 80 substeps", None, "semi", 80, 1),
        ("newton XPBD, 100 x 1", None, "xpbd", 100, 1),
        ("taichi symplectic, 80 substeps, 1 kernel/frame", None, "taichi", 80, 0),
        ("taichi symplectic, 80 substeps, 2 kernels/substep", None, "taichi-substep", 80, 0),
    ],
    128: [
        ("pliant FastMassSpring symplectic, 160 substeps", "cloth_drape_128_symplectic", None, 0, 0),
        (
            "pliant ... step by step (before 1 launch/frame)",
            "cloth_drape_128_symplectic_stepwise",
            None,
            0,
            0,
        ),
        ("pliant XPBD colouring, 100 x 1, omega 1.6", "xpbd_cloth_drape_128_coloring", None, 0, 0),
        ("newton SemiImplicit, 160 substeps", None, "semi", 160, 1),
        ("newton XPBD, 250 x 1", None, "xpbd", 250, 1),
        ("taichi symplectic, 160 substeps, 1 kernel/frame", None, "taichi", 160, 0),
        ("taichi symplectic, 160 substeps, 2 kernels/substep", None, "taichi-substep", 160, 0),
    ],
}


def _last_json(text: str) -> dict:
    return json.loads([ln for ln in text.splitlines() if ln.startswith("{")][-1])


def run_pliant(row: str, core: str) -> dict:
    out = subprocess.run(
        ["taskset", "-c", core, sys.executable, "-m", "pliant.cli", "bench", row],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    r = _last_json(out)
    return {
        "fps": r["fps"],
        "fps_cpu_time": r.get("fps_cpu_time"),
        "trajectory_error": r["trajectory_error"],
        "peak_mem_mb": r.get("peak_mem_mb"),
    }


def run_newton(py: str, network: str, n: int, solver: str, substeps: int, iterations: int, core: str) -> dict:
    import numpy as np

    from pliant.bench._drape_motion import reference_curve, trajectory_error

    if solver.startswith("taichi"):  # the same network in Taichi (cloth_drape_taichi.py), symplectic Euler
        cmd = [py, str(PEERS / "cloth_drape_taichi.py"), "--network", network, "--substeps", str(substeps)]
        cmd += ["--launch", "substep" if solver == "taichi-substep" else "frame"]
    else:
        cmd = [py, str(PEERS / "cloth_drape_newton.py"), "--network", network, "--solver", solver]
        cmd += ["--substeps", str(substeps), "--iterations", str(iterations)]
    r = _last_json(
        subprocess.run(["taskset", "-c", core, *cmd], capture_output=True, text=True, check=True).stdout
    )
    err = trajectory_error(np.asarray(r["sag_curve"]), reference_curve(n))
    return {
        "fps": r["fps"],
        "fps_cpu_time": r.get("fps_cpu_time"),
        "trajectory_error": round(err, 5),
        "peak_mem_mb": r["peak_mem_mb"],
    }


def _load() -> float:
    """The 1-minute load average (the box is shared: it says how much the wall-clock figures mean)."""
    import os

    return round(os.getloadavg()[0], 2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[64])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--core", default="1")
    ap.add_argument("--peers-python", default="/work/peers-venv/bin/python")
    ap.add_argument("--only", nargs="+", default=None, help="run the configs whose label holds one of these")
    ap.add_argument("--out", default=None, help="also write each run as a JSON line to this file")
    args = ap.parse_args()
    out = open(args.out, "a") if args.out else None  # noqa: SIM115 (kept open over the rounds)
    from pliant.bench._drape_motion import export_network

    for n in args.n:
        network = str(Path(tempfile.mkdtemp()) / f"drape{n}.npz")
        export_network(n, network)
        configs = [c for c in CONFIGS[n] if args.only is None or any(o in c[0] for o in args.only)]
        rows: dict[str, list[dict]] = {c[0]: [] for c in configs}
        for r in range(args.rounds):
            for label, row, solver, sub, it in configs:  # interleaved: A B C ... A B C ...
                res = (
                    run_pliant(row, args.core)
                    if row
                    else run_newton(args.peers_python, network, n, solver, sub, it, args.core)
                )
                rows[label].append(res)
                line = json.dumps({"n": n, "config": label, "round": r, "load_avg_1min": _load(), **res})
                print(line, file=sys.stderr, flush=True)
                if out is not None:
                    print(line, file=out, flush=True)
        first = configs[0][0]
        print(
            f"\ncloth {n}x{n}, 30-frame fall, medians of {args.rounds} interleaved rounds on core {args.core}"
        )
        # fps: wall clock; cpu fps: frames per second of the process's CPU time (on a shared core the wall
        # clock counts other jobs' time slices too). Ratios: the first row's over this row's within each
        # round (same load), then the median, with the range over the rounds.
        print(
            f"{'config':48s} {'fps':>8s} {'cpu fps':>8s} {'traj err':>9s} {'first is N x faster':>21s} "
            f"{'(cpu time)':>18s} {'peak MB':>8s}"
        )
        for label in rows:
            fps = statistics.median(x["fps"] for x in rows[label])
            err = statistics.median(x["trajectory_error"] for x in rows[label])
            mems = [x["peak_mem_mb"] for x in rows[label] if x.get("peak_mem_mb") is not None]
            mem = f"{statistics.median(mems):8.1f}" if mems else f"{'-':>8s}"
            cols = []
            for key in ("fps", "fps_cpu_time"):
                pairs = [(a.get(key), b.get(key)) for a, b in zip(rows[first], rows[label], strict=True)]
                ratios = [a / b for a, b in pairs if a and b]
                cols.append(
                    f"{statistics.median(ratios):5.2f}x [{min(ratios):.2f}-{max(ratios):.2f}]"
                    if ratios
                    else "-"
                )
            cpus = [x["fps_cpu_time"] for x in rows[label] if x.get("fps_cpu_time")]
            cpu = f"{statistics.median(cpus):8.2f}" if cpus else f"{'-':>8s}"
            print(f"{label:48s} {fps:8.2f} {cpu} {100 * err:8.2f}% {cols[0]:>21s} {cols[1]:>18s} {mem}")


if __name__ == "__main__":
    main()
