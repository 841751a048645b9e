""":func:`run_scene`: what ``pliant run`` does, as a library function returning a :class:`RunReport`."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ._cameras import CameraScore, compared_frames, render_cameras

if TYPE_CHECKING:
    from ..gaussians import SplatSession
    from ..io import CameraFile, Trajectory
    from ..scene import Scene, SceneConfig
    from ..sim import Simulator

#: Where :func:`run_scene` sends its summary lines.
Log = Callable[[str], None]

#: ``RunReport.status`` values.
STATUSES = ("ok", "diverged", "interrupted", "failed")


class RunError(ValueError):
    """A run that cannot start: an output path, frame rate, camera file, splat section or initial state the
    user must change. Raised before anything is simulated or written; the message is the error line."""


@dataclass
class RunReport:
    """What :func:`run_scene` did.

    Attributes:
        name: the outputs' file stem (``<name>.npz`` ...).
        status: "ok"; "diverged" (the simulation diverged or its implicit system became singular: the frames
            so far are written); "interrupted" (Ctrl-C: partial outputs kept); "failed" (the simulation ran
            but the video could not be rendered).
        message: why the status is not "ok" ("" when it is).
        frames: frames simulated (the trajectory holds ``frames + 1``, frame 0 included).
        frames_requested: frames the scene asked for.
        interrupted_at: the frame a Ctrl-C stopped the simulation at (resumable with ``resume=True``), or
            None.
        wall_simulate: wall time of the simulation [s] (build, splats and twin excluded).
        wall_render: wall time of the video [s], or None when none was rendered.
        written: every file written, in order (trajectory, render mesh, video, camera videos).
        checkpoint: the checkpoint file when it exists after the run, else None.
        warnings: notes about the run (a camera file with another frame count, ...).
        metrics: figures of the run: ``particle_substeps_per_s``, ``drift`` (mean distance [m] to the
            correction twin, ``corrected`` / ``uncorrected``) when a correction ran.
        cameras: one :class:`CameraScore` per camera of the camera file.
        trajectory: the simulated trajectory (positions [T, N, 3], times), or None before a run.
    """

    name: str
    status: str = "ok"
    message: str = ""
    frames: int = 0
    frames_requested: int = 0
    interrupted_at: int | None = None
    wall_simulate: float = 0.0
    wall_render: float | None = None
    written: list[Path] = field(default_factory=list)
    checkpoint: Path | None = None
    warnings: list[str] = field(default_factory=list)
    metrics: dict[str, Any] = field(default_factory=dict)
    cameras: list[CameraScore] = field(default_factory=list)
    trajectory: Trajectory | None = None

    @property
    def ok(self) -> bool:
        """Whether the run ended as asked (status "ok")."""
        return self.status == "ok"


def _outputs(out: Path, name: str, cameras: int) -> tuple[list[Path], list[Path]]:
    """The run's output paths (trajectory, video, checkpoint, render mesh) and the camera videos, each one
    file directly in ``out`` (links followed); ``out`` is created and checked writable."""
    from ..io import OutputPathError, check_file_stem, check_writable_dir, confined

    try:
        check_file_stem(name, "scene name")
        main = [confined(out, f"{name}{suffix}") for suffix in (".npz", ".mp4", ".ckpt.npz", ".render.npz")]
        videos = [confined(out, f"camera_{c}.mp4") for c in range(cameras)]
        check_writable_dir(out)  # a forbidden out fails now, not after the simulation
    except OutputPathError as exc:
        raise RunError(str(exc)) from None
    return main, videos


def _camera_file(cfg: SceneConfig, cameras: str | os.PathLike | None) -> CameraFile | None:
    """The validated camera file (None without one); the scene must have splats to draw."""
    if cameras is None:
        return None
    from ..gaussians import gaussians_section
    from ..io import CameraFileError, load_camera_file

    if gaussians_section(cfg) is None:
        raise RunError(
            f"--cameras: {cfg.source} has no [gaussians] section, so there are no splats to render; add one, "
            'e.g.\n    [gaussians]\n    generate = "mesh"'
        )
    try:
        return load_camera_file(cameras)
    except (CameraFileError, FileNotFoundError) as exc:
        raise RunError(f"--cameras: {exc}") from None


def run_tag(cfg: SceneConfig) -> str:
    """SHA-256 of what a run simulates: the scene but its frame count, device, divergence bound, camera and
    outputs (a resume may ask for more frames, on another device, with other outputs)."""
    import hashlib
    import json

    data = cfg.model_dump(mode="json", exclude={"camera", "output"})
    for k in ("frames", "device", "max_speed"):
        data["scene"].pop(k, None)
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()


def run_scene(
    cfg: SceneConfig,
    out: str | os.PathLike,
    name: str | None = None,
    *,
    device: str | None = None,
    dtype: str | None = None,
    resume: bool = False,
    video: bool = True,
    renderer: str = "auto",
    cameras: str | os.PathLike | None = None,
    progress: bool = False,
    log: Callable[[str], None] | None = None,
) -> RunReport:
    """Build ``cfg``, run its frames, and write ``<out>/<name>.npz`` (+ ``.mp4``, ``.ckpt.npz``,
    ``.render.npz``, ``camera_<c>.mp4``), as ``pliant run`` does.

    Every output path is checked first (one file name inside ``out``, links followed), then the video's
    frame rate and the camera file, then the scene is built, its splats (and correction twin) made and its
    initial state checked: a mistake in any of them is a :class:`RunError` before anything is simulated or
    written. The kernels of a built-in scene's first frames compile on background threads meanwhile
    (:meth:`pliant.scene.Scene.prebuild_kernels`). A divergence or Ctrl-C during the run ends it with the
    frames so far written (``status``); the report says what happened.

    Args:
        cfg: a validated scene (:func:`pliant.scene.load_scene`), with any overrides applied.
        out: the output folder (created).
        name: the outputs' file stem (default: the scene's name).
        device: Warp device; None: the scene's.
        dtype: "float32" or "float64"; None: the scene's.
        resume: continue from ``<out>/<name>.ckpt.npz`` (it must exist).
        video: render ``<name>.mp4`` (when ``[output] video`` is on too).
        renderer: "auto" (splats when the scene has ``[gaussians]``), "mesh" or "splats".
        cameras: a camera file (:mod:`pliant.io._camera_file`): the run's splats are rendered from each of
            its cameras into ``camera_<c>.mp4`` and, when it holds images, scored against them
            (:attr:`RunReport.cameras`); the scene needs a ``[gaussians]`` section.
        progress: progress bars (and the correction twin's timing line).
        log: called with each summary line as the run goes (the header, the timings); None: silent.

    Returns:
        The :class:`RunReport`.

    Raises:
        RunError: a user error found before the run (nothing simulated or written).
        SceneError: the scene cannot be built (naming the field).
        DivergenceError: the correction twin diverged (nothing written).
    """
    from ..scene import build_scene
    from ..sim import DivergenceError
    from ..solvers import SingularSystemError

    say: Log = log if log is not None else (lambda line: None)
    out = Path(out)
    name = cfg.scene.name if name is None else name
    cams = _camera_file(cfg, cameras) if cameras is not None else None
    (traj_path, video_path, ckpt, render_path), camera_videos = _outputs(out, name, cams.count if cams else 0)
    want_video = video and cfg.output.video
    if want_video:
        _check_output_fps(cfg)
    # A value that overflows the model's dtype (origin 1e39 in float32) is reported by the frame-0 check
    # below, not as NumPy's RuntimeWarning.
    with np.errstate(over="ignore", invalid="ignore"):
        scene = build_scene(cfg, device=device, dtype=dtype)
    scene.prebuild_kernels()  # the first frames' kernels compile on both cores while the splats are made
    m = scene.model
    if want_video or cams is not None:
        _check_scene_fps(scene, want_video)
    if resume and not ckpt.exists():
        raise RunError(f"--resume: no checkpoint at {ckpt}; run once without --resume first")
    splats = _splats(cfg, scene, renderer, cams is not None, log if progress else None)
    sim = scene.simulator()
    sim.checkpoint_tag = run_tag(cfg)  # a checkpoint of another scene or other physics is refused
    say(_header(name, scene, sim))
    report = RunReport(name, frames_requested=scene.frames)
    t0 = time.perf_counter()
    if not resume:
        try:
            sim.check_initial_state()  # non-finite → a user error, with nothing written
        except DivergenceError as exc:
            raise RunError(str(exc)) from None
    try:
        traj = sim.run(
            scene.frames,
            progress=progress,
            record_velocity=cfg.output.record_velocity,
            checkpoint=ckpt,
            checkpoint_every=cfg.output.checkpoint_every,
            resume=resume,
            on_frame=splats.on_frame if splats is not None else None,
        )
    except KeyboardInterrupt:
        traj, report.status, report.interrupted_at = sim.trajectory(), "interrupted", sim.frame
        report.message = f"interrupted at frame {sim.frame} of {scene.frames}; partial outputs kept"
    except (DivergenceError, SingularSystemError) as exc:
        # A singular implicit system mid-run (masses lost next to h²K) ends the run as a divergence does:
        # the frames so far are written, the message says what to change.
        traj, report.status, report.message = sim.trajectory(), "diverged", str(exc)
    wall = report.wall_simulate = time.perf_counter() - t0
    report.trajectory, report.frames = traj, max(traj.frame_count - 1, 0)
    steps = report.frames * scene.substeps
    if cfg.output.trajectory:
        _write_trajectory(report, scene, traj, traj_path, render_path)
    report.checkpoint = ckpt if ckpt.exists() else None
    rate = ""
    if wall > 0 and steps:
        report.metrics["particle_substeps_per_s"] = m.particle_count * steps / wall
        rate = f", {report.metrics['particle_substeps_per_s']:.3g} particle-substeps/s"
    say(f"simulated {traj.frame_count - 1} frames in {wall:.2f} s{rate}")
    if splats is not None and splats.twin_x is not None and report.status == "ok":
        report.metrics["drift"] = splats.drift(traj.x)
        say(splats.drift_summary(traj.x, report.metrics["drift"]))
    if want_video and traj.frame_count > 0:
        _video(report, scene, splats, traj, video_path, progress, say)
    if cams is not None and traj.frame_count > 0 and splats is not None:
        _cameras(report, cams, splats, traj, camera_videos, scene.fps, progress, say)
    return report


def _check_output_fps(cfg: SceneConfig) -> None:
    """``[output] fps``, when set, is a frame rate the video writer takes (:class:`RunError` if not)."""
    from ..render import check_fps

    fps = getattr(cfg.output, "fps", None)
    if fps is not None:
        try:
            check_fps(fps)
        except ValueError as exc:
            raise RunError(f"output.fps: {exc}") from None


def _check_scene_fps(scene: Scene, want_video: bool) -> None:
    """The scene's video frame rate (``output.fps``, default 1 / frame_dt) is one the video writer takes
    (:class:`RunError` naming the fix if not); ``want_video``: the run's own video asked for it."""
    from ..render import check_fps

    try:
        check_fps(scene.fps)
    except ValueError as exc:
        fix = "or use --no-video" if want_video else "needed by the --cameras videos"
        raise RunError(f"video frame rate (output.fps, default 1/frame_dt): {exc}; {fix}") from None


def _splats(
    cfg: SceneConfig, scene: Scene, renderer: str, cameras: bool, log: Callable[[str], None] | None
) -> SplatSession | None:
    """The scene's splat session (splats, correction twin, corrector) for ``renderer``; with ``cameras``, one
    that draws no video when the renderer is "mesh" (the camera videos still draw splats)."""
    from ..gaussians import SplatSceneError, SplatSession, splat_session

    try:  # [gaussians]: splats, twin, corrector
        splats = splat_session(cfg, scene, renderer, log=log)
        if cameras and splats is None:  # renderer "mesh": the cameras still draw splats
            splats = SplatSession(cfg, scene, log=log)
            splats.draw = False
    except SplatSceneError as exc:
        raise RunError(str(exc)) from None
    return splats


def _header(name: str, scene: Scene, sim: Simulator) -> str:
    """The run's first summary line: sizes, frames, substeps, frame duration (s), solver, device, dtype."""
    m = scene.model
    info = sim.solver.describe()
    counts = f"{m.particle_count} particles, {m.spring_count} springs" + (
        f", {m.tet_count} tets" if m.tet_count else ""
    )
    solver = f"{info.get('solver', type(sim.solver).__name__)}/{info.get('integrator', '-')}"
    return (
        f"{name}: {counts}; {scene.frames} frames x {scene.substeps} substeps "
        f"(frame_dt {scene.frame_dt:.4g} s), "
        f"{solver} on {m.device} {m.dtype}"
    )


def _write_trajectory(
    report: RunReport, scene: Scene, traj: Trajectory, traj_path: Path, render_path: Path
) -> None:
    """Write ``<name>.npz`` (with the colliders and ground ``pliant export`` draws) and, for a scene with
    embedded render meshes, ``<name>.render.npz`` (what the video draws); both go in ``report.written``."""
    # What `pliant export` draws beside the objects: the drawn colliders (static meshes) and the ground.
    traj.meta.update(scene.trajectory_meta())
    report.written.append(Path(traj.save(traj_path)))
    if scene.embeddings and traj.frame_count > 0:
        # What the video draws (particles, the fine embedded surface, colliders) as <name>.render.npz.
        from ..io import Trajectory

        xf, ff, _ = scene.render_mesh(traj.x, traj.faces, traj.t)
        fine = Trajectory(x=xf, t=traj.t, faces=ff, meta={**traj.meta, "render_mesh": True})
        report.written.append(Path(fine.save(render_path)))


def _video(
    report: RunReport,
    scene: Scene,
    splats: SplatSession | None,
    traj: Trajectory,
    path: Path,
    progress: bool,
    say: Log,
) -> None:
    """Render ``<name>.mp4`` (splats or the mesh renderer) into the report; a failure sets its status."""
    t1 = time.perf_counter()
    m = scene.model
    try:
        from ..render import render_video

        xr, fr, colors = scene.render_mesh(traj.x, traj.faces, traj.t)
        if splats is not None and splats.draw:
            splats.render_video(traj.x, path, scene.fps, progress=progress)
        else:
            render_video(
                xr,
                path,
                faces=fr,
                colors=colors,
                fps=scene.fps,
                camera=scene.camera,
                progress=progress,
                ground=m.ground.height if m.ground is not None else False,
            )
        report.written.append(path)
        report.wall_render = time.perf_counter() - t1
        say(f"rendered {traj.frame_count} frames in {report.wall_render:.2f} s")
    except KeyboardInterrupt:
        report.status = "interrupted"
        report.message = report.message or "interrupted while rendering; the trajectory is saved"
    except (OSError, ValueError) as exc:  # VideoError (ffmpeg), a camera the frames cannot be fitted to
        report.status = "failed" if report.status == "ok" else report.status
        report.message = report.message or f"could not render the video: {exc}; the trajectory is saved"


def _cameras(
    report: RunReport,
    cams: CameraFile,
    splats: SplatSession,
    traj: Trajectory,
    videos: list[Path],
    fps: float,
    progress: bool,
    say: Log,
) -> None:
    """Render the camera file's cameras and score them into the report; a failure sets its status."""
    n, notes = compared_frames(cams, np.asarray(traj.t))
    report.warnings += notes
    for note in notes:
        say(f"note: {note}")
    try:
        report.cameras = render_cameras(splats, traj.x, cams, videos, fps, compare=n, progress=progress)
    except KeyboardInterrupt:
        report.status = "interrupted"
        report.message = report.message or "interrupted while rendering the cameras; the trajectory is saved"
        return
    except (OSError, ValueError) as exc:
        report.status = "failed" if report.status == "ok" else report.status
        report.message = report.message or f"could not render the cameras: {exc}; the trajectory is saved"
        return
    for s in report.cameras:
        report.written.append(s.video)
        say(s.summary())
