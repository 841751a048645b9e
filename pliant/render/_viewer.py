"""An interactive viewer in the browser for a recorded trajectory (``pliant view``), on viser.

viser (``pip install 'pliant[viewer]'``) serves a three.js scene over a websocket; this module puts each
object of the trajectory in it — cloth and shells as triangle meshes, solids as their boundary surface,
ropes as polylines, loose particles as points — with the colliders and the ground ``pliant run`` stored,
and a timeline (frame slider, play, speed). Frames are sent on demand, so memory stays at one trajectory.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ._export_objects import ObjectPart, _prim_names, collider_points, trajectory_objects

if TYPE_CHECKING:
    from ..io import Trajectory

#: Object colours (RGB 0-255), one per object in turn.
PALETTE = [(90, 160, 230), (230, 130, 70), (110, 190, 110), (200, 90, 160), (220, 200, 80), (120, 120, 220)]


@dataclass
class ColliderPart(ObjectPart):
    """A drawn collider's scene node (kind ``"collider"``, ``name`` its node): ``collider`` is its
    ``meta["colliders"]`` entry, ``points`` [m], [V, 3] float64, where the node draws it now (the node holds
    them as float32); :func:`move_nodes` poses a moving one at the time of the frame shown."""

    collider: dict[str, Any] = field(default_factory=dict)
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


def drawn_colliders(handles: list[tuple[Any, ObjectPart]]) -> dict[str, np.ndarray]:
    """Node name → the points [m], [V, 3] float64, each collider node of ``handles`` draws now."""
    return {p.name: p.points for _, p in handles if isinstance(p, ColliderPart)}


class ViewerError(ImportError):
    """viser is missing (install the ``viewer`` extra)."""


def load_viser() -> Any:
    """The ``viser`` module, imported on first use; :class:`ViewerError` with the install line when the
    ``viewer`` extra is missing (callers check before building a scene)."""
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
        colliders: collider node name → the points [m], [V, 3] float64 it draws now (a moving collider's
            pose at the frame's time, :func:`pliant.render.collider_points`).
    """

    server: Any
    url: str
    traj: Trajectory
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
        move_nodes(self._handles, np.asarray(self.traj.x[k], np.float32), float(self.traj.t[k]))
        self.frame = k
        if self._slider is not None and int(self._slider.value) != k:
            self._slider.value = k

    @property
    def colliders(self) -> dict[str, np.ndarray]:
        """Collider node name → the points [m], [V, 3] float64, it draws now."""
        return drawn_colliders(self._handles)

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


def move_nodes(handles: list[tuple[Any, ObjectPart]], x: np.ndarray, t: float | None = None) -> None:
    """Put every object's scene node(s) at positions ``x`` [N, 3] (float32) of the whole model and, given
    ``t``, every moving collider's where it is then.

    Args:
        handles: (scene node handle, part) pairs of :func:`add_object_nodes`.
        x: the positions [m], [N, 3].
        t: the time [s] of ``x`` since the start (a trajectory's ``t``, a live simulation's time): moving
            colliders are posed at it (:func:`pliant.render.collider_points`); None: they stay put.
    """
    for handle, part in handles:
        if isinstance(part, ColliderPart):
            if t is not None and "velocity" in part.collider:  # a static one never changes
                part.points = collider_points(part.collider, [t])[0]
                handle.vertices = part.points.astype(np.float32)
            continue
        xs = x[part.start : part.start + part.count]
        if part.kind in ("surface", "solid"):
            handle.vertices = xs
        elif part.kind == "curve":
            handle.points = np.stack([xs[:-1], xs[1:]], axis=1)
        elif part.kind == "spheres":  # the pickable particles of a live view (one sphere instance each)
            handle.batched_positions = xs
        else:
            handle.points = xs


