"""``pliant run`` and ``pliant demo``: simulate a scene, save the trajectory, render the video."""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ._common import EXIT_DIVERGED, EXIT_INTERRUPTED, EXIT_OK, EXIT_USER, CliError

if TYPE_CHECKING:
    from ..scene import SceneConfig

#: Exit status of each :attr:`pliant.runner.RunReport.status`.
STATUS_EXIT = {"ok": EXIT_OK, "diverged": EXIT_DIVERGED, "interrupted": EXIT_INTERRUPTED, "failed": EXIT_USER}

#: Mesh files a scene can reference (``kind = "mesh"``) but that are not scenes themselves.
MESH_SUFFIXES = (".obj", ".ply", ".stl", ".msh", ".vtk", ".vtu", ".off", ".mesh")


def mesh_instead_of_scene(scene: str) -> str | None:
    """For a mesh file given where a scene is expected, the lines of a scene that runs it stably
    (:func:`pliant.scene.from_mesh` when the file can be read), else None. The first line is the error; the
    rest is a TOML file to copy (``pliant run`` prints it on stdout, without a prefix)."""
    from pathlib import PurePath

    p = PurePath(scene)
    if p.suffix.lower() not in MESH_SUFFIXES:
        return None
    from ..scene import from_mesh, mesh_scene_toml

    stem = "".join(c if c.isalnum() or c in "_-" else "_" for c in p.stem) or "my_mesh"
    try:
        toml = from_mesh(scene).toml
    except Exception:  # an unreadable mesh: the scene's own error will name the problem when it runs
        toml = mesh_scene_toml(scene, None)
    first = (
        f"{scene} is a mesh, not a scene file; a scene says what to do with it. Save the lines below as "
        f"{stem}.toml next to it (`pliant run {scene} > {stem}.toml` does) and run `pliant run {stem}.toml`:"
    )
    return first + "\n" + toml


def _load(scene: str, overrides: list[str] | None = None, *, force: bool = False) -> SceneConfig:
    """The validated scene (``force``: without the size checks, as ``--force``)."""
    import warnings

    if Path(scene).suffix.lower() in MESH_SUFFIXES and Path(scene).is_file():
        # A missing file gets the loader's "no such scene file". The scene to copy goes to stdout as plain
        # lines (no "pliant: error:" prefix), the error line to stderr.
        first, _, toml = (mesh_instead_of_scene(scene) or "").partition("\n")  # a mesh suffix: a str
        print(toml, flush=True)
        raise CliError(first)
    from ..scene import load_scene

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DeprecationWarning)
        cfg = load_scene(scene, overrides or (), force=force)
    for w in caught:  # renamed scene keys: one note each, naming the new key; other warnings as usual
        if issubclass(w.category, DeprecationWarning):
            print(f"pliant: note: {w.message}", file=sys.stderr)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return cfg


def _apply_overrides(cfg: SceneConfig, args: argparse.Namespace) -> None:
    """Command-line options replace the scene file's values (already validated by argparse)."""
    if getattr(args, "frames", None) is not None:
        cfg.scene.frames = args.frames
    if getattr(args, "dt", None) is not None:
        print("pliant: note: --dt is deprecated; use --frame-dt (the frame duration [s])", file=sys.stderr)
        if getattr(args, "frame_dt", None) is None:
            args.frame_dt = args.dt
    if getattr(args, "frame_dt", None) is not None:
        if not 1e-6 <= args.frame_dt <= 10.0:
            raise CliError("--frame-dt must be in [1e-06, 10] s")
        cfg.scene.frame_dt = args.frame_dt
    if getattr(args, "substeps", None) is not None:
        if not 1 <= args.substeps <= 10_000:
            raise CliError("--substeps must be in [1, 10000]")
        cfg.scene.substeps = args.substeps
    if getattr(args, "integrator", None):
        from ..scene import integrator_names

        # Only those a scene can step with: the list an error prints is the list that is accepted.
        names = integrator_names(system_only=True)
        key = args.integrator.lower().replace("-", "").replace("_", "")
        if not any(n.lower() == key for n in names):
            ode = next((n for n in integrator_names() if n.lower() == key), None)
            why = (
                f"{ode} integrates ODEs only, not a scene"
                if ode
                else f"unknown integrator {args.integrator!r}"
            )
            raise CliError(f"--integrator: {why}; available: {', '.join(names)}")
        cfg.solver.integrator = args.integrator
        cfg.solver.integrator_options = {}
    if getattr(args, "checkpoint_every", None) is not None:
        cfg.output.checkpoint_every = args.checkpoint_every


