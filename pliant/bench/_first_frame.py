"""Time to the first frame on a fresh kernel cache: from process start to the end of frame 1, for the demo
and every built-in scene (issue #15 goal: the demo within 4 s, every scene within 6 s).

Each measurement starts a new Python process with an empty ``WARP_CACHE_PATH`` and goes the way ``pliant
run`` does (background warm-up, load, build, one frame); the same scene with ``PLIANT_PREBUILD=0`` (no
background compilation) runs beside it in the same round, so the row shows both sides. Wall seconds: the
wait a user sees, on a machine where other work may run (report spread, not single figures).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable

from ._common import print_rows

_CHILD = """
import os, time
if os.environ.get("PLIANT_PREBUILD") != "0":
    from pliant._prebuild import warm_up
    warm_up("cpu")
from pliant.scene import build_scene, load_scene
scene = build_scene(load_scene({name!r}), device="cpu")
scene.prebuild_kernels()
scene.simulator().run(1, progress=False)
print("FIRST_FRAME_AT", time.time())
"""


def first_frame_seconds(name: str, prebuild: bool = True) -> float:
    """Wall seconds from starting a process to the end of built-in scene ``name``'s first frame, with an
    empty kernel cache; ``prebuild`` False turns the background compilation off."""
    with tempfile.TemporaryDirectory(prefix="pliant-ff-") as cache:
        env = {**os.environ, "WARP_CACHE_PATH": cache, "PLIANT_PREBUILD": "1" if prebuild else "0"}
        t0 = time.time()
        out = subprocess.run(
            [sys.executable, "-c", _CHILD.format(name=name)],
            capture_output=True,
            text=True,
            env=env,
            check=True,
        ).stdout
    line = [ln for ln in out.splitlines() if ln.startswith("FIRST_FRAME_AT")][-1]
    return float(line.split()[1]) - t0


def first_frame(quick: bool = False) -> dict:
    """The demo (``cloth``) and every built-in scene (quick: the demo and the FEM box), with and without
    background compilation, one round each (two for the demo)."""
    from ..scene import builtin_scenes

    names = ["cloth", "soft_box_fem"] if quick else builtin_scenes()
    rows = {}
    for name in names:
        rounds = 2 if name == "cloth" else 1
        on = [first_frame_seconds(name, True) for _ in range(rounds)]
        off = [first_frame_seconds(name, False) for _ in range(rounds)]
        rows[name] = {"prebuild_s": round(min(on), 2), "serial_s": round(min(off), 2)}
    worst = max(r["prebuild_s"] for r in rows.values())
    return {
        "what": "seconds from process start to the end of frame 1, empty kernel cache, CPU",
        "demo_s": rows["cloth"]["prebuild_s"],
        "worst_scene_s": worst,
        "goal": "demo <= 4 s, every scene <= 6 s",
        "scenes": rows,
    }


BENCHMARKS: dict[str, Callable[..., dict]] = {"first_frame": first_frame}


if __name__ == "__main__":
    print_rows(BENCHMARKS, sys.argv[1:])
