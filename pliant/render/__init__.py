"""Headless preview rendering, video/GIF writing, plots and mesh-sequence export.

Everything here works without a GPU or a display. The rasterizer (:class:`Renderer`) runs as
Warp kernels on the ``"cpu"`` device whatever device a simulation uses; positions are copied
to the host. pliant is y-up (gravity along -y), lengths are in metres.

Typical use::

    from pliant.render import render_video, video
    render_video(x, "drop.mp4", faces=faces)   # x: positions [T, N, 3]
    video(traj, "drop.gif")                     # any object with .x, .faces, .t
"""

from .. import _warp  # noqa: F401  (Warp initialised once, quietly, before any kernel)
from ._camera import Camera
from ._export import export_obj, export_obj_sequence, export_ply, export_ply_sequence, export_usd
from ._export_objects import (
    ObjectPart,
    collider_points,
    curve_segments,
    export_usd_objects,
    export_vtu_series,
    export_xdmf,
    trajectory_objects,
)
from ._plots import fit_order, plot_error_vs_dt, plot_phase_portrait, plot_series
from ._renderer import Renderer
from ._video import (
    VideoError,
    VideoWriter,
    check_fps,
    link_beads,
    realtime_indices,
    render_video,
    video,
    write_video,
)
from ._viewer import (
    ColliderPart,
    Viewer,
    ViewerError,
    add_object_nodes,
    drawn_colliders,
    is_loopback,
    load_viser,
    move_nodes,
    require_token,
    serve_viewer,
    viewer_url,
)

__all__ = [
    "link_beads",
    "curve_segments",
    "add_object_nodes",
    "ColliderPart",
    "drawn_colliders",
    "is_loopback",
    "load_viser",
    "move_nodes",
    "require_token",
    "viewer_url",
    "Viewer",
    "ViewerError",
    "serve_viewer",
    "ObjectPart",
    "export_usd_objects",
    "export_vtu_series",
    "export_xdmf",
    "trajectory_objects",
    "collider_points",
    "Camera",
    "Renderer",
    "VideoError",
    "VideoWriter",
    "check_fps",
    "write_video",
    "render_video",
    "video",
    "realtime_indices",
    "export_ply",
    "export_obj",
    "export_ply_sequence",
    "export_obj_sequence",
    "export_usd",
    "plot_series",
    "plot_phase_portrait",
    "plot_error_vs_dt",
    "fit_order",
]