def add_object_nodes(
    server: Any, traj: Trajectory, x0: np.ndarray, *, spheres: float = 0.0
) -> tuple[list[tuple[Any, ObjectPart]], dict[str, str]]:
    """One scene node per object of ``traj`` at positions ``x0`` [N, 3], plus its colliders and ground.

    Cloth and shells are triangle meshes, solids their boundary surface, ropes polylines, loose particles
    points. ``spheres`` > 0 [m] also draws each rope and point particle as a sphere of that radius (a
    batched mesh: the browser can click and drag those, not lines or points; the node's part has kind
    ``"spheres"``).

    Colliders are drawn where they were added (t = 0); :func:`move_nodes` with a time poses the moving ones.

    Returns:
        (scene node handle, part) pairs in the order :func:`move_nodes` moves them (the colliders last, each
        a :class:`ColliderPart`), and node name → what it shows (``"mesh"``, ``"curve"``, ``"points"``,
        ``"spheres"``, ``"collider"``, ``"ground"``).
    """
    from dataclasses import replace

    parts = trajectory_objects(traj)
    handles: list[tuple[Any, ObjectPart]] = []
    nodes: dict[str, str] = {}
    x0 = np.asarray(x0, np.float32)
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
            nodes[node] = "mesh"
        elif part.kind == "curve":
            h = server.scene.add_line_segments(
                node, np.stack([xs[:-1], xs[1:]], axis=1), colour, thickness=0.008
            )
            nodes[node] = "curve"
        else:
            h = server.scene.add_point_cloud(node, xs, colour, point_size=0.01, point_shape="circle")
            nodes[node] = "points"
        handles.append((h, part))
        if spheres > 0 and part.kind in ("curve", "points"):
            import trimesh

            ball = trimesh.creation.icosphere(subdivisions=1, radius=spheres)
            n = part.count
            hs = server.scene.add_batched_meshes_simple(
                f"{node}_particles",
                np.asarray(ball.vertices, np.float32),
                np.asarray(ball.faces, np.int32),
                batched_wxyzs=np.tile(np.array([1.0, 0.0, 0.0, 0.0], np.float32), (n, 1)),
                batched_positions=xs,
                batched_colors=colour,
            )
            nodes[f"{node}_particles"] = "spheres"
            handles.append((hs, replace(part, kind="spheres")))
    for i, mesh in enumerate(traj.meta.get("colliders") or []):
        node = f"/pliant/colliders/collider{i}"
        pts = np.asarray(mesh["points"], np.float64).reshape(-1, 3)
        tris = np.asarray(mesh["faces"], np.int32).reshape(-1, 3)
        h = server.scene.add_mesh_simple(
            node, pts.astype(np.float32), tris, color=(160, 160, 160), side="double"
        )
        part = ColliderPart(node, "collider", 0, 0, tris, np.zeros((0, 4), np.int32), "collider", mesh, pts)
        handles.append((h, part))
        nodes[node] = "collider"
    finite = np.asarray(traj.x).reshape(-1, 3)
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
        nodes["/pliant/ground"] = "ground"
    # pliant is y-up; start the camera in front of and above the objects, looking at them, as close as lets
    # every position the objects take fill the view. One frame (a live view's start) says nothing of where
    # they go: they fall, so the box reaches down by its own size, to the ground at most.
    server.scene.set_up_direction("+y")
    if traj.x.shape[0] == 1:
        lo = lo.copy()
        drop = lo[1] - max(float(np.max(hi - lo)), 1e-3)
        lo[1] = min(max(drop, float(ground)), lo[1]) if ground is not None else drop
    eye, look = fit_camera(lo, hi, fov=float(server.initial_camera.fov))
    server.initial_camera.position = tuple(float(c) for c in eye)
    server.initial_camera.look_at = tuple(float(c) for c in look)
    return handles, nodes


#: The direction from what the camera looks at toward it: in front (+z) and above (+y), about 24° up.
CAMERA_DIRECTION = (0.0, 0.8, 1.8)


def fit_camera(
    lo: np.ndarray, hi: np.ndarray, *, fov: float, aspect: float = 4.0 / 3.0, margin: float = 1.1
) -> tuple[np.ndarray, np.ndarray]:
    """The camera (eye, look-at point) [m] that looks at the box [lo, hi] along :data:`CAMERA_DIRECTION` from
    the nearest distance at which all of the box fits the view (y up), with ``margin`` to spare.

    Args:
        lo: the box's low corner [m], (3,).
        hi: its high corner [m], (3,).
        fov: the vertical field of view [rad].
        aspect: the view's width / height (the page's canvas is wider than tall; 4:3 is the narrow end).
        margin: the distance's factor over the tightest fit (1.1: the box spans about 90 % of the view).
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    centre = 0.5 * (lo + hi)
    half = np.maximum(0.5 * (hi - lo), 5e-4)  # a point or a flat object: still a distance to stand at
    w = np.asarray(CAMERA_DIRECTION, float)
    w /= np.linalg.norm(w)
    u = np.cross([0.0, 1.0, 0.0], w)
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    corners = centre + half * np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)])
    r = corners - centre
    ty = np.tan(0.5 * fov)
    # A corner r is in view at distance d when |r·u| ≤ (d - r·w) tan(fov_x / 2), and the same for v.
    need = np.maximum(np.abs(r @ u) / (ty * aspect), np.abs(r @ v) / ty) + r @ w
    d = margin * float(np.max(need))
    return centre + d * w, centre


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an interface a server binds) is reachable from this machine alone."""
    import ipaddress

    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:  # a host name: it may resolve to any interface
        return False


def viewer_url(host: str, port: int, token: str | None) -> str:
    """The address a browser opens: ``http://host:port``, where a wildcard host (``0.0.0.0``, ``::``) is
    replaced by this machine's name; with a token, the page is told to open its websocket with the token
    (viser's page drops the query of its own address, but connects to the ``websocket`` parameter as is)."""
    import socket

    shown = socket.gethostname() if host in ("0.0.0.0", "::", "") else host
    if ":" in shown:
        shown = f"[{shown}]"
    base = f"http://{shown}:{port}"
    return base if not token else f"{base}/?websocket=ws://{shown}:{port}/?token={token}"


