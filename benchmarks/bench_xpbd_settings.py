"""XPBD colouring settings of the cloth drape side by side: frames/s and trajectory_error per (substeps, ω).

Each round runs every setting once (``pliant.bench._xpbd.cloth_drape``: the timed 30-frame fall, frames
replayed as CPU graphs as ``pliant bench --graph`` does, then an untimed run for ``trajectory_error``), so
a loaded machine slows all settings of a round alike; the summary gives medians and the paired ratio of
each setting to the first. Run on one core from the repository root (issue 42 item 3):

    taskset -c 0 .venv/bin/python benchmarks/bench_xpbd_settings.py --n 64 --rounds 3 \\
        --settings 100:1.0 50:1.6
"""

from __future__ import annotations

import argparse
import json
import os
import statistics


def main() -> None:
    """Parse the arguments, run the interleaved rounds, print one JSON line per run and a summary."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, nargs="+", default=[64], help="cells per side")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument(
        "--settings", nargs="+", default=["100:1.0", "50:1.6"], help="SUBSTEPS:OMEGA, the first is the base"
    )
    ap.add_argument("--no-graph", action="store_true", help="launch the frames instead of replaying graphs")
    ap.add_argument("--json", help="also append the JSON lines to this file")
    args = ap.parse_args()
    if not args.no_graph:
        os.environ["PLIANT_BENCH_GRAPH"] = "1"  # read by pliant.bench._common.run_timed
    from pliant.bench._xpbd import cloth_drape

    settings = [(int(s), float(w)) for s, w in (x.split(":") for x in args.settings)]
    out = open(args.json, "a") if args.json else None  # noqa: SIM115 - closed below
    for n in args.n:
        fps: dict[tuple[int, float], list[float]] = {s: [] for s in settings}
        errors: dict[tuple[int, float], float] = {}
        for r in range(args.rounds):
            for sub, omega in settings:
                row = cloth_drape(n, "coloring", substeps=sub, relaxation=omega)
                line = {"n": n, "round": r, "substeps": sub, "omega": omega, "graph": row["graph"]}
                line |= {"fps": row["fps"], "trajectory_error": row["trajectory_error"]}
                fps[(sub, omega)].append(row["fps"])
                errors[(sub, omega)] = row["trajectory_error"]
                print(json.dumps(line), flush=True)
                if out:
                    out.write(json.dumps(line) + "\n")
        base = fps[settings[0]]
        for s in settings:
            ratios = [a / b for a, b in zip(fps[s], base, strict=True)]
            summary = {"n": n, "substeps": s[0], "omega": s[1], "median_fps": statistics.median(fps[s])}
            summary |= {"trajectory_error": errors[s], "median_ratio_to_first": statistics.median(ratios)}
            print(json.dumps({"summary": summary}), flush=True)
            if out:
                out.write(json.dumps({"summary": summary}) + "\n")
    if out:
        out.close()


if __name__ == "__main__":
    main()
