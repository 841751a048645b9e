"""Command line: ``pliant demo | run | scenes | info | bench | study | export | fit | observe``.

Each command only parses arguments and calls the public API. User mistakes (a bad scene file, an unknown
device, a missing file) print one ``error:`` line per problem on stderr and exit non-zero, never a
traceback; set ``PLIANT_DEBUG=1`` to see the traceback anyway.

Exit codes: 0 success, 1 user error (a usage mistake included), 2 the simulation diverged (anywhere: the
run, the correction twin of a ``[gaussians.correction]`` scene, ``observe``, ``fit``; one
``pliant: error: diverged at frame ...`` line), 130 interrupted (Ctrl-C).

Nothing here imports Warp (nor ``pliant``'s layers) until a command runs: ``pliant --help`` answers at once
and prints no device warning.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from typing import NoReturn

# The exit codes and CliError live in ._common, below the command modules; pliant.cli.* still names them.
from ._common import (  # noqa: F401 - EXIT_OK is re-exported
    EXIT_DIVERGED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_USER,
    CliError,
    Subparsers,
    _examples,
    _positive_float,
    _positive_int,
    _sub,
    add_force,
)


class _Parser(argparse.ArgumentParser):
    """argparse with pliant's exit code for usage mistakes: 1 (argparse's 2 means "diverged" here)."""

    def error(self, message: str) -> NoReturn:
        import difflib
        import re

        self.print_usage(sys.stderr)
        command = self.prog.removeprefix("pliant").strip()  # "run" for `pliant run`'s parser
        m = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)", message)
        if m:  # a misspelled command or choice
            # Python < 3.12.8 quotes the choices, later versions do not.
            choices = re.findall(r"'([^']*)'", m.group(2)) or [c.strip() for c in m.group(2).split(",")]
            close = difflib.get_close_matches(m.group(1), choices, n=1)
            message += f"; did you mean {close[0]!r}?" if close else ""
        _error(f"{command}: {message}" if command else message)
        raise SystemExit(EXIT_USER)

    def parse_args(  # type: ignore[override]  # only ever called as parse_args(argv)
        self, args: Sequence[str] | None = None, namespace: None = None
    ) -> argparse.Namespace:
        """As argparse, but an unknown option is reported by its command's parser with the closest known
        option (argparse's ``suggest_on_error`` exists only from Python 3.14, and not for options)."""
        ns, extra = self.parse_known_args(args, namespace)
        if extra:
            parser = self._command_parser(getattr(ns, "command", None))
            parser.error(unrecognized(extra, parser))
        return ns

    def _command_parser(self, command: str | None) -> argparse.ArgumentParser:
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction) and command in action.choices:
                return action.choices[command]
        return self


def unrecognized(extra: Sequence[str], parser: argparse.ArgumentParser) -> str:
    """argparse's "unrecognized arguments" message, with "did you mean" for each misspelled option."""
    import difflib

    known = [o for a in parser._actions for o in a.option_strings if o.startswith("--")]
    hints = []
    for arg in extra:
        name = arg.split("=", 1)[0]
        if name.startswith("-"):
            close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
            if close:
                hints.append(f"{name}: did you mean {close[0]}?")
    return "unrecognized arguments: " + " ".join(extra) + "".join(f"; {h}" for h in hints)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``pliant`` (one sub-command per action)."""
    from .. import __version__

    p = _Parser(
        prog="pliant",
        description="Deformable-object simulation (mass-spring, PBD/XPBD, FEM) on NVIDIA Warp.",
        epilog=_examples(
            "pliant demo                      # the cloth demo: out/demo.mp4",
            "pliant scenes                    # the built-in scenes",
            "pliant run rope --frames 60      # a built-in scene",
            "pliant run my_scene.toml --set 'objects[0].material.stiffness=200'",
            "pliant export out/rope.npz --out rope.usd",
            "pliant COMMAND --help            # each command's options",
        )
        + "\n\nexit codes: 0 success, 1 user error, 2 the simulation diverged, 130 interrupted (Ctrl-C)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--version", action="version", version=f"pliant {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    _add_run_parsers(sub)  # demo, run
    _add_tool_parsers(sub)  # scenes, info, bench, study, export
    _add_sweep_view_parsers(sub)  # sweep, view
    from ._fit import add_parsers as _fit_parsers

    _fit_parsers(sub)  # fit, observe
    from ._twin import add_parsers as _twin_parsers

    _twin_parsers(sub)
    return p


def _add_run_parsers(sub: Subparsers) -> None:
    """``pliant demo`` and ``pliant run``'s options."""
    d = _sub(
        sub,
        "demo",
        "simulate the built-in cloth scene and write demo.mp4 + demo.npz",
        "pliant demo",
        "pliant demo --frames 30 --device cpu --out /tmp/demo",
    )
    d.add_argument("--out", default="out", help="output folder (default: out)")
    d.add_argument("--frames", type=_positive_int, help="number of frames (default: the scene's)")
    d.add_argument("--device", help="cpu or cuda:N (default: CUDA when present)")
    d.add_argument("--no-video", action="store_true", help="skip rendering the video")
    d.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    add_force(d)

    r = _sub(
        sub,
        "run",
        "run a scene file or a built-in scene (`pliant scenes` lists them)",
        "pliant run cloth",
        "pliant run my_scene.toml --frames 100 --device cuda:0 --out results",
        "pliant run rope --set 'objects[0].material.stiffness=200' --set scene.frames=10",
        "pliant run rope --integrator RK4 --no-video",
        "pliant run my_scene.toml --resume            # continue after Ctrl-C",
        "pliant run twin.toml --cameras held_out.npz  # splats from new cameras, PSNR / IoU vs their images",
    )
    r.add_argument("scene", help="a scene .toml file or a built-in scene name")
    r.add_argument("--frames", type=_positive_int, help="override [scene] frames")
    r.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="PATH=VALUE",
        dest="overrides",
        help="override any scene field, e.g. 'objects[0].material.stiffness=200' (quoted: [ ] are shell "
        "patterns) or solver.integrator=RK4 (VALUE is a TOML value, else a string; repeatable)",
    )
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
    r.add_argument(
        "--renderer",
        choices=("auto", "mesh", "splats"),
        default="auto",
        help="draw the video as meshes or as the [gaussians] splats (auto: splats when the scene has them)",
    )
    r.add_argument(
        "--cameras",
        metavar="CAMS.npz",
        help="also render the [gaussians] splats from these cameras (K [C,3,3], world_to_camera [C,4,4], "
        "image_size [2] or images [C,T,H,W,3] (+ masks, t)) into <out>/camera_<c>.mp4; with images, print "
        "PSNR and mask IoU per camera",
    )
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    add_force(r)