def require_token(server: Any, token: str) -> None:
    """Refuse every websocket of ``server`` (a ``viser.ViserServer``) that does not carry ``?token=token``,
    as Jupyter guards its server: the refused client is closed (code 1008) before it receives the scene
    or can send anything. Any client that connected before this call is closed too (it may reconnect
    with the token).

    Args:
        server: the running viser server.
        token: the secret (non-empty).
    """
    import asyncio
    import hmac
    from urllib.parse import parse_qs, urlsplit

    if not token:
        raise ValueError("require_token: the token is empty; pass a secret (secrets.token_urlsafe())")
    ws = server._websock_server
    loop = ws._background_event_loop

    async def check(conn: Any) -> None:
        raw = ws._live_connections.get(conn.client_id)
        if raw is None:
            return
        given = parse_qs(urlsplit(raw.request.path).query).get("token", [""])[0]
        if not hmac.compare_digest(given.encode(), token.encode()):
            await raw.close(1008, "pliant view: no or wrong token; open the URL pliant view printed")

    async def install() -> None:
        # On the event loop: no connection is being set up while the check goes in first, and those that
        # came before it are closed.
        ws._client_connect_cb.insert(0, check)
        for raw in list(ws._live_connections.values()):
            await raw.close(1008, "pliant view: reconnect with the token")

    asyncio.run_coroutine_threadsafe(install(), loop).result(timeout=30)


def serve_viewer(
    traj: Trajectory,
    *,
    host: str = "127.0.0.1",
    port: int = 8080,
    verbose: bool = False,
    token: str | None = None,
) -> Viewer:
    """Serve ``traj`` (a :class:`pliant.io.Trajectory`) in the browser at ``http://host:port``.

    Args:
        traj: the recorded trajectory (``pliant run`` writes one with its objects, colliders and ground).
        host: interface to listen on (``0.0.0.0`` to reach it from another machine).
        port: TCP port (viser moves to the next free one when it is taken; see ``Viewer.url``).
        verbose: let viser print its banner.
        token: a secret every client's websocket must carry (:func:`require_token`; ``Viewer.url`` has it),
            or None to let any client that reaches the port connect.

    Returns:
        The running :class:`Viewer` (call ``stop()`` to end it).
    """
    viser = load_viser()
    if traj.frame_count < 1 or not np.all(np.isfinite(traj.x)):
        raise ValueError("the trajectory has no frames or non-finite positions; nothing to show")
    server = viser.ViserServer(host=host, port=port, verbose=verbose)
    if token:
        require_token(server, token)
    handles, nodes = add_object_nodes(server, traj, traj.x[0])
    v = Viewer(
        server=server,
        url=viewer_url(host, server.get_port(), token),
        traj=traj,
        parts=[p for _, p in handles if not isinstance(p, ColliderPart)],
        nodes=nodes,
        _handles=handles,
    )
    v.show(0)  # a moving collider at its pose at the first frame's time (a recording may start late)
    t = traj.frame_count
    v._slider = server.gui.add_slider("frame", min=0, max=max(t - 1, 1), step=1, initial_value=0)
    v._slider.on_update(lambda _: v.show(int(v._slider.value)))
    v._playing = server.gui.add_checkbox("play", False)
    v._speed = server.gui.add_slider("speed", min=0.1, max=4.0, step=0.1, initial_value=1.0)
    frame_dt = float(traj.frame_dt or (traj.t[1] - traj.t[0] if t > 1 else 1 / 30))
    v.play(min(1.0 / max(frame_dt, 1e-6), 60.0))
    return v


def chromium() -> str | None:
    """The headless browser that screenshots a viewer page (``chromium`` or ``chromium-browser``), or None."""
    import shutil

    return shutil.which("chromium") or shutil.which("chromium-browser")


def screenshot_page(
    url: str, path: str | os.PathLike, *, width: int = 800, height: int = 600, budget_ms: int = 8000
) -> Path:
    """Screenshot the viewer page at ``url`` into ``path`` (PNG) with headless Chromium, WebGL in software
    (SwiftShader: no GPU needed).

    Args:
        url: the page (``Viewer.url`` or ``LiveViewer.url``).
        path: the PNG to write.
        width: window width [px].
        height: window height [px].
        budget_ms: Chromium's virtual time budget [ms]: how long the page may load and draw the scene it
            receives over the viewer's websocket.

    Raises:
        FileNotFoundError: no chromium on this machine (``apt-get install chromium``).
    """
    import subprocess
    import tempfile

    exe = chromium()
    if exe is None:
        raise FileNotFoundError("no chromium to screenshot the viewer: apt-get install chromium")
    path = Path(path)
    with tempfile.TemporaryDirectory() as profile:
        subprocess.run(
            [
                exe,
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-quic",
                "--no-first-run",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                f"--user-data-dir={profile}",
                "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader",  # WebGL in software: no GPU here
                f"--window-size={width},{height}",
                f"--virtual-time-budget={budget_ms}",
                f"--screenshot={path}",
                url,
            ],
            capture_output=True,
            timeout=120 + budget_ms / 1000,
        )
    return path
