"""Kernel manifests of the built-in scenes: which Warp modules and overloads their first frames launch.

``Scene.prebuild_kernels`` (called by :func:`pliant.runner.run_scene` and the live viewer, not by
``build_scene``) hands a built-in scene's manifest to :func:`pliant._prebuild.prebuild` (through
:func:`pliant._prebuild.maybe_prebuild`), which compiles them
on two threads before the first step (docs/design.md, "First frame on a fresh kernel cache"). Regenerate the
file after changing kernels or scenes::

    python -m pliant.scene._kernels          # rewrites pliant/scenes/kernels.json (about a minute)

Each scene is recorded in a fresh process with the prebuild off, so an entry lists exactly what the scene
launches in its first three frames on the CPU in float32.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile

from .. import _prebuild
from ._build import build_scene
from ._load import builtin_scenes, load_scene

#: The environment switch of background compilation (:func:`pliant._prebuild.maybe_prebuild`).
ENV = _prebuild.ENV
#: Frames a manifest covers (those tests/test_golden.py checks).
FRAMES = 3


def record_scene(name: str) -> dict:
    """Build and run built-in scene ``name`` for :data:`FRAMES` frames (CPU, float32); its manifest."""
    _prebuild.warm_up("cpu")  # the precompiled header first: no module's cost includes it
    _prebuild.wait()
    _prebuild.time_compiles()
    scene = build_scene(load_scene(name), device="cpu", dtype="float32")
    scene.simulator().run(FRAMES, progress=False)
    return _prebuild.record()


def main() -> None:
    """Record every built-in scene in its own process and write :data:`pliant._prebuild.MANIFEST`."""
    out = {}
    for name in builtin_scenes():
        # A fresh process and an empty kernel cache each: the costs are those of a first build.
        env = {**os.environ, ENV: "0", "WARP_CACHE_PATH": tempfile.mkdtemp(prefix="pliant-kernels-")}
        code = (
            "import json; from pliant.scene._kernels import record_scene; "
            f"print(json.dumps(record_scene({name!r})))"
        )
        res = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
        )
        out[name] = json.loads(res.stdout.strip().splitlines()[-1])
        shutil.rmtree(env["WARP_CACHE_PATH"], ignore_errors=True)
        print(name, len(out[name]["modules"]), "modules", len(out[name]["overloads"]), "overloads")
    _prebuild.MANIFEST.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
