"""Cloth drape benchmark (pliant.bench._mass_spring): one JSON line per run.

A 1 m cloth of n × n cells, 0.5 kg, E·t = 1000 N/m, ν = 0.3, pinned at two adjacent corners, falls from
the horizontal and hangs for 300 frames of 1/60 s. Each line has fps, particle-substeps/s and the sag
against the converged reference.

Usage:
    python benchmarks/bench_cloth.py                         # the default table (64, 128; both methods)
    python benchmarks/bench_cloth.py --n 64 128 256 --method implicit --iterations 20
    python benchmarks/bench_cloth.py --n 64 --method symplectic --substeps 80
    python benchmarks/bench_cloth.py --reference 64 --device cuda:0   # recompute a reference sag
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one CPU core; must precede the NumPy import

import argparse  # noqa: E402
import json  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[64, 128], help="cells per side")
    ap.add_argument(
        "--method", nargs="+", default=["implicit", "symplectic"], help="implicit | symplectic | force"
    )
    ap.add_argument("--substeps", type=int, default=None, help="substeps per frame (default: stable count)")
    ap.add_argument("--iterations", type=int, default=None, help="CG iterations per implicit step")
    ap.add_argument("--damping-rate", type=float, default=1.0, help="velocity damping c [1/s]")
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--dtype", default="float32")
    ap.add_argument("--reference", type=int, default=None, help="compute the converged sag for this n")
    args = ap.parse_args()

    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.config.quiet = True
    from pliant.bench._mass_spring import IMPLICIT_ITERATIONS, SYMPLECTIC_SUBSTEPS, cloth_drape, reference_sag

    if args.reference is not None:
        ref = reference_sag(args.reference, device=args.device)
        print(json.dumps({"n": args.reference, "reference_sag": ref}))
        return
    for n in args.n:
        for method in args.method:
            sub = args.substeps or (1 if method == "implicit" else SYMPLECTIC_SUBSTEPS.get(n, 5 * n // 4))
            its = args.iterations or IMPLICIT_ITERATIONS.get(n, max(20, n // 6))
            row = cloth_drape(
                n,
                method,
                sub,
                its,
                damping_rate=args.damping_rate,
                frames=args.frames,
                device=args.device,
                dtype=args.dtype,
            )
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
