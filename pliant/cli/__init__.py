"""Command line: ``pliant demo | run | info | bench | study | export | fit | observe``.

Each command only parses arguments and calls the public API. User mistakes (a bad scene file, an unknown
device, a missing file) print one ``error:`` line per problem on stderr and exit non-zero, never a
traceback; set ``PLIANT_DEBUG=1`` to see the traceback anyway.

Exit codes: 0 success, 1 user error, 2 the simulation diverged, 130 interrupted (Ctrl-C).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence

EXIT_OK, EXIT_USER, EXIT_DIVERGED, EXIT_INTERRUPTED = 0, 1, 2, 130


class CliError(Exception):
    """A user error the CLI reports as one line (``exit_code`` defaults to 1)."""

    def __init__(self, message: str, exit_code: int = EXIT_USER) -> None:
        super().__init__(message)
        self.exit_code = exit_code


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {v}")
    return v


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not v > 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
    return v


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``pliant`` (one sub-command per action)."""
    p = argparse.ArgumentParser(
        prog="pliant",
        description="Deformable-object simulation (mass-spring, PBD/XPBD, FEM) on NVIDIA Warp.",
    )
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    d = sub.add_parser("demo", help="simulate the built-in cloth scene and write demo.mp4 + demo.npz")
    d.add_argument("--out", default="out", help="output folder (default: out)")
    d.add_argument("--frames", type=_positive_int, help="number of frames (default: the scene's)")
    d.add_argument("--device", help="cpu or cuda:N (default: CUDA when present)")
    d.add_argument("--no-video", action="store_true", help="skip rendering the video")
    d.add_argument("-q", "--quiet", action="store_true", help="no progress bars")

    r = sub.add_parser("run", help="run a scene file or a built-in scene (cloth, rope, soft_box, points)")
    r.add_argument("scene", help="a scene .toml file or a built-in scene name")
    r.add_argument("--frames", type=_positive_int, help="override [scene] frames")
    r.add_argument("--frame-dt", type=_positive_float, help="override [scene] frame_dt: frame duration [s]")
    r.add_argument("--dt", type=_positive_float, help="deprecated name of --frame-dt")
    r.add_argument("--substeps", type=_positive_int, help="override [scene] substeps")
    r.add_argument("--integrator", metavar="NAME", help="override [solver] integrator (e.g. RK4)")
    r.add_argument("--device", help="cpu or cuda:N (default: the scene's, else CUDA when present)")
    r.add_argument("--dtype", choices=("float32", "float64"), help="override [scene] dtype")
    r.add_argument("--out", default="out", help="output folder (default: out)")
    r.add_argument("--resume", action="store_true", help="continue from <out>/<name>.ckpt.npz")
    r.add_argument("--checkpoint-every", type=_positive_int, metavar="N", help="frames between checkpoints")
    r.add_argument("--no-video", action="store_true", help="skip rendering the video")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bars")

    sub.add_parser("info", help="versions, devices and the Warp kernel cache")

    b = sub.add_parser("bench", help="run benchmarks (one JSON line each)")
    b.add_argument("names", nargs="*", metavar="NAME", help="benchmarks to run (default: all)")
    b.add_argument("--list", action="store_true", help="list the benchmarks and exit")
    b.add_argument("--json", metavar="PATH", help="also append the JSON lines to PATH")
    b.add_argument("--device", help="device passed to benchmarks that take one")
    b.add_argument("--quick", action="store_true", help="smaller problems (smoke test)")

    s = sub.add_parser("study", help="run a study (integrators: error vs dt, stability, energy)")
    s.add_argument("study", choices=("integrators",))
    s.add_argument("--out", default="docs/figures", help="output folder (default: docs/figures)")
    s.add_argument("--quick", action="store_true", help="fewer step sizes (smoke test)")

    e = sub.add_parser("export", help="export a trajectory NPZ to PLY / OBJ (sequences) or USD")
    e.add_argument("trajectory", metavar="TRAJ.npz")
    e.add_argument("--format", choices=("ply", "obj", "usd"), help="default: from --out's extension")
    e.add_argument("--out", required=True, help="a folder (ply/obj sequences) or a file (usd, or --frame)")
    e.add_argument("--frame", type=int, help="export only this frame (ply/obj; negative counts from the end)")
    from ._fit import add_parsers as _fit_parsers

    _fit_parsers(sub)  # fit, observe
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``pliant`` command; returns the exit code."""
    args = build_parser().parse_args(argv)
    debug = bool(os.environ.get("PLIANT_DEBUG"))
    try:
        if args.command in ("demo", "run"):
            from ._run import cmd_demo, cmd_run

            return cmd_demo(args) if args.command == "demo" else cmd_run(args)
        if args.command in ("fit", "observe"):
            from ._fit import cmd_fit, cmd_observe

            return cmd_fit(args) if args.command == "fit" else cmd_observe(args)
        from ._misc import cmd_bench, cmd_export, cmd_info, cmd_study

        return {"info": cmd_info, "bench": cmd_bench, "study": cmd_study, "export": cmd_export}[args.command](
            args
        )
    except CliError as exc:
        if debug:
            raise
        _error(str(exc))
        return exc.exit_code
    except KeyboardInterrupt:
        _error("interrupted")
        return EXIT_INTERRUPTED
    except (ValueError, FileNotFoundError, NotImplementedError, ImportError, OSError) as exc:
        if debug:
            raise
        _error(str(exc) or type(exc).__name__)
        return EXIT_USER


def _error(message: str) -> None:
    for line in message.splitlines() or [""]:
        print(f"pliant: error: {line}", file=sys.stderr)


__all__ = ["CliError", "build_parser", "main"]
