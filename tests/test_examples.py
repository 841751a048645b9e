"""Every example runs as a script with ``--test --frames 20`` and passes its own physics checks."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.py"))


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_example_passes_its_checks(path):
    """The example exits 0 with --test --frames 20 (its test_final() assertions hold)."""
    # The examples import the pliant of this checkout (not whichever one is installed in the venv).
    root = str(path.parents[1])
    env = {
        **os.environ,
        "PYTHONUNBUFFERED": "1",
        "PYTHONPATH": os.pathsep.join([root, os.environ.get("PYTHONPATH", "")]),
    }
    proc = subprocess.run(
        [sys.executable, str(path), "--test", "--frames", "20", "--device", "cpu"],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=path.parent,
        env=env,
    )
    assert proc.returncode == 0, f"{path.name} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"


def test_examples_exist():
    """The examples the README promises are present."""
    names = {p.stem for p in EXAMPLES}
    assert {"free_fall", "rope_swing", "cloth_drop", "gradients"} <= names
