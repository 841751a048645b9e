"""A splat session: the ``[gaussians]`` splats of a built scene for one run, drawn as its video and, with
``[gaussians.correction]``, a "real" twin (the same scene with other parameters, rendered by a ring of
cameras) whose images a :class:`~pliant.gaussians.VisualCorrector` pulls the run toward after every frame
(:meth:`SplatSession.on_frame`, the simulator's ``on_frame`` hook). :func:`pliant.runner.run_scene` makes one
for ``pliant run``."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ._camera import Camera
from ._correct import VisualCorrector
from ._render import RenderOutput
from ._scene import SplatSceneError, gaussians_section, scene_splats
from ._surface import ring_cameras

if TYPE_CHECKING:
    from ..scene import GaussianCorrectionSection, Scene, SceneConfig
    from ..sim import Simulator

#: How a run's video is drawn: "auto" (splats when the scene has a [gaussians] section), "mesh", "splats".
RENDERERS = ("auto", "mesh", "splats")


class SplatSession:
    """The splats of a built scene and, with ``[gaussians.correction]``, the twin and the corrector.

    Everything that can fail on the user's input (PLY, binding, the twin's overrides) fails here, before
    anything is simulated.

    Args:
        cfg: the scene's validated config (its ``[gaussians]`` section).
        scene: the built scene (``build_scene(cfg)``).
        correct: simulate the twin and correct toward it when the scene has ``[gaussians.correction]``.
        log: called with each progress line (the twin's timing); None: silent.

    Raises:
        SplatSceneError: the section cannot be built, or the twin is invalid or has another particle count;
            the message names the scene file and the field.
        DivergenceError: the twin diverged (nothing written).
    """

    def __init__(
        self,
        cfg: SceneConfig,
        scene: Scene,
        *,
        correct: bool = True,
        log: Callable[[str], None] | None = None,
    ) -> None:
        self.cfg, self.scene, self.log = cfg, scene, log
        self.splats = scene_splats(cfg, scene)
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
        from ..scene import SceneError, build_scene, parse_scene
        from ..sim import DivergenceError

        cfg = self.cfg
        try:
            # Sized as this run's scene was (parameters only: the particle count is compared below).
            twin_cfg = parse_scene(cfg.text, cfg.source, cfg.base_dir, overrides=spec.set, force=True)
        except SceneError as exc:
            raise SplatSceneError(f"gaussians.correction.set: the twin scene is invalid:\n{exc}") from None
        for key in ("frames", "frame_dt", "substeps"):  # the twin runs in step with this run
            setattr(twin_cfg.scene, key, getattr(cfg.scene, key))
        m = self.scene.model
        twin = build_scene(twin_cfg, device=m.device, dtype=m.dtype)
        if twin.model.particle_count != m.particle_count:
            raise SplatSceneError(
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
        if self.log is not None:
            self.log(
                f"real twin ({', '.join(spec.set)}): simulated and rendered by {spec.cameras} cameras "
                f"at {spec.width}x{spec.height} in {time.perf_counter() - t0:.2f} s"
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
        """The simulator's ``on_frame`` hook: after frame ``sim.frame``, correct the simulation toward the
        twin's images of that time (nothing without a correction)."""
        if self.corrector is not None and sim.frame < len(self.images):
            self.corrector.correct(sim, self.images[sim.frame])

    def drift(self, x: np.ndarray) -> dict[str, float]:
        """Mean particle distance [m] of the run ``x`` [T, N, 3] to the twin (``corrected``) and, with
        ``report_uncorrected``, of a run of the scene without correction (``uncorrected``); {} without a
        twin."""
        if self.twin_x is None:
            return {}
        n = min(len(x), len(self.twin_x))
        out = {"corrected": float(np.linalg.norm(x[:n] - self.twin_x[:n], axis=2).mean())}
        if self.spec is not None and self.spec.report_uncorrected:
            plain = self.scene.simulator().run(n - 1, progress=False).x
            out["uncorrected"] = float(np.linalg.norm(plain - self.twin_x[:n], axis=2).mean())
        return out

    def drift_summary(self, x: np.ndarray, drift: dict[str, float] | None = None) -> str:
        """One line of :meth:`drift` (computed here unless given); "" without a twin."""
        d = self.drift(x) if drift is None else drift
        if not d:
            return ""
        corrected = d["corrected"]
        line = f"visual correction: mean drift from the real twin {corrected:.4g} m"
        if "uncorrected" in d:
            u = d["uncorrected"]
            line += f", uncorrected {u:.4g} m ({100 * (1 - corrected / max(u, 1e-300)):.0f}% less)"
        return line

    def render(self, x: np.ndarray, camera: Camera) -> RenderOutput:
        """Colour, alpha and depth of the splats at model positions ``x`` ([N, 3], metres) seen by
        ``camera``."""
        return self.splats.render(x, camera)

    def render_video(self, x: np.ndarray, path: Path, fps: float, progress: bool) -> None:
        """Draw the trajectory ``x`` [T, N, 3] as splats with the scene's camera into ``path`` (``fps``
        frames per second; ``progress``: a progress bar)."""
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


def splat_session(
    cfg: SceneConfig, scene: Scene, renderer: str = "auto", *, log: Callable[[str], None] | None = None
) -> SplatSession | None:
    """The :class:`SplatSession` of a run (None when the scene has no ``[gaussians]`` section, or the
    renderer is ``"mesh"`` and there is no correction to run).

    Args:
        cfg: the scene's validated config.
        scene: the built scene.
        renderer: one of :data:`RENDERERS`; ``"mesh"`` draws the video with the mesh renderer (a correction
            still runs), ``"splats"`` requires a ``[gaussians]`` section.
        log: progress lines (see :class:`SplatSession`); None: silent.

    Raises:
        SplatSceneError: an unknown renderer, ``"splats"`` without a section, or a section that cannot be
            built.
    """
    if renderer not in RENDERERS:
        raise SplatSceneError(f"--renderer must be one of {', '.join(RENDERERS)}, got {renderer!r}")
    spec = gaussians_section(cfg)
    if spec is None:
        if renderer == "splats":
            raise SplatSceneError(
                f"--renderer splats: {cfg.source} has no [gaussians] section; add one, e.g.\n"
                '    [gaussians]\n    generate = "mesh"'
            )
        return None
    if renderer == "mesh" and spec.correction is None:
        return None
    run = SplatSession(cfg, scene, correct=True, log=log)
    run.draw = renderer != "mesh"
    return run
