"""``pliant scenes [list | show NAME]``: the built-in scenes, one line each, or one as a starting file."""

from __future__ import annotations

import argparse
import importlib.resources

from ._common import EXIT_OK, CliError


def _text(name: str) -> str:
    return (importlib.resources.files("pliant") / "scenes" / f"{name}.toml").read_text(encoding="utf-8")


def scene_summary(text: str) -> str:
    """One line describing a scene file: its ``[scene] description``, else its leading comment's first
    sentence (the built-in scenes open with a comment saying what happens)."""
    lines = []
    for line in text.splitlines():
        stripped = line.strip()
        if not stripped.startswith("#"):
            break
        lines.append(stripped.lstrip("#").strip())
    words = " ".join(w for w in lines if w)
    words = words.split(". ")[0].rstrip(".")  # the first sentence
    head, colon, tail = words.partition(": ")
    if colon and len(head) >= 30:  # "A cantilever beam (...): what happens" -> the subject
        words = head
    elif colon:  # "The demo: a cloth held at ..." -> what it is
        words = tail[:1].upper() + tail[1:]
    if len(words) > 100:
        words = words[:97].rsplit(" ", 1)[0] + " ..."
    return words


def cmd_scenes(args: argparse.Namespace) -> int:
    """``pliant scenes``: list; ``pliant scenes show NAME``: print the TOML of a built-in scene."""
    # Listed here rather than through pliant.scene, which loads Warp: `pliant scenes` answers at once.
    root = importlib.resources.files("pliant") / "scenes"
    names = sorted(p.name[: -len(".toml")] for p in root.iterdir() if p.name.endswith(".toml"))
    if args.action == "show":
        if not args.name:
            raise CliError("scenes show: give a scene name; `pliant scenes` lists them")
        if args.name not in names:
            raise CliError(
                f"scenes show: no built-in scene {args.name!r}; built-in scenes: {', '.join(names)}"
            )
        print(_text(args.name), end="")
        return EXIT_OK
    if args.name:
        raise CliError(f"scenes: unexpected {args.name!r}; did you mean `pliant scenes show {args.name}`?")
    width = max(len(n) for n in names)
    for n in names:
        print(f"{n:<{width}}  {scene_summary(_text(n))}")
    return EXIT_OK
