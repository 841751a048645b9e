"""pliant as the README installs it away from a checkout: a wheel built from the source tree holds every
file the package needs at run time, and installed into a fresh venv, run from a folder outside the
checkout with the checkout nowhere on ``sys.path``, ``pliant demo --frames 2`` writes its outputs.

The wheel is built once per module with ``pip wheel --no-deps`` (no ``build`` package needed; pip fetches
setuptools for the isolated build from the index) from a copy of the source tree, so that ``build/`` and
``*.egg-info`` never land in the checkout. Two installs:

- ``test_wheel_demo_in_a_fresh_venv`` (default suite; about 12 s with a warm Warp kernel cache: 5 s to
  build the wheel, 2 s to install it, 4 s for the demo; 2 shared cores, 2026-11-28) installs the wheel
  with ``--no-deps`` into a venv whose own site-packages comes first and which sees the running
  interpreter's site-packages through a path line, for the dependencies only. A path line does not run
  that site-packages' ``.pth`` files, so an editable pliant installed there (``make test``'s ``.venv``)
  stays out of reach: the test checks that ``pliant.__file__`` lies inside the new venv. This proves the
  wheel's own contents.
- ``test_wheel_installs_with_its_dependencies`` (slow: about 50 s with a warm pip cache, 40 s of it pip
  installing about 900 MB of dependencies; longer when they must be downloaded) installs the wheel with
  its dependencies into a venv that sees nothing else, which proves pyproject's dependency list as well.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PIP = [sys.executable, "-m", "pip", "--disable-pip-version-check", "--no-input"]


def _run(cmd: list[str], cwd: Path, env: dict | None = None, timeout: float = 600) -> str:
    r = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, f"{cmd} exited {r.returncode}:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r.stdout


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel built from a copy of the checkout's pyproject.toml, README.md, LICENSE and pliant/."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(ROOT / name, src / name)
    shutil.copytree(ROOT / "pliant", src / "pliant", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    _run([*PIP, "wheel", "--no-deps", "-q", "-w", str(tmp / "dist"), str(src)], cwd=tmp)
    (whl,) = (tmp / "dist").glob("pliant-*.whl")
    return whl


def _package_files() -> set[str]:
    """Files under pliant/ that the checkout holds: git's tracked list, else every file but bytecode."""
    if (ROOT / ".git").exists() and shutil.which("git"):
        out = _run(["git", "ls-files", "-z", "pliant"], cwd=ROOT)
        files = {f for f in out.split("\0") if f}
    else:
        files = {p.relative_to(ROOT).as_posix() for p in (ROOT / "pliant").rglob("*") if p.is_file()}
    return {f for f in files if "__pycache__" not in f and (ROOT / f).is_file()}


def test_wheel_holds_every_package_file(wheel):
    """Every file of pliant/ (modules, subpackages, scenes, kernels.json, benchmark references, py.typed)
    is in the wheel, and the README's wheel file name is the one the build writes."""
    names = set(zipfile.ZipFile(wheel).namelist())
    missing = sorted(_package_files() - names)
    assert not missing, (
        f"the wheel lacks {missing}: name them in pyproject.toml's [tool.setuptools.package-data] "
        "(data files) or give the folder an __init__.py (modules)"
    )
    for must in ("pliant/py.typed", "pliant/scenes/kernels.json", "pliant/scenes/cloth.toml"):
        assert must in names
    entry = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith(".dist-info/entry_points.txt")))
    assert "pliant = pliant.cli:main" in entry.decode()
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    shown = set(re.findall(r"dist/(pliant-[^\s\"\[]+\.whl)", readme))
    assert shown == {wheel.name}, f"README.md names {sorted(shown)}; the build writes {wheel.name}"


def _venv(path: Path) -> Path:
    """A new venv without pip (the running pip installs into it with --python); returns its python."""
    _run([sys.executable, "-m", "venv", "--without-pip", str(path)], cwd=path.parent)
    py = path / ("Scripts/python.exe" if os.name == "nt" else "bin/python")
    assert py.is_file()
    return py


