"""Run pliant's soft box drop and the peer scripts interleaved on one core; print medians and ratios.

Stdlib only. Run from the repository root:

    python3 benchmarks/peers/run_side_by_side.py --rounds 3 --out /tmp/side_by_side.jsonl

pliant runs from ``.venv``, the peers from ``--peers-python`` (a venv with newton==1.8.0 and mujoco==4.0.0).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys

PEERS = "benchmarks/peers"


def configs(py: str) -> dict[str, list[str]]:
    newton = [py, f"{PEERS}/soft_box_newton.py"]
    mujoco = [py, f"{PEERS}/soft_box_mujoco.py"]
    return {
        "pliant implicit L-BFGS (BackwardEuler)": [".venv/bin/pliant", "bench", "soft_box_drop_10_implicit"],
        "pliant implicit L-BFGS float32": [
            ".venv/bin/python",
            "-c",
            "import json; from pliant.bench._fem import BENCHMARKS; "
            "print(json.dumps(BENCHMARKS['soft_box_drop_10_implicit'](dtype='float32')))",
        ],
        "pliant implicit Newton (direct)": [".venv/bin/pliant", "bench", "soft_box_drop_10_implicit_newton"],
        "newton VBD 10x10 (examples' setting)": [
            *newton,
            "--solver",
            "vbd",
            "--substeps",
            "10",
            "--iterations",
            "10",
        ],
        "newton VBD 1x40": [*newton, "--solver", "vbd", "--substeps", "1", "--iterations", "40"],
        "newton VBD 1x10": [*newton, "--solver", "vbd", "--substeps", "1", "--iterations", "10"],
        "newton SemiImplicit 50 substeps": [
            *newton,
            "--solver",
            "semi",
            "--substeps",
            "50",
            "--collide-every",
            "50",
            "--contact-gap",
            "0.05",
        ],  # fmt: skip
        "mujoco flex discrete/CG": [*mujoco, "--solver", "CG"],
        "mujoco flex discrete/Newton": [*mujoco, "--solver", "Newton"],
    }


def run(cmd: list[str], core: str) -> dict:
    out = subprocess.run(["taskset", "-c", core, *cmd], capture_output=True, text=True, check=False)
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("{")]
    if out.returncode or not lines:
        return {"error": (out.stderr or out.stdout).strip().splitlines()[-1:]}
    row = json.loads(lines[-1])
    row.setdefault("wall_per_sim_s", row["wall_s"] / (row["frames"] / 60.0))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--core", default="0")
    ap.add_argument("--peers-python", default="/work/peers-venv/bin/python")
    ap.add_argument("--only", nargs="*", help="substrings of config names to run (pliant always runs)")
    ap.add_argument("--out", default=None, help="append every row as a JSON line here")
    args = ap.parse_args()

    cfgs = configs(args.peers_python)
    if args.only:
        cfgs = {k: v for k, v in cfgs.items() if k.startswith("pliant") or any(s in k for s in args.only)}
    rows: dict[str, list[dict]] = {k: [] for k in cfgs}
    for r in range(args.rounds):
        for name, cmd in cfgs.items():  # interleaved: A B C ... A B C ...
            row = run(cmd, args.core)
            row["config"], row["round"] = name, r
            rows[name].append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
            if args.out:
                with open(args.out, "a") as f:
                    f.write(json.dumps(row) + "\n")

    def med(name: str, key: str) -> float | None:
        vals = [x[key] for x in rows[name] if x.get(key) is not None]
        return statistics.median(vals) if vals else None

    base = med(next(iter(cfgs)), "wall_per_sim_s")
    # Ratio within each round (same load), then the median: less sensitive to drift than a ratio of medians.
    first = next(iter(cfgs))
    paired = {}
    for name in cfgs:
        rs = [
            p["wall_per_sim_s"] / q["wall_per_sim_s"]
            for p, q in zip(rows[name], rows[first], strict=True)
            if "wall_s" in p and "wall_s" in q
        ]
        paired[name] = statistics.median(rs) if rs else float("nan")
    print(f"{'config':40s} {'tets':>5s} {'dt [ms]':>8s} {'iters':>6s} {'s/step':>8s} {'s/sim s':>8s} "
          f"{'peer/pliant':>11s} {'paired':>6s} {'com':>7s} {'top':>7s} {'bottom':>7s} "
          f"{'vmax':>6s}")  # fmt: skip
    for name in cfgs:
        if not any("wall_s" in x for x in rows[name]):
            print(f"{name:40s} FAILED: {rows[name][0].get('error')}")
            continue
        last = rows[name][-1]
        w = med(name, "wall_per_sim_s")
        print(
            f"{name:40s} {last['elements']:5d} {last['dt'] * 1e3:8.3f} {last['iterations_per_step']:6.2f} "
            f"{med(name, 'time_per_step_s'):8.4f} {w:8.3f} {w / base:11.2f} {paired[name]:6.2f} "
            f"{med(name, 'final_height_com'):7.4f} {med(name, 'final_height_top'):7.4f} "
            f"{med(name, 'final_height_bottom'):7.4f} "
            f"{med(name, 'final_max_speed'):6.3f}"
        )
    print(
        f"(medians of {args.rounds} interleaved runs on core {args.core}; "
        "peer/pliant = peer's wall per simulated second over pliant's: >= 2 is the claim)"
    )


if __name__ == "__main__":
    main()