def _add_tool_parsers(sub: Subparsers) -> None:
    """``pliant scenes``, ``info``, ``bench``, ``study`` and ``export``'s options."""
    sc = _sub(
        sub,
        "scenes",
        "list the built-in scenes, or print one as a starting file",
        "pliant scenes",
        "pliant scenes show cloth > my_cloth.toml   # then edit and: pliant run my_cloth.toml",
    )
    sc.add_argument("action", nargs="?", choices=("list", "show"), default="list", help="default: list")
    sc.add_argument("name", nargs="?", help="the scene to print (with show)")

    i = _sub(
        sub,
        "info",
        "versions, devices and the Warp kernel cache; with a scene, its size and the memory it needs",
        "pliant info",
        "pliant info soft_box --set 'objects[0].cells=100'  # particles, tets, springs, GB before building",
    )
    i.add_argument("scene", nargs="?", help="a scene .toml file or a built-in scene name (optional)")
    i.add_argument(
        "--set", action="append", default=[], metavar="PATH=VALUE", dest="overrides", help="as in pliant run"
    )

    b = _sub(
        sub,
        "bench",
        "run benchmarks (one JSON line each)",
        "pliant bench --list",
        "pliant bench --quick --json bench.jsonl",
    )
    b.add_argument("names", nargs="*", metavar="NAME", help="benchmarks to run (default: all)")
    b.add_argument("--list", action="store_true", help="list the benchmarks and exit")
    b.add_argument("--json", metavar="PATH", help="also append the JSON lines to PATH")
    b.add_argument("--device", help="device passed to benchmarks that take one")
    b.add_argument("--quick", action="store_true", help="smaller problems (smoke test)")
    b.add_argument(
        "--graph",
        action="store_true",
        help="time frames replayed as captured graphs, as the Simulator runs them (rows say graph: true)",
    )

    s = _sub(
        sub,
        "study",
        "run a study (integrators: error vs dt, stability, energy)",
        "pliant study integrators --quick --out /tmp/figures",
    )
    s.add_argument("study", choices=("integrators",))
    s.add_argument("--out", default="docs/figures", help="output folder (default: docs/figures)")
    s.add_argument("--quick", action="store_true", help="fewer step sizes (smoke test)")

    e = _sub(
        sub,
        "export",
        "export a trajectory NPZ to USD (one prim per object), VTU/XDMF (ParaView), PLY / OBJ",
        "pliant export out/cloth.npz --out cloth.usd          # Blender, Omniverse",
        "pliant export out/fem_drop.npz --format vtu --out vtu/   # ParaView: open vtu/frame_series.pvd",
        "pliant export out/fem_drop.npz --out fem_drop.xdmf",
        "pliant export out/rope.npz --format obj --out frames/",
        "pliant export out/rope.npz --out last.ply --frame -1",
    )
    e.add_argument("trajectory", metavar="TRAJ.npz")
    e.add_argument(
        "--format", choices=("ply", "obj", "usd", "vtu", "xdmf"), help="default: from --out's extension"
    )
    e.add_argument(
        "--out", required=True, help="a folder (ply/obj/vtu sequences) or a file (usd, xdmf, or --frame)"
    )
    e.add_argument("--frame", type=int, help="export only this frame (ply/obj; negative counts from the end)")