def _clean_env(venv: Path) -> dict:
    """The environment of a user who activated ``venv``: no PYTHONPATH, no other venv."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON") and k != "VIRTUAL_ENV"}
    bindir = venv / ("Scripts" if os.name == "nt" else "bin")
    env["PATH"] = str(bindir) + os.pathsep + env.get("PATH", "")
    env["VIRTUAL_ENV"] = str(venv)
    env["PYTHONNOUSERSITE"] = "1"
    return env


_PROBE = """
import json, sys
import pliant, pliant._extras, pliant._prebuild, pliant.cli._scenes
print(json.dumps({"file": pliant.__file__, "path": sys.path, "checkout": str(pliant._extras.checkout_root()),
                  "manifests": sorted(pliant._prebuild._manifests())}))
"""


def _demo_from_venv(venv: Path, py: Path, tmp_path: Path) -> None:
    """Run ``pliant demo --frames 2`` with the venv's console script from a folder outside the checkout,
    after checking that the venv's pliant is the one imported and that the checkout is not on the path."""
    env = _clean_env(venv)
    work = tmp_path / "user"
    work.mkdir()
    probe = json.loads(_run([str(py), "-c", _PROBE], cwd=work, env=env).strip().splitlines()[-1])
    assert Path(probe["file"]).resolve().is_relative_to(venv.resolve()), probe["file"]
    # The checkout's source must not be importable: no path entry is the checkout or holds its pliant/. (The
    # dependencies' site-packages may lie inside the checkout, as make test's .venv does: it is reached by a
    # path line, which runs none of its .pth files, so its editable pliant stays out of reach.)
    source = (ROOT / "pliant" / "__init__.py").resolve()
    on_path = [
        p
        for p in probe["path"]
        if p and (Path(p).resolve() == ROOT or (Path(p) / "pliant" / "__init__.py").resolve() == source)
    ]
    assert not on_path, f"the checkout's source is on the venv's sys.path: {on_path}"
    assert probe["checkout"] == "None"
    scenes = sorted(p.stem for p in (ROOT / "pliant" / "scenes").glob("*.toml"))
    assert probe["manifests"] == sorted(json.loads((ROOT / "pliant/scenes/kernels.json").read_text()))
    assert set(probe["manifests"]) <= set(scenes)

    script = venv / ("Scripts/pliant.exe" if os.name == "nt" else "bin/pliant")
    out = _run(
        [str(script), "demo", "--frames", "2", "--device", "cpu", "-q", "--out", "out"], cwd=work, env=env
    )
    assert "625 particles" in out, out
    npz, mp4 = work / "out" / "demo.npz", work / "out" / "demo.mp4"
    assert mp4.is_file() and mp4.stat().st_size > 1000
    with np.load(npz) as z:
        x = z["x"]  # positions [m], (frames + 1, particles, 3)
    assert x.shape == (3, 625, 3)  # the initial state and two frames of the 24 x 24 cloth
    assert np.isfinite(x).all()
    # Gravity acted: two frames (1/15 s) move the unpinned particles down, the two pinned corners not.
    drop = x[0, :, 1] - x[-1, :, 1]
    assert (drop > 1e-4).sum() >= 600 and (np.abs(drop) < 1e-6).sum() >= 2


def test_wheel_demo_in_a_fresh_venv(wheel, tmp_path):
    """The wheel, installed without its dependencies into a fresh venv that borrows them from the running
    interpreter's site-packages (after its own), runs ``pliant demo`` away from the checkout."""
    venv = tmp_path / "venv"
    py = _venv(venv)
    own = Path(
        _run([str(py), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"], cwd=tmp_path).strip()
    )
    deps = dict.fromkeys([sysconfig.get_path("purelib"), sysconfig.get_path("platlib")])
    (own / "_running_interpreter_deps.pth").write_text("".join(f"{d}\n" for d in deps))
    _run([*PIP, "--python", str(py), "install", "-q", "--no-deps", str(wheel)], cwd=tmp_path)
    _demo_from_venv(venv, py, tmp_path)


@pytest.mark.slow
def test_wheel_installs_with_its_dependencies(wheel, tmp_path):
    """The wheel, installed with its dependencies from the package index into a venv that sees nothing
    else, satisfies them (``pip check``) and runs ``pliant demo`` away from the checkout."""
    venv = tmp_path / "venv"
    py = _venv(venv)
    _run([*PIP, "--python", str(py), "install", "-q", str(wheel)], cwd=tmp_path)
    _run([*PIP, "--python", str(py), "check"], cwd=tmp_path)
    _demo_from_venv(venv, py, tmp_path)
