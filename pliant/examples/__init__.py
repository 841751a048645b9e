"""Runnable examples, shipped with the package: ``python -m pliant.examples NAME [--test] [options]``.

Each example is a module ``pliant/examples/NAME.py`` with an ``Example`` class and a ``__main__`` block
(``--test`` runs its physics checks). ``python -m pliant.examples`` lists them. A new example is one file
in this folder; ``examples/NAME.py`` in the repository is a three-line wrapper that runs it, and in a
source checkout a script placed only in ``examples/`` is found too (it does not ship until moved here).
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path


def packaged() -> dict[str, Path]:
    """Examples inside the package: name → file."""
    root = importlib.resources.files(__name__)
    return {
        p.name[:-3]: Path(str(p))
        for p in root.iterdir()
        if p.name.endswith(".py") and not p.name.startswith("_")
    }


def checkout() -> dict[str, Path]:
    """Scripts in a source checkout's ``examples/`` folder that are not wrappers of packaged ones."""
    folder = Path(__file__).resolve().parents[2] / "examples"
    if not folder.is_dir():
        return {}
    out = {}
    for p in sorted(folder.glob("*.py")):
        if 'runpy.run_module("pliant.examples.' not in p.read_text(encoding="utf-8", errors="replace"):
            out[p.stem] = p
    return out


def available() -> dict[str, Path]:
    """Every example this installation can run: packaged ones first, then a checkout's own scripts."""
    return {**checkout(), **packaged()}


__all__ = ["available", "checkout", "packaged"]
