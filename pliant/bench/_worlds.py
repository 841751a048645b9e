"""Many runs in one simulation: throughput of W copies of a 16 × 16 cloth stepped together (``pl.sweep``'s
batched chunks), in runs × frames per CPU second, against one run alone. Each copy has its own stiffness.
Figures: ``runs_frames_per_s`` per W and ``speedup`` = that over W = 1's (goal ≥ 10 at W = 256 on one core).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

from ._common import print_rows


def worlds_cloth_16(quick: bool = False) -> dict:
    """W = 1, 16, 256 (quick: 1, 4) copies of the 16 × 16 cloth, 10 frames (quick: 2) of 80 substeps."""
    from ..sweep._sweep import run_chunk

    counts, frames = ((1, 4), 2) if quick else ((1, 16, 256), 10)
    base = ["objects[0].nx=16", "objects[0].ny=16"]
    run_chunk("cloth", [base, base], 1, None)  # compile outside the timing
    rates, sags = {}, {}
    for w in counts:
        runs = [[*base, f"objects[0].material.stiffness={300.0 + k}"] for k in range(w)]
        t0 = time.process_time()
        rows = run_chunk("cloth", runs, frames, None)
        cpu = time.process_time() - t0
        assert all(r["status"] == "ok" for r in rows), rows[0]
        rates[w] = w * frames / cpu
        sags[w] = rows[0]["sag"]
    one = rates[counts[0]]
    from ..scene import load_scene

    solver = load_scene("cloth").solver
    return {
        "scene": "cloth 16x16 (pliant/scenes/cloth.toml)",
        "solver": solver.kind,
        "integrator": solver.integrator,
        "frames": frames,
        "runs_frames_per_s": {str(w): round(r, 2) for w, r in rates.items()},
        "speedup": {str(w): round(r / one, 2) for w, r in rates.items()},
        # the first copy moves as the run alone does, whatever W is (a sanity figure)
        "sag_first_copy_m": {str(w): round(s, 9) for w, s in sags.items()},
    }


BENCHMARKS: dict[str, Callable[..., dict]] = {"worlds_cloth_16": worlds_cloth_16}


if __name__ == "__main__":
    print_rows(BENCHMARKS, sys.argv[1:])