def simulate(
    cfg: SceneConfig,
    out: Path,
    name: str,
    *,
    device: str | None = None,
    dtype: str | None = None,
    resume: bool = False,
    video: bool = True,
    quiet: bool = False,
    resume_hint: str = "",
    renderer: str = "auto",
    cameras: str | None = None,
) -> int:
    """``pliant run``'s call of :func:`pliant.runner.run_scene`: its lines printed as the run goes, then
    what it wrote and how it ended; returns the exit status.

    Raises:
        CliError: a user error found before the run (:class:`pliant.runner.RunError`).
    """
    from ..runner import RunError, run_scene

    def say(line: str) -> None:
        print(line, flush=True)

    try:
        report = run_scene(
            cfg,
            out,
            name,
            device=device,
            dtype=dtype,
            resume=resume,
            video=video,
            renderer=renderer,
            cameras=cameras,
            progress=not quiet,
            log=say,
        )
    except RunError as exc:
        raise CliError(str(exc)) from None
    for w in report.written:
        print(f"wrote {w}")
    note = report.message
    if report.interrupted_at is not None and resume_hint:
        note += f"; resume with: {resume_hint} --resume"
    if report.status == "diverged":
        print(f"pliant: error: {note} (partial outputs kept)", file=sys.stderr)
    elif report.status == "failed":
        print(f"pliant: error: {note}", file=sys.stderr)
    elif report.status == "interrupted":
        print(f"pliant: {note}", file=sys.stderr)
    return STATUS_EXIT[report.status]


def cmd_run(args: argparse.Namespace) -> int:
    """``pliant run SCENE``."""
    cfg = _load(args.scene, args.overrides, force=args.force)
    _apply_overrides(cfg, args)
    hint = ["pliant", "run", args.scene, "--out", args.out] + (["--force"] if args.force else [])
    for item in args.overrides:
        hint += ["--set", item]
    for opt in ("frames", "frame_dt", "substeps", "integrator", "device", "dtype", "cameras"):
        val = getattr(args, opt, None)
        if val is not None:
            hint += [f"--{opt.replace('_', '-')}", str(val)]
    return simulate(
        cfg,
        Path(args.out),
        cfg.scene.name,
        device=args.device,
        dtype=args.dtype,
        resume=args.resume,
        video=not args.no_video,
        quiet=args.quiet,
        resume_hint=shlex.join(hint),
        renderer=args.renderer,
        cameras=getattr(args, "cameras", None),
    )


def cmd_demo(args: argparse.Namespace) -> int:
    """``pliant demo``: the built-in cloth scene, written as ``<out>/demo.mp4`` and ``<out>/demo.npz``."""
    cfg = _load("cloth", force=args.force)
    _apply_overrides(cfg, args)
    out = Path(args.out)
    t0 = time.perf_counter()
    status = simulate(
        cfg,
        out,
        "demo",
        device=args.device,
        video=not args.no_video,
        quiet=args.quiet,
    )
    print(f"demo done in {time.perf_counter() - t0:.1f} s", flush=True)
    if not args.no_video and (out / "demo.mp4").exists():
        print(f"video: {(out / 'demo.mp4').resolve()}")
    return status
