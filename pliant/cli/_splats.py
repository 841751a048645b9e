"""``pliant run`` with a ``[gaussians]`` section: the video drawn as Gaussian splats, and visual correction
toward a "real" twin (``[gaussians.correction]``: the same scene with other parameters, rendered by a ring
of cameras, the images fed to :class:`pliant.gaussians.VisualCorrector` after every frame)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ._common import CliError

if TYPE_CHECKING:
    from ..gaussians import VisualCorrector
    from ..scene import Scene, SceneConfig
    from ..scene._gaussians import GaussianCorrectionSection
    from ..sim import Simulator

RENDERERS = ("auto", "mesh", "splats")


class SplatRun:
    """The splats of a built scene and, with ``[gaussians.correction]``, the twin and the corrector.

    Everything that can fail on the user's input (PLY, binding, the twin's overrides) fails here, before
    anything is simulated.
    """

    def __init__(self, cfg: SceneConfig, scene: Scene, *, correct: bool = True, quiet: bool = False) -> None:
        from ..gaussians._scene import SplatSceneError, gaussians_section, scene_splats

        self.cfg, self.scene, self.quiet = cfg, scene, quiet
        try:
            self.splats = scene_splats(cfg, scene)
        except SplatSceneError as exc:
            raise CliError(str(exc)) from None
        self.draw = True  # render the video as splats (False: the mesh renderer draws it)
        section = gaussians_section(cfg)
        self.spec = section.correction if correct and section is not None else None
        self.twin_x: np.ndarray | None = None
        self.images: list[list[np.ndarray]] = []
        self.corrector: VisualCorrector | None = None
        if self.spec is not None:
            self._twin(self.spec)

    def _twin(self, spec: GaussianCorrectionSection) -> None:
        """Simulate the twin (the scene file with ``correction.set``), render it, make the corrector."""
        from ..gaussians import VisualCorrector
        from ..gaussians._surface import ring_cameras
        from ..scene import SceneError, build_scene, parse_scene
        from ..sim import DivergenceError

        cfg = self.cfg
        try:
            # Sized as this run's scene was (parameters only: the particle count is compared below).
            twin_cfg = parse_scene(cfg.text, cfg.source, cfg.base_dir, overrides=spec.set, force=True)
        except SceneError as exc:
            raise CliError(f"gaussians.correction.set: the twin scene is invalid:\n{exc}") from None
        for key in ("frames", "frame_dt", "substeps"):  # the twin runs in step with this run
            setattr(twin_cfg.scene, key, getattr(cfg.scene, key))
        m = self.scene.model
        twin = build_scene(twin_cfg, device=m.device, dtype=m.dtype)
        if twin.model.particle_count != m.particle_count:
            raise CliError(
                f"{cfg.source}: gaussians.correction.set: the twin has {twin.model.particle_count} "
                f"particles, this scene {m.particle_count}; change parameters only, not the geometry"
            )
        t0 = time.perf_counter()
        try:
            self.twin_x = twin.simulator().run(self.scene.frames, progress=False).x
        except DivergenceError as exc:  # `pliant` reports it as any divergence: one line, exit 2
            raise DivergenceError(
                exc.frame,
                f"the real twin ([gaussians.correction] set {', '.join(spec.set)}), simulated before "
                f"this run (nothing of it written): {exc.quantity}",
                exc.value,
                exc.advice,
            ) from None
        lo, hi = self.splats.lo, self.splats.hi
        self.cameras = ring_cameras(
            self.twin_x[:, lo:hi], spec.cameras, width=spec.width, height=spec.height, elevation=30.0
        )
        self.images = [[self.splats.image(x, c) for c in self.cameras] for x in self.twin_x]
        if not self.quiet:
            print(
                f"real twin ({', '.join(spec.set)}): simulated and rendered by {spec.cameras} cameras "
                f"at {spec.width}x{spec.height} in {time.perf_counter() - t0:.2f} s",
                flush=True,
            )
        self.corrector = VisualCorrector(
            self.splats.binding,
            self.cameras,
            method=spec.method,
            iterations=spec.iterations,
            max_step=spec.max_step,
            position_gain=spec.position_gain,
            velocity_gain=spec.velocity_gain,
            force_gain=spec.force_gain,
            background=self.splats.background,
        )

    def on_frame(self, sim: Simulator) -> None:
        """After frame ``sim.frame``: correct the simulation toward the twin's images of that time."""
        if self.corrector is not None and sim.frame < len(self.images):
            self.corrector.correct(sim, self.images[sim.frame])

    def drift_summary(self, x: np.ndarray) -> str:
        """Mean particle distance [m] to the twin of the run ``x`` [T, N, 3], and of an uncorrected run."""
        if self.twin_x is None:
            return ""
        n = min(len(x), len(self.twin_x))
        corrected = float(np.linalg.norm(x[:n] - self.twin_x[:n], axis=2).mean())
        line = f"visual correction: mean drift from the real twin {corrected:.4g} m"
        if self.spec is not None and self.spec.report_uncorrected:
            plain = self.scene.simulator().run(n - 1, progress=False).x
            d = float(np.linalg.norm(plain - self.twin_x[:n], axis=2).mean())
            line += f", uncorrected {d:.4g} m ({100 * (1 - corrected / max(d, 1e-300)):.0f}% less)"
        return line

    def render_video(self, x: np.ndarray, path: Path, fps: float, progress: bool) -> None:
        """Draw the trajectory ``x`` [T, N, 3] as splats with the scene's camera into ``path``."""
        from ..gaussians import Camera
        from ..render import Camera as ViewCamera
        from ..render import write_video

        view = self.scene.camera
        cc = self.cfg.camera
        if view is None:
            view = ViewCamera.fit(x[:, self.splats.lo : self.splats.hi], width=cc.width, height=cc.height)
        cam = Camera.look_at(
            view.eye, view.target, up=view.up, fov_y=view.fov_y, width=view.width, height=view.height
        )
        frames = (self.splats.image(xf, cam) for xf in x)
        if progress:
            from tqdm.auto import tqdm

            frames = tqdm(frames, total=len(x), unit="frame", desc="rendering splats", leave=False)
        write_video(frames, path, fps=fps)


def splat_run(cfg: SceneConfig, scene: Scene, renderer: str, *, quiet: bool) -> SplatRun | None:
    """The :class:`SplatRun` of ``pliant run`` (None when the scene has no ``[gaussians]`` section or the
    renderer is ``"mesh"``; with ``"mesh"`` no correction runs either)."""
    if renderer not in RENDERERS:
        raise CliError(f"--renderer must be one of {', '.join(RENDERERS)}, got {renderer!r}")
    spec = getattr(cfg, "gaussians", None)
    if spec is None:
        if renderer == "splats":
            raise CliError(
                f"--renderer splats: {cfg.source} has no [gaussians] section; add one, e.g.\n"
                '    [gaussians]\n    generate = "mesh"'
            )
        return None
    if renderer == "mesh" and spec.correction is None:
        return None
    run = SplatRun(cfg, scene, correct=True, quiet=quiet)
    run.draw = renderer != "mesh"
    return run
