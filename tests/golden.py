"""Golden trajectories of the built-in scenes: a few frames of each, on the CPU, as a regression fixture.

Regenerate (only when a change is meant to alter the motion, and say why in the commit):

    python -m tests.golden            # writes tests/data/golden/<scene>.npz

The test (`tests/test_golden.py`) runs the same frames with the current code and compares.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np

GOLDEN_DIR = Path(__file__).parent / "data" / "golden"
FRAMES = 3  # enough to pass contact, handles and the first implicit steps; small enough for the default suite


def simulate(name: str, frames: int = FRAMES) -> np.ndarray:
    """Positions [frames + 1, N, 3] of built-in scene ``name`` run for ``frames`` frames on the CPU."""
    import pliant as pl

    scene = _build(pl, name)
    traj = scene.simulator().run(frames, progress=False)
    return np.asarray(traj.x)


def _build(pl, name: str):
    return pl.scene.build_scene(pl.scene.load_scene(name), device="cpu")


def scene_names() -> list[str]:
    import pliant as pl

    return list(pl.scene.builtin_scenes())


def main(argv: list[str]) -> int:
    GOLDEN_DIR.mkdir(parents=True, exist_ok=True)
    names = argv or scene_names()
    for name in names:
        x = simulate(name)
        np.savez_compressed(GOLDEN_DIR / f"{name}.npz", x=x, meta=json.dumps({"frames": FRAMES}))
        print(f"{name}: {x.shape} {x.dtype}", flush=True)
    return 0


if __name__ == "__main__":
    os.environ.setdefault("PLIANT_DEVICE", "cpu")
    sys.exit(main(sys.argv[1:]))
