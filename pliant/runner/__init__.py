"""Running a scene as ``pliant run`` does, as a library function: :func:`run_scene` builds the scene, runs
its frames (resuming from a checkpoint), checkpoints, writes the trajectory, the video and the render mesh,
draws splats, runs the splat corrector, renders extra cameras from a camera file, and returns a
:class:`RunReport`.

It sits above ``scene`` and ``gaussians`` (it uses both), below ``cli`` (whose ``pliant run`` parses, calls
it and prints); docs/design.md, "Layers", says why it is not in ``sim``.

Example::

    import pliant as pl
    report = pl.run_scene(pl.scene.load_scene("rope"), "out", video=False)
    print(report.written, report.wall_simulate)
"""

from ._cameras import CameraScore, render_cameras
from ._run import RunError, RunReport, run_scene

__all__ = ["CameraScore", "RunError", "RunReport", "render_cameras", "run_scene"]
