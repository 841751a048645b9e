"""The soft box drop at equal accuracy: pliant's rows and the peers interleaved on one core, every run's
speed beside its ``trajectory_error``; medians and paired ratios.

Two errors per run, both the largest deviation of the centre-of-mass height over frames 1-24 (fall,
impact, rebound) relative to the 0.1 m drop (``pliant.bench._box_motion``):

* ``own error``: against the same code converged (pliant: the stored float64 reference; a peer: its own run
  at a much smaller step, computed once per driver run, ``REFERENCES``). This is the accuracy a speed is
  bought at: a speed claim stands only at ``own error`` <= 2 %.
* ``vs pliant``: against pliant's reference. It measures how far the peer's *physics* is from pliant's
  (MuJoCo's soft contact and StVK material, Newton's contact penalty), not its convergence.

Run from the repository root with pliant's venv (the peers run from ``--peers-python``, a venv with
newton==1.8.0, mujoco==4.0.0 and taichi==1.7.4; see README.md):

    .venv/bin/python benchmarks/peers/run_side_by_side.py --rounds 3 --out /tmp/side_by_side.jsonl
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

PEERS = Path(__file__).resolve().parent
FRAME = 1.0 / 60.0


def _pliant(call: str) -> list[str]:
    """A command printing ``pliant.bench._fem``'s ``call`` (a row of BENCHMARKS, or soft_box_drop) as JSON."""
    code = f"import json; from pliant.bench._fem import BENCHMARKS, soft_box_drop; print(json.dumps({call}))"
    return [sys.executable, "-c", code]


def _pliant_row(row: str) -> list[str]:
    return _pliant(f"BENCHMARKS[{row!r}]()")


def _pliant_drop(**kwargs: object) -> list[str]:
    return _pliant("soft_box_drop({})".format(", ".join(f"{k}={v!r}" for k, v in kwargs.items())))


def configs(py: str) -> dict[str, tuple[list[str], str | None]]:
    """label -> (command printing one JSON row with ``com_curve`` or ``trajectory_error``, family)."""
    newton = [py, str(PEERS / "soft_box_newton.py")]
    mujoco = [py, str(PEERS / "soft_box_mujoco.py")]
    taichi = [py, str(PEERS / "soft_box_taichi.py")]
    return {
        "pliant symplectic + penalty, 16 substeps, f32": (_pliant_row("soft_box_drop_10_explicit"), None),
        "pliant ImplicitMidpoint L-BFGS (AMG H0), 12 substeps": (
            _pliant_row("soft_box_drop_10_implicit"),
            None,
        ),
        "pliant BackwardEuler L-BFGS, 1 step/frame": (_pliant_row("soft_box_drop_10_backward_euler"), None),
        "pliant BackwardEuler L-BFGS, 128 substeps": (
            _pliant_drop(n=10, method="implicit", substeps=128, dtype="float64"),
            None,
        ),
        "mujoco flex CG, 2.08 ms (8/frame)": (
            [*mujoco, "--solver", "CG", "--timestep", str(FRAME / 8)],
            "mj",
        ),
        "mujoco flex CG, 1/60 s": ([*mujoco, "--solver", "CG", "--timestep", str(FRAME)], "mj"),
        "newton VBD 10 substeps x 10": (
            [*newton, "--solver", "vbd", "--substeps", "10", "--iterations", "10"],
            "vbd",
        ),
        "newton SemiImplicit 50 substeps": (
            [*newton, "--solver", "semi", "--substeps", "50"]
            + ["--collide-every", "50", "--contact-gap", "0.05"],
            "semi",
        ),
        "taichi symplectic + penalty, 16 substeps, f32": ([*taichi, "--substeps", "16"], "ti"),
    }


