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

#: Mesh files a scene can reference (``kind = "mesh"``) but that are not scenes themselves.
MESH_SUFFIXES = (".obj", ".ply", ".stl", ".msh", ".vtk", ".vtu", ".off", ".mesh")


#: Strain under the body's own weight that the suggested spring stiffness gives (1 %: it keeps its shape).
MESH_SAG = 0.01
#: ω·Δt of the stiffest particle in the suggested scene: half the explicit limit 2 (a margin over the
#: Gershgorin bound of the spring network's highest frequency).
MESH_OMEGA_DT = 1.0


def mesh_scene_values(path: str | Path, density: float = 1000.0, frame_dt: float = 1.0 / 60.0) -> dict:
    """Spring stiffness and substeps that run ``path`` (a mesh file) as a stable mass-spring scene.

    The mesh is filled with tets as ``kind = "mesh"`` does (TetGen for a closed surface) and the scene's
    masses are lumped the same way (ρ·V/4 per tet corner). Stiffness: a spring network of edge length h
    behaves like a material of modulus E ≈ k/h, and a column of height H sags by the strain ρ g H / E under
    its own weight, so k = ρ g H h / ``MESH_SAG``. Substeps: the network's highest angular frequency is
    bounded by Gershgorin, ω² ≤ max_i 2 k n_i / m_i (n_i springs at particle i of mass m_i), and symplectic
    Euler is stable for ω Δt < 2; the substeps make ω Δt = ``MESH_OMEGA_DT``.

    Args:
        path: a surface (.obj, .ply, .stl, ...) or tet mesh (.msh, .vtk, .vtu) file.
        density: ρ [kg/m³] (the scene's default for a mesh object).
        frame_dt: the frame duration [s] (the scene's default).

    Returns:
        ``stiffness`` [N/m], ``substeps``, ``particles``, ``mass`` [kg], ``height`` [m] (the mesh's extent)
        and ``lift`` [m], the upward shift that puts its lowest point 10 % of that extent above y = 0.
    """
    import math

    import numpy as np

    from ..geometry import TetMesh, edges_from_tets, load_mesh, signed_tet_volumes, tetrahedralize

    mesh = load_mesh(path)
    pts = np.asarray(mesh.points, np.float64)
    if isinstance(mesh, TetMesh):
        tets = np.asarray(mesh.tets)
    else:
        tm = tetrahedralize(pts, mesh.triangles, name=str(path))
        pts, tets = np.asarray(tm.points, np.float64), np.asarray(tm.tets)
    m = np.zeros(len(pts))
    np.add.at(m, tets.ravel(), np.repeat(np.abs(signed_tet_volumes(pts, tets)) * density / 4.0, 4))
    edges = edges_from_tets(tets)
    h = float(np.median(np.linalg.norm(pts[edges[:, 0]] - pts[edges[:, 1]], axis=1)))
    height = float(np.ptp(pts, axis=0).max())
    k = density * 9.81 * height * h / MESH_SAG
    k = float(f"{k:.2g}")  # two significant digits (rounding changes ω by < 5 %, within the margin)
    n = np.bincount(edges.ravel(), minlength=len(pts))
    used = m > 0
    omega = math.sqrt(float(np.max(2.0 * k * n[used] / m[used])))
    substeps = max(1, math.ceil(frame_dt * omega / MESH_OMEGA_DT))
    lift = 0.1 * height - float(pts[:, 1].min())  # the lowest point 10 % of the size above the ground
    return {
        "stiffness": k,
        "substeps": substeps,
        "particles": len(pts),
        "mass": float(m.sum()),
        "height": height,
        "lift": lift,
    }


