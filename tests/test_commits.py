"""Commit habits (docs/design.md, "Contributing"): one change per commit, a subject of at most 72
characters, and a body that says why. Checked on every commit after the rule was adopted."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: The last commit before the rule; older history is left as it is.
BASE = "91dd376"


def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)


def _commits() -> list[tuple[str, str, str]]:
    if shutil.which("git") is None or _git("rev-parse", "--git-dir").returncode != 0:
        pytest.skip("not a git checkout")
    if _git("cat-file", "-e", f"{BASE}^{{commit}}").returncode != 0:
        pytest.skip(f"{BASE} is not in this clone's history (a shallow clone)")
    out = _git("log", "--no-merges", "--format=%h%x1f%s%x1f%b%x1e", f"{BASE}..HEAD").stdout
    rows = [r.strip("\n").split("\x1f") for r in out.split("\x1e") if r.strip()]
    return [(h, s, b) for h, s, b in rows]


def test_subjects_are_short():
    long = [f"{h} ({len(s)} chars): {s}" for h, s, _ in _commits() if len(s) > 72]
    assert not long, "commit subjects over 72 characters:\n" + "\n".join(long)


def test_every_commit_says_why():
    bare = [f"{h}: {s}" for h, s, b in _commits() if not b.strip()]
    assert not bare, "commits without a body saying why:\n" + "\n".join(bare)
