"""How far each solver's soft-box trajectory is from its own converged one (equal-accuracy comparison).

Runs pliant's soft box drop (``pliant.bench._fem``) with Newton at 1e-6 m/s as the converged reference and
L-BFGS at the tolerances given, and MuJoCo's flex with CG at its benchmark tolerance against MuJoCo Newton at
1e-12; prints, per run, the largest deviation of the centre-of-mass height over the 60 frames [µm]. Run from
the repository root with pliant's venv (the peers run from ``--peers-python``):

    .venv/bin/python benchmarks/peers/accuracy.py --tolerances 1e-3 1e-2 2e-2
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

PLIANT = (
    "import json, sys; from pliant.bench._fem import soft_box_drop; "
    "print(json.dumps(soft_box_drop(10, 'implicit', dtype='float64', minimizer=sys.argv[3], "
    "trajectory=sys.argv[1], newton_tol=float(sys.argv[2]))))"
)


def pliant_run(path: Path, tol: float, minimizer: str) -> dict:
    cmd = [sys.executable, "-c", PLIANT, str(path), str(tol), minimizer]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def mujoco_run(py: str, path: Path, *extra: str) -> dict:
    cmd = [py, "benchmarks/peers/soft_box_mujoco.py", "--trajectory", str(path), *extra]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tolerances", type=float, nargs="+", default=[1e-3, 1e-2, 2e-2])
    ap.add_argument("--peers-python", default="/work/peers-venv/bin/python")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp())
    rows = []
    ref = tmp / "pliant_ref.npy"
    pliant_run(ref, 1e-6, "newton")
    for tol in args.tolerances:
        p = tmp / f"pliant_{tol}.npy"
        r = pliant_run(p, tol, "lbfgs")
        err = float(np.abs(np.load(p) - np.load(ref)).max())
        rows.append(("pliant L-BFGS", f"{tol:g} m/s", r["iterations_per_step"], err))
    mref = tmp / "mujoco_ref.npy"
    mujoco_run(args.peers_python, mref, "--solver", "Newton", "--tolerance", "1e-12", "--iterations", "1000")
    for solver in ("CG", "Newton"):
        p = tmp / f"mujoco_{solver}.npy"
        r = mujoco_run(args.peers_python, p, "--solver", solver)
        err = float(np.abs(np.load(p) - np.load(mref)).max())
        rows.append((f"MuJoCo {solver}", f"{r['tolerance']:g}", r["iterations_per_step"], err))
    print(f"{'solver':16s} {'tolerance':>10s} {'iters/step':>10s} {'max |com - com_converged| [um]':>32s}")
    for name, tol, its, err in rows:
        print(f"{name:16s} {tol:>10s} {its:10.2f} {err * 1e6:32.2f}")


if __name__ == "__main__":
    main()