def _add_sweep_view_parsers(sub: Subparsers) -> None:
    """``pliant sweep`` and ``pliant view``'s options."""
    sw = _sub(
        sub,
        "sweep",
        "run a scene over a grid of --set values (batched copies, or Ray tasks) into DIR/results.csv",
        "pliant sweep cloth --set 'objects[0].material.stiffness=100,200,400' --out sweep/",
        "pliant sweep rope --set 'objects[0].material.stiffness=50,100' --set solver.damping_rate=0,1 "
        "--out s/",
        "pliant sweep cloth --set 'objects[0].material.stiffness=100,200' --ray --out sweep/   # pliant[ray]",
    )
    sw.add_argument("scene", metavar="SCENE")
    sw.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="PATH=V1,V2,...",
        help="a scene field and its values (repeat: the grid is the product)",
    )
    sw.add_argument("--out", required=True, help="output folder (results.csv; a re-run skips finished runs)")
    sw.add_argument(
        "--worlds", type=int, default=16, help="runs stepped together in one simulation (default 16)"
    )
    sw.add_argument("--frames", type=int, help="frames per run (default: the scene's)")
    sw.add_argument("--ray", action="store_true", help="run chunks as Ray tasks (local cluster by default)")
    sw.add_argument("--address", help="an existing Ray cluster's address (with --ray)")
    sw.add_argument("--save-trajectories", action="store_true", help="also write each run's positions")
    sw.add_argument("-q", "--quiet", action="store_true", help="no progress line")
    add_force(sw)
    vw = _sub(
        sub,
        "view",
        "look at a trajectory in the browser, or run a scene live and drag it with the mouse "
        "(needs pliant[viewer])",
        "pliant view out/cloth.npz                 # play back; then open http://127.0.0.1:8080",
        "pliant view cloth                         # live: drag the cloth, change its stiffness, record",
        "pliant view out/fit/fitted.toml --device cuda:0",
        "pliant view out/fem_drop.npz --host 0.0.0.0 --port 8090",
    )
    vw.add_argument("trajectory", metavar="TRAJ.npz|SCENE")
    vw.add_argument("--host", default="127.0.0.1", help="interface (0.0.0.0: reachable from other machines)")
    vw.add_argument("--port", type=int, default=8080, help="TCP port (default 8080)")
    vw.add_argument(
        "--token",
        help="a secret the page's websocket must carry (in the printed URL); default: a random one when "
        "--host is not loopback, none on loopback; --token '' lets anyone who reaches the port in",
    )
    vw.add_argument("--device", help="live: Warp device, e.g. cpu or cuda:0 (default: the scene's)")
    vw.add_argument("--dtype", choices=("float32", "float64"), help="live: precision (default: the scene's)")
    vw.add_argument("--paused", action="store_true", help="live: start paused")
    vw.add_argument("--out", default=".", help="live: folder of the record button's live_<n>.npz/.mp4")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``pliant`` command; returns the exit code."""
    try:
        args = build_parser().parse_args(argv)
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    debug = bool(os.environ.get("PLIANT_DEBUG"))
    try:
        if (
            args.command in ("demo", "run", "sweep", "fit", "observe", "twin")
            and os.environ.get("PLIANT_PREBUILD") != "0"
        ):
            from .._prebuild import warm_up

            # Compiles the first kernel (and Clang's header cache) while the imports and the scene build run.
            warm_up(getattr(args, "device", None))
        if args.command in ("demo", "run"):
            from ._run import cmd_demo, cmd_run

            return cmd_demo(args) if args.command == "demo" else cmd_run(args)
        if args.command == "scenes":
            from ._scenes import cmd_scenes

            return cmd_scenes(args)
        if args.command in ("fit", "observe"):
            from ._fit import cmd_fit, cmd_observe

            return cmd_fit(args) if args.command == "fit" else cmd_observe(args)
        if args.command == "twin":
            from ._twin import cmd_twin

            return cmd_twin(args)
        if args.command == "sweep":
            from ._sweep import cmd_sweep

            return cmd_sweep(args)
        if args.command == "view":
            from ._view import cmd_view

            return cmd_view(args)
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
    except RuntimeError as exc:
        if debug or not _is_divergence(exc):
            raise
        # A divergence outside `pliant run`'s own loop (the correction twin, observe, fit): the same one line
        # and exit code; `simulate` has already saved what the main loop computed.
        _error(str(exc).splitlines()[0])
        return EXIT_DIVERGED


def _is_divergence(exc: BaseException) -> bool:
    """Whether ``exc`` is a :class:`pliant.DivergenceError` (checked without importing Warp: the class can
    only have been raised if its module is loaded)."""
    sim = sys.modules.get("pliant.sim._divergence")
    return sim is not None and isinstance(exc, sim.DivergenceError)


def _error(message: str) -> None:
    for line in message.splitlines() or [""]:
        print(f"pliant: error: {line}", file=sys.stderr)


__all__ = ["CliError", "build_parser", "main"]
