"""An interactive viewer in the browser for a recorded trajectory (``pliant view``), on viser.

viser (``pip install 'pliant[viewer]'``) serves a three.js scene over a websocket; this module puts each
object of the trajectory in it — cloth and shells as triangle meshes, solids as their boundary surface,
ropes as polylines, loose particles as points — with the colliders and the ground ``pliant run`` stored,
and a timeline (frame slider, play, speed). Frames are sent on demand, so memory stays at one trajectory.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ._export_objects import ObjectPart, _prim_names, trajectory_objects

#: Object colours (RGB 0-255), one per object in turn.
PALETTE = [(90, 160, 230), (230, 130, 70), (110, 190, 110), (200, 90, 160), (220, 200, 80), (120, 120, 220)]


class ViewerError(ImportError):
    """viser is missing (install the ``viewer`` extra)."""


def _viser() -> Any:
    try:
        import viser
    except ImportError:
        from .._extras import pip_install

        raise ViewerError(
            f"pliant view needs viser, an optional extra: {pip_install('viewer')} (or pip install viser)"
        ) from None
    return viser


@dataclass
class Viewer:
    """A running viewer: the viser server, the scene nodes it holds and the timeline's current frame.

    Attributes:
        server: the ``viser.ViserServer``.
        url: where a browser opens it.
        nodes: scene node names → what they show (``"mesh"``, ``"curve"``, ``"points"``, ``"collider"``,
            ``"ground"``).
        frame: the frame shown.
    """

    server: Any
    url: str
    traj: Any
    parts: list[ObjectPart]
    nodes: dict[str, str] = field(default_factory=dict)
    frame: int = 0
    _handles: list[tuple[Any, ObjectPart]] = field(default_factory=list)
    _stop: threading.Event = field(default_factory=threading.Event)
    _slider: Any = None
    _playing: Any = None
    _speed: Any = None

    def show(self, frame: int) -> None:
        """Move every object to ``frame`` (negative counts from the end)."""
        t = self.traj.frame_count
        k = int(frame) % t
        x = np.asarray(self.traj.x[k], np.float32)
        for handle, part in self._handles:
            xs = x[part.start : part.start + part.count]
            if part.kind in ("surface", "solid"):
                handle.vertices = xs
            elif part.kind == "curve":
                handle.points = np.stack([xs[:-1], xs[1:]], axis=1)
            else:
                handle.points = xs
        self.frame = k
        if self._slider is not None and int(self._slider.value) != k:
            self._slider.value = k

    def play(self, fps: float) -> None:
        """Advance the timeline at ``fps`` frames per second while the "play" box is ticked (a thread)."""

        def loop() -> None:
            while not self._stop.is_set():
                if self._playing.value:
                    self.show(self.frame + 1)
                time.sleep(1.0 / max(fps * float(self._speed.value), 1e-3))

        threading.Thread(target=loop, daemon=True).start()

    def stop(self) -> None:
        """Stop playback and the server."""
        self._stop.set()
        self.server.stop()


def serve_viewer(traj: Any, *, host: str = "127.0.0.1", port: int = 8080, verbose: bool = False) -> Viewer:
    """Serve ``traj`` (a :class:`pliant.io.Trajectory`) in the browser at ``http://host:port``.

    Args:
        traj: the recorded trajectory (``pliant run`` writes one with its objects, colliders and ground).
        host: interface to listen on (``0.0.0.0`` to reach it from another machine).
        port: TCP port (viser moves to the next free one when it is taken; see ``Viewer.url``).
        verbose: let viser print its banner.

    Returns:
        The running :class:`Viewer` (call ``stop()`` to end it).
    """
    viser = _viser()
    if traj.frame_count < 1 or not np.all(np.isfinite(traj.x)):
        raise ValueError("the trajectory has no frames or non-finite positions; nothing to show")
    server = viser.ViserServer(host=host, port=port, verbose=verbose)
    parts = trajectory_objects(traj)
    v = Viewer(server=server, url=f"http://{host}:{server.get_port()}", traj=traj, parts=parts)
    x0 = np.asarray(traj.x[0], np.float32)
    for i, (part, name) in enumerate(zip(parts, _prim_names(parts), strict=True)):
        colour = PALETTE[i % len(PALETTE)]
        node = f"/pliant/{name}"
        xs = x0[part.start : part.start + part.count]
        if part.kind in ("surface", "solid"):
            from ..geometry import surface_from_tets

            faces = part.faces if part.kind == "surface" else surface_from_tets(part.tets)
            h = server.scene.add_mesh_simple(
                node, xs, np.asarray(faces, np.int32), color=colour, side="double"
            )
            v.nodes[node] = "mesh"
        elif part.kind == "curve":
            h = server.scene.add_line_segments(
                node, np.stack([xs[:-1], xs[1:]], axis=1), colour, thickness=0.008
            )
            v.nodes[node] = "curve"
        else:
            h = server.scene.add_point_cloud(node, xs, colour, point_size=0.01, point_shape="circle")
            v.nodes[node] = "points"
        v._handles.append((h, part))
    for i, mesh in enumerate(traj.meta.get("colliders") or []):
        node = f"/pliant/colliders/collider{i}"
        pts = np.asarray(mesh["points"], np.float32).reshape(-1, 3)
        tris = np.asarray(mesh["faces"], np.int32).reshape(-1, 3)
        server.scene.add_mesh_simple(node, pts, tris, color=(160, 160, 160), side="double")
        v.nodes[node] = "collider"
    finite = traj.x.reshape(-1, 3)
    lo, hi = finite.min(axis=0), finite.max(axis=0)
    centre, size = 0.5 * (lo + hi), float(max(np.max(hi - lo), 0.5))
    ground = traj.meta.get("ground")
    if ground is not None:
        server.scene.add_grid(
            "/pliant/ground",
            width=4 * size,
            height=4 * size,
            plane="xz",
            cell_size=size / 8,
            section_size=size / 2,
            plane_color=(235, 235, 235),
            plane_opacity=1.0,
            position=(float(centre[0]), float(ground), float(centre[2])),
        )
        v.nodes["/pliant/ground"] = "ground"
    # pliant is y-up; start the camera in front of and above the objects, looking at them.
    server.scene.set_up_direction("+y")
    server.initial_camera.position = tuple(float(c) for c in centre + np.array([0.0, 0.8, 1.8]) * size)
    server.initial_camera.look_at = tuple(float(c) for c in centre)
    t = traj.frame_count
    v._slider = server.gui.add_slider("frame", min=0, max=max(t - 1, 1), step=1, initial_value=0)
    v._slider.on_update(lambda _: v.show(int(v._slider.value)))
    v._playing = server.gui.add_checkbox("play", False)
    v._speed = server.gui.add_slider("speed", min=0.1, max=4.0, step=0.1, initial_value=1.0)
    dt = float(traj.meta.get("dt") or (traj.t[1] - traj.t[0] if t > 1 else 1 / 30))
    v.play(min(1.0 / max(dt, 1e-6), 60.0))
    return v
