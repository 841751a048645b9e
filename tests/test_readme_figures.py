"""The figures of README.md and docs/*.md that are tagged with the command printing them are reproduced.

A tag is an HTML comment (invisible when rendered) right after the figure::

    <!-- figure {"id": "...", "run": ["pliant ...", ...], "extra": ["--no-video", ...], "find": "REGEX",
         "value": 480.0, "tol": 1.0, "slow": false} -->

``run`` are the commands as the text shows them (each must appear verbatim in the 3000 characters before the
tag: the figure names its command), ``extra`` options appended to each when the test runs it (``-q``,
``--no-video``: nothing that changes the figure), ``find`` a regular expression on the last command's output
whose group is the figure (two groups: their ratio), ``value`` ± ``tol`` what the text says. Commands run
in a fresh folder; paths under ``benchmarks/`` and ``tests/data/`` are the repository's. Figures whose
commands take seconds run in the default suite (the demo's counts: 15 s on a loaded 2-core machine); the
others are ``slow`` (the splat drift 73 s there, 10-15 s idle; the fit_rope fit 75 s; the cross-engine
fits 1-4 minutes; the default fit of docs/fit.md's Newton cloth 31 s).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TAG = re.compile(r"<!-- figure (\{.*?\}) -->", re.S)


def tagged_figures() -> list[tuple[str, dict, str]]:
    """(file, tag, the text before it) of every tagged figure."""
    out = []
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = path.read_text(encoding="utf-8")
        for m in TAG.finditer(text):
            out.append((path.name, json.loads(m.group(1)), text[max(0, m.start() - 3000) : m.start()]))
    return out


FIGURES = tagged_figures()


def test_figures_are_tagged_and_name_their_commands():
    """At least the README's fit and splat figures are tagged, and every tag's commands appear in the text
    just before it (a reader sees the command that printed the figure)."""
    ids = {tag["id"] for _, tag, _ in FIGURES}
    assert {"demo_counts", "fit_rope_stiffness", "splat_drift", "cross_engine_default"} <= ids, ids
    assert len(ids) == len(FIGURES), "figure ids must be unique"
    for name, tag, before in FIGURES:
        for cmd in tag["run"]:
            assert cmd in before, f"{name}: figure {tag['id']}: the text does not show `{cmd}`"


def _argv(cmd: str, extra: str) -> list[str]:
    argv = shlex.split(cmd) + shlex.split(extra)
    if argv[0] == "pliant":
        argv = [sys.executable, "-m", "pliant.cli", *argv[1:]]
    elif argv[0] == "python":
        argv[0] = sys.executable
    return [str(ROOT / a) if a.startswith(("benchmarks/", "tests/data/")) else a for a in argv]


@pytest.mark.parametrize(
    "tag",
    [
        pytest.param(tag, id=tag["id"], marks=[pytest.mark.slow] if tag.get("slow") else [])
        for _, tag, _ in FIGURES
    ],
)
def test_figure_is_reproduced(tag, tmp_path):
    """Run the figure's commands and find the printed figure within its tolerance."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PLIANT_PREBUILD": "0"}
    extras = tag.get("extra", [""] * len(tag["run"]))
    output = ""
    for cmd, extra in zip(tag["run"], extras, strict=True):
        proc = subprocess.run(
            _argv(cmd, extra), cwd=tmp_path, env=env, capture_output=True, text=True, timeout=1800
        )
        output = proc.stdout + proc.stderr
        assert proc.returncode == 0, f"`{cmd}` exited {proc.returncode}:\n{output[-3000:]}"
    m = re.search(tag["find"], output)
    assert m, f"{tag['id']}: no match for {tag['find']!r} in:\n{output[-3000:]}"
    groups = [float(g) for g in m.groups()]
    value = groups[0] / groups[1] if len(groups) == 2 else groups[0]
    assert abs(value - tag["value"]) <= tag["tol"], f"{tag['id']}: {value:.6g}, the text says {tag['value']}"
