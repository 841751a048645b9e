"""Background compilation (pliant._prebuild): the built-in scenes' kernel manifests match the kernels, a
prebuilt scene compiles nothing more in its first frames, and no module is ever built twice."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
import warp as wp

from pliant import _prebuild
from pliant.scene import build_scene, builtin_scenes, load_scene

REGENERATE = "regenerate pliant/scenes/kernels.json with `python -m pliant.scene._kernels`"


@pytest.mark.parametrize(
    "t",
    [wp.float32, wp.float64, wp.int32, wp.vec3f, wp.vec3d, wp.mat33f, wp.vec2i, wp.vec4f],
)
def test_type_json_round_trip(t):
    j = _prebuild._type_json(t)
    assert j is not None
    assert _prebuild._type_json(_prebuild._type_from_json(j)) == j
    arr = {"array": 2, "dtype": j}
    back = _prebuild._type_from_json(arr)
    assert back.ndim == 2 and _prebuild._type_json(back.dtype) == j


@pytest.mark.parametrize("t", [int, float, bool])
def test_python_scalars_round_trip(t):
    assert _prebuild._type_from_json(_prebuild._type_json(t)) is t


def test_every_builtin_scene_has_a_manifest():
    stored = json.loads(_prebuild.MANIFEST.read_text())
    assert sorted(stored) == sorted(builtin_scenes()), REGENERATE


@pytest.mark.parametrize("name", builtin_scenes())
def test_manifest_entries_name_existing_kernels(name, monkeypatch):
    """Every module and overload a manifest lists exists, with the argument count it records."""
    monkeypatch.setenv("PLIANT_PREBUILD", "0")
    build_scene(load_scene(name), device="cpu", dtype="float32")
    import pliant.sim._simulator  # noqa: F401  (the Simulator's module: created when a run starts)

    manifest = _prebuild.manifest_for(name)
    mods = _prebuild._user_modules()
    missing = [m for m in manifest["modules"] if m not in mods]
    assert not missing, f"{name}: modules {missing} no longer exist; {REGENERATE}"
    for e in manifest["overloads"]:
        k = mods[e["module"]].kernels.get(e["kernel"])
        assert k is not None, f"{name}: kernel {e['module']}.{e['kernel']} is gone; {REGENERATE}"
        assert len(k.adj.args) == len(e["args"]), f"{name}: {e['kernel']} changed its arguments; {REGENERATE}"


_COVERED = """
import json, os
os.environ["PLIANT_PREBUILD"] = "1"
from pliant import _prebuild
from pliant.scene import build_scene, load_scene
from pliant.scene._kernels import FRAMES
out = {}
for name in ("cloth", "soft_box_fem", "xpbd_soft_body"):
    scene = build_scene(load_scene(name), device="cpu", dtype="float32")
    scene.prebuild_kernels()  # what run_scene does before its first step
    _prebuild.wait()
    mods = _prebuild._user_modules()
    listed = _prebuild.manifest_for(name)["modules"]
    before = {n: dict(mods[n].execs) for n in listed}
    scene.simulator().run(FRAMES, progress=False)
    out[name] = {
        "unloaded": [n for n in listed if not before[n]],
        "reloaded": [
            n for n, ex in before.items() if any(mods[n].execs.get(k) is not v for k, v in ex.items())
        ],
    }
print(json.dumps(out))
"""


def test_a_prebuilt_scene_loads_nothing_more_in_its_first_frames():
    """After the prebuild, every listed module is loaded and the scene's first frames load none of them
    again: the manifest covers what they launch (in a process of its own: the overloads it registers must
    not change which modules later tests build together)."""
    out = subprocess.run(
        [sys.executable, "-c", _COVERED], capture_output=True, text=True, check=True, timeout=300
    ).stdout
    result = json.loads(out.strip().splitlines()[-1])
    for name, r in result.items():
        assert not r["unloaded"], f"{name}: not loaded by the prebuild: {r['unloaded']}"
        assert not r["reloaded"], f"{name}: loaded again (a missing overload): {r['reloaded']}; {REGENERATE}"


_CHILD = """
import collections, json
import warp._src.build as wb
built = collections.Counter()
orig = wb.build_cpu
def counting(obj_path, *a, **k):
    built[obj_path.rsplit("/", 1)[-1]] += 1
    return orig(obj_path, *a, **k)
wb.build_cpu = counting
from pliant._prebuild import warm_up
warm_up("cpu")
from pliant.scene import build_scene, load_scene
scene = build_scene(load_scene("soft_box_fem"), device="cpu")
scene.prebuild_kernels()
scene.simulator().run(1, progress=False)
print(json.dumps(built))
"""


def test_fresh_cache_builds_every_module_once(tmp_path):
    """With an empty kernel cache, the warm-up, the background prebuild and the main thread together build
    each module exactly once (the threads never race on one)."""
    env = {**os.environ, "WARP_CACHE_PATH": str(tmp_path), "PLIANT_PREBUILD": "1"}
    out = subprocess.run(
        [sys.executable, "-c", _CHILD], capture_output=True, text=True, env=env, check=True, timeout=300
    ).stdout
    built = json.loads(out.strip().splitlines()[-1])
    assert len(built) >= 8, built
    twice = {k: n for k, n in built.items() if n > 1}
    assert not twice, f"built more than once: {twice}"
    names = {_prebuild.module_of_object(k) for k in built}
    assert len(names) == len(built), f"one module built with two hashes (a recompile): {sorted(built)}"