def references(py: str) -> dict[str, list[str]]:
    """Each peer family's converged run (24 frames): 8-16x smaller steps than its rows, tight tolerances."""
    newton = [py, str(PEERS / "soft_box_newton.py"), "--frames", "24"]
    mujoco = [py, str(PEERS / "soft_box_mujoco.py"), "--frames", "24"]
    taichi = [py, str(PEERS / "soft_box_taichi.py"), "--frames", "24"]
    return {
        "mj": [*mujoco, "--solver", "CG", "--timestep", str(FRAME / 128), "--tolerance", "1e-10"],
        "vbd": [*newton, "--solver", "vbd", "--substeps", "80", "--iterations", "10"],
        "semi": [*newton, "--solver", "semi", "--substeps", "800"],
        "ti": [*taichi, "--substeps", "256", "--f64"],  # float64: g dt² is a few float32 ulps of the height
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
    import numpy as np

    from pliant.bench._box_motion import reference_curve, trajectory_error

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--core", default="1")
    ap.add_argument("--peers-python", default="/work/peers-venv/bin/python")
    ap.add_argument("--only", nargs="*", help="substrings of config names to run (the first always runs)")
    ap.add_argument("--out", default=None, help="append every row as a JSON line here")
    args = ap.parse_args()

    cfgs = configs(args.peers_python)
    first = next(iter(cfgs))
    if args.only:
        cfgs = {k: v for k, v in cfgs.items() if k == first or any(s in k for s in args.only)}
    ref = reference_curve(10)
    own_ref = {}
    for fam, cmd in references(args.peers_python).items():
        if any(f == fam for _, f in cfgs.values()):
            r = run(cmd, args.core)
            own_ref[fam] = np.asarray(r["com_curve"]) if "com_curve" in r else None
            print(f"{fam} reference: {r.get('error') or 'ok'}", file=sys.stderr, flush=True)
    rows: dict[str, list[dict]] = {k: [] for k in cfgs}
    for r in range(args.rounds):
        for name, (cmd, fam) in cfgs.items():  # interleaved: A B C ... A B C ...
            row = run(cmd, args.core)
            if "com_curve" in row:
                curve = np.asarray(row.pop("com_curve"))
                row["trajectory_error"] = trajectory_error(curve, ref)
                mine = own_ref.get(fam)
                row["own_error"] = trajectory_error(curve, mine) if mine is not None else None
            elif "trajectory_error" in row:
                row["own_error"] = row["trajectory_error"]  # pliant: its reference is its own physics
            row["config"], row["round"] = name, r
            rows[name].append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
            if args.out:
                with open(args.out, "a") as f:
                    f.write(json.dumps(row) + "\n")

    def med(name: str, key: str) -> float:
        vals = [x[key] for x in rows[name] if x.get(key) is not None]
        return statistics.median(vals) if vals else float("nan")

    print(f"\nsoft box 10^3, medians of {args.rounds} interleaved rounds on core {args.core}")
    head = f"{'dt [ms]':>8s} {'s/sim s':>8s} {'N x first':>10s} {'own err':>8s} {'vs pliant':>9s}"
    print(f"{'config':48s} {head}")
    for name in cfgs:
        ok = [x for x in rows[name] if "wall_s" in x]
        if not ok:
            print(f"{name:48s} FAILED: {rows[name][0].get('error')}")
            continue
        # This row's time over the first row's, within each round (same load), then the median.
        paired = statistics.median(
            p["wall_per_sim_s"] / q["wall_per_sim_s"]
            for p, q in zip(rows[name], rows[first], strict=True)
            if "wall_s" in p and "wall_s" in q
        )
        print(
            f"{name:48s} {ok[-1]['dt'] * 1e3:8.3f} {med(name, 'wall_per_sim_s'):8.3f} {paired:9.2f}x "
            f"{100 * med(name, 'own_error'):7.2f}% {100 * med(name, 'trajectory_error'):8.2f}%"
        )
    print("(own err: against the same code converged; vs pliant: against pliant's reference, a physics gap)")


if __name__ == "__main__":
    main()
