"""``python -m pliant.examples NAME [--test] [options]``; without NAME, the list of examples."""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

from . import available, packaged


def _summary(path: Path) -> str:
    """The first sentence of the comment block under ``# Example ...``, at most ~90 characters."""
    words = []
    for ln in path.read_text(encoding="utf-8").splitlines()[3:12]:
        if not ln.startswith("# ") or ln.startswith("# Command"):
            break
        words.append(ln[2:].strip())
    text = " ".join(words).split(". ")[0].rstrip(".")
    return text if len(text) <= 90 else text[:87].rsplit(" ", 1)[0] + " ..."


def main(argv: list[str]) -> int:
    names = available()
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: python -m pliant.examples NAME [--test] [--frames N] [--device cpu|cuda:0] ...")
        print("examples:")
        for name, path in sorted(names.items()):
            print(f"  {name:<16} {_summary(path)}")
        return 0
    name = argv[0].removesuffix(".py")
    if name not in names:
        print(
            f"pliant.examples: error: no example {name!r}; available: {', '.join(sorted(names))}",
            file=sys.stderr,
        )
        return 1
    sys.argv = [str(names[name]), *argv[1:]]
    if name in packaged():
        runpy.run_module(f"{__package__}.{name}", run_name="__main__", alter_sys=True)
    else:
        runpy.run_path(str(names[name]), run_name="__main__")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
