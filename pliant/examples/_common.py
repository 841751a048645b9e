"""What every simulation example shares: its command line and its ``__main__`` run (not an example)."""

from __future__ import annotations

import argparse
import time
from typing import Any


def create_parser(doc: str | None, frames: int) -> argparse.ArgumentParser:
    """The examples' options: ``--device``, ``--frames`` (default ``frames``), ``--output``, ``--test``."""
    p = argparse.ArgumentParser(description=doc)
    p.add_argument("--device", default=None, help="cpu or cuda:N (default: CUDA when present)")
    p.add_argument("--frames", "--num-frames", dest="frames", type=int, default=frames)
    p.add_argument("--output", default=None, help="write a video (.mp4 or .gif)")
    p.add_argument("--test", action="store_true", help="run the physics checks of test_final()")
    return p


def main(example_class: Any, args: argparse.Namespace) -> None:
    """Run ``example_class(args)``; then render ``--output`` and, with ``--test``, its physics checks."""
    example = example_class(args)
    t0 = time.perf_counter()
    example.run(progress=not args.test)
    print(f"{example.frames} frames in {time.perf_counter() - t0:.2f} s")
    if args.output:
        example.render(args.output)
        print(f"wrote {args.output}")
    if args.test:
        example.test_final()