def mesh_instead_of_scene(scene: str) -> str | None:
    """For a mesh file given where a scene is expected, the lines of a scene that runs it stably (stiffness
    and substeps from :func:`mesh_scene_values` when the file can be read), else None. The first line is
    the error; the rest is a TOML file to copy (``pliant run`` prints it on stdout, without a prefix)."""
    from pathlib import PurePath

    p = PurePath(scene)
    if p.suffix.lower() not in MESH_SUFFIXES:
        return None
    stem = "".join(c if c.isalnum() or c in "_-" else "_" for c in p.stem) or "my_mesh"
    try:
        v = mesh_scene_values(scene)
    except Exception:  # an unreadable mesh: the scene's own error will name the problem when it runs
        v = None
    lines = [
        f"{scene} is a mesh, not a scene file; a scene says what to do with it. Save the lines below as "
        f"{stem}.toml next to it (`pliant run {scene} > {stem}.toml` does) and run `pliant run {stem}.toml`:",
        "# a closed surface is filled with tets, a tet mesh used as is; it falls onto the ground.",
        '# Add scale, origin, rotation = [x, y, z] degrees or up = "z" to [[objects]] as needed;',
        "# `pliant scenes show soft_box` shows a complete scene.",
    ]
    if v is not None:
        lines += [
            "[scene]",
            f"substeps = {v['substeps']}   # explicit steps per frame: ω·Δt ≤ {MESH_OMEGA_DT:g} (< 2) for "
            "the stiffest particle",
        ]
    lines += ["[[objects]]", 'kind = "mesh"', f'path = "{p.name}"']
    if v is not None:
        lines.append(f"origin = [0.0, {v['lift']:.3g}, 0.0]   # [m]: its lowest point just above the ground")
        lines.append(
            f"material = {{ stiffness = {v['stiffness']:g} }}   # [N/m]: sags ~{MESH_SAG:.0%} under its own "
            f"weight ({v['particles']} particles, {v['mass']:.3g} kg, {v['height']:.3g} m)"
        )
    else:
        lines.append("material = { stiffness = 500 }   # [N/m]; raise [scene] substeps if it diverges")
    lines += ["[ground]", "friction = 0.5"]
    return "\n".join(lines)


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
) -> int:
    """Build, run, save ``<out>/<name>.npz`` (+ ``.mp4``, ``.ckpt.npz``) and print a summary.

    Every output path is checked first (one file name inside ``out``, links followed), then the video's
    frame rate, then the scene is built and its initial state checked: a mistake in any of them is an
    error before anything is simulated or written.
    """
    import numpy as np

    from ..io._paths import OutputPathError, check_file_stem, check_writable_dir, confined
    from ..scene import build_scene
    from ..sim import DivergenceError
    from ..solvers import SingularSystemError

    try:
        check_file_stem(name, "scene name")
        traj_path, video_path, ckpt, render_path = (
            confined(out, f"{name}{suffix}") for suffix in (".npz", ".mp4", ".ckpt.npz", ".render.npz")
        )
        check_writable_dir(out)  # a forbidden --out fails now, not after the simulation
    except OutputPathError as exc:
        raise CliError(str(exc)) from None
    want_video = video and cfg.output.video
    if want_video:
        from ..render import check_fps

        fps = getattr(cfg.output, "fps", None)
        if fps is not None:
            try:
                check_fps(fps)
            except ValueError as exc:
                raise CliError(f"output.fps: {exc}") from None
    # A value that overflows the model's dtype (origin 1e39 in float32) is reported by the frame-0 check
    # below, not as NumPy's RuntimeWarning.
    with np.errstate(over="ignore", invalid="ignore"):
        scene = build_scene(cfg, device=device, dtype=dtype)
    m = scene.model
    if want_video:
        try:
            check_fps(scene.fps)
        except ValueError as exc:
            raise CliError(
                f"video frame rate (output.fps, default 1/frame_dt): {exc}; or use --no-video"
            ) from None
    if resume and not ckpt.exists():
        raise CliError(f"--resume: no checkpoint at {ckpt}; run once without --resume first")
    from ._splats import splat_run

    splats = splat_run(cfg, scene, renderer, quiet=quiet)  # [gaussians]: splats, twin, corrector
    sim = scene.simulator()
    info = sim.solver.describe()
    counts = f"{m.particle_count} particles, {m.spring_count} springs" + (
        f", {m.tet_count} tets" if m.tet_count else ""
    )
    solver = f"{info.get('solver', type(sim.solver).__name__)}/{info.get('integrator', '-')}"
    print(
        f"{name}: {counts}; {scene.frames} frames x {scene.substeps} substeps "
        f"(frame_dt {scene.frame_dt:.4g} s), "
        f"{solver} on {m.device} {m.dtype}",
        flush=True,
    )
    status, note = EXIT_OK, ""
    t0 = time.perf_counter()
    if not resume:
        try:
            sim.check_initial_state()  # non-finite → a user error, with nothing written
        except DivergenceError as exc:
            raise CliError(str(exc)) from None
    try:
        traj = sim.run(
            scene.frames,
            progress=not quiet,
            record_velocity=cfg.output.record_velocity,
            checkpoint=ckpt,
            checkpoint_every=cfg.output.checkpoint_every,
            resume=resume,
            on_frame=splats.on_frame if splats is not None else None,
        )
    except KeyboardInterrupt:
        traj, status = sim.trajectory(), EXIT_INTERRUPTED
        note = f"interrupted at frame {sim.frame} of {scene.frames}; partial outputs kept" + (
            f"; resume with: {resume_hint} --resume" if resume_hint else ""
        )
    except (DivergenceError, SingularSystemError) as exc:
        # A singular implicit system mid-run (masses lost next to h²K) ends the run as a divergence does:
        # the frames so far are written, the message says what to change, exit 2.
        traj, status = sim.trajectory(), EXIT_DIVERGED
        note = str(exc)
    wall = time.perf_counter() - t0
    steps = max(traj.frame_count - 1, 0) * scene.substeps
    written = []
    if cfg.output.trajectory:
        from ..live import scene_trajectory_meta

        # What `pliant export` draws beside the objects: the drawn colliders (static meshes) and the ground.
        traj.meta.update(scene_trajectory_meta(scene))
        written.append(str(traj.save(traj_path)))
        if scene.embeddings and traj.frame_count > 0:
            # What the video draws (particles, the fine embedded surface, colliders) as <name>.render.npz.
            from ..io import Trajectory

            xf, ff, _ = scene.render_mesh(traj.x, traj.faces)
            fine = Trajectory(x=xf, t=traj.t, faces=ff, meta={**traj.meta, "render_mesh": True})
            written.append(str(fine.save(render_path)))
    rate = f", {m.particle_count * steps / wall:.3g} particle-substeps/s" if wall > 0 and steps else ""
    print(f"simulated {traj.frame_count - 1} frames in {wall:.2f} s{rate}", flush=True)
    if splats is not None and splats.twin_x is not None and status == EXIT_OK:
        print(splats.drift_summary(traj.x), flush=True)
    if want_video and traj.frame_count > 0:
        t1 = time.perf_counter()
        try:
            from ..render import render_video

            xr, fr, colors = scene.render_mesh(traj.x, traj.faces)
            if splats is not None and splats.draw:
                splats.render_video(traj.x, video_path, scene.fps, progress=not quiet)
            else:
                render_video(
                    xr,
                    video_path,
                    faces=fr,
                    colors=colors,
                    fps=scene.fps,
                    camera=scene.camera,
                    progress=not quiet,
                    ground=m.ground.height if m.ground is not None else False,
                )
            written.append(str(video_path))
            print(f"rendered {traj.frame_count} frames in {time.perf_counter() - t1:.2f} s", flush=True)
        except KeyboardInterrupt:
            status = EXIT_INTERRUPTED
            note = note or "interrupted while rendering; the trajectory is saved"
        except (OSError, ValueError) as exc:  # VideoError (ffmpeg), a camera the frames cannot be fitted to
            status = EXIT_USER if status == EXIT_OK else status
            note = note or f"could not render the video: {exc}; the trajectory is saved"
    for w in written:
        print(f"wrote {w}")
    if status == EXIT_DIVERGED:
        print(f"pliant: error: {note} (partial outputs kept)", file=sys.stderr)
    elif status == EXIT_USER:
        print(f"pliant: error: {note}", file=sys.stderr)
    elif status == EXIT_INTERRUPTED:
        print(f"pliant: {note}", file=sys.stderr)
    return status


def cmd_run(args: argparse.Namespace) -> int:
    """``pliant run SCENE``."""
    cfg = _load(args.scene, args.overrides, force=args.force)
    _apply_overrides(cfg, args)
    hint = ["pliant", "run", args.scene, "--out", args.out] + (["--force"] if args.force else [])
    for item in args.overrides:
        hint += ["--set", item]
    for opt in ("frames", "frame_dt", "substeps", "integrator", "device", "dtype"):
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
