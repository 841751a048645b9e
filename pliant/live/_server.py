"""The live view in the browser (viser): the simulation steps in a thread paced to real time, each frame moves
the scene nodes, a drag on an object drags the particle under the cursor, and a panel holds pause, step,
reset, time scale, the material sliders and a record button."""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..render import add_object_nodes, drawn_colliders, load_viser, move_nodes, require_token, viewer_url
from ._session import LiveSession, write_parameter

#: The time scale slider's range (simulated seconds per wall-clock second).
TIME_SCALE = (0.05, 4.0)


@dataclass
class LiveViewer:
    """A running live view: the viser server, its scene nodes, the stepping thread's pacing and rate.

    Attributes:
        server: the ``viser.ViserServer``.
        url: where a browser opens it.
        session: the :class:`LiveSession` it steps and drags.
        nodes: scene node names → what they show (as :func:`pliant.render._viewer.add_object_nodes`).
        paused: True while the simulation waits (pause button, or after a divergence).
        time_scale: simulated seconds per wall-clock second the pacing aims at.
        fps: frames per wall-clock second achieved over the last second (0 while paused).
        status: the line the panel shows: the rate while running, "paused at frame n" while paused, or the
            divergence message.
        note: the panel's last refusal or adjustment (a slider value out of range, substeps raised for a
            stiffer material), "" when there is none.
        token: the secret a client's websocket must carry (``?token=...``), or None when any client may
            connect.
        record_dir: where the record button writes ``live_<n>.npz`` / ``.mp4``.
        recorded: the files the record button has written.
    """

    server: Any
    url: str
    session: LiveSession
    nodes: dict[str, str] = field(default_factory=dict)
    paused: bool = False
    time_scale: float = 1.0
    fps: float = 0.0
    status: str = ""
    note: str = ""
    token: str | None = None
    record_dir: Path = Path(".")
    recorded: list[Path] = field(default_factory=list)
    _handles: list[tuple[Any, Any]] = field(default_factory=list)
    _splats: Any = None
    _marker: Any = None
    _splat_node: Any = None
    _stop: threading.Event = field(default_factory=threading.Event)
    _single: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None
    _times: deque = field(default_factory=lambda: deque(maxlen=240))
    _gui: dict[str, Any] = field(default_factory=dict)
    _halted: str | None = None  # the divergence message while paused by one
    _grab_owner: int | None = None  # the client whose drag holds the grab (None: a script's grab, or none)

    # ------------------------------------------------------------------ the loop
    def show(self, x: np.ndarray) -> None:
        """Move the scene nodes (and the splats) to positions ``x`` [N, 3] and moving colliders to their pose
        at the session's simulated time (that of its latest ``x``)."""
        move_nodes(self._handles, x, self.session.t)
        if self._marker is not None:  # the grab's target: a red ball where the cursor pulls
            target = self.session.target
            if target is not None:
                self._marker.position = tuple(float(c) for c in target)
            self._marker.visible = target is not None
        if self._splats is not None:
            self._splat_node.set_gaussians(*splat_arrays(self._splats, x))

    def run_frame(self) -> bool:
        """Step one frame, show it; on divergence pause and say why. Returns whether a frame was stepped."""
        from ..sim import DivergenceError

        try:
            x = self.session.step(1)
        except DivergenceError as exc:
            self.paused = True
            self._halted = f"paused: {exc} (reset to go on)"
            self._say()
            return False
        self.show(x)
        now = time.perf_counter()
        self._times.append(now)
        while self._times and now - self._times[0] > 1.0:
            self._times.popleft()
        if len(self._times) > 1:
            self.fps = (len(self._times) - 1) / max(self._times[-1] - self._times[0], 1e-9)
        return True

    def _loop(self) -> None:
        frame_dt = self.session.sim.frame_dt
        due = time.perf_counter()
        shown = 0.0
        while not self._stop.is_set():
            if self.paused and not self._single.is_set():
                if self._times:  # the rate of a run that has stopped: gone, so a resume starts afresh
                    self._times.clear()
                    self.fps = 0.0
                    self._say()
                time.sleep(0.02)
                due = time.perf_counter()
                continue
            single = self._single.is_set()
            self._single.clear()
            self.run_frame()
            if single:
                self._say()
            # Frame pacing: each frame is due frame_dt / time_scale after the last; a machine that cannot
            # keep up runs flat out and the panel shows the rate it reaches (no catching up in bursts).
            due += frame_dt / max(self.time_scale, 1e-6)
            now = time.perf_counter()
            if due > now:
                time.sleep(due - now)
            else:
                due = now
            if now - shown > 0.5:
                shown = now
                self._say()

    def _say(self) -> None:
        """Put the rate (running), "paused at frame n" or the divergence message in the panel's box."""
        if self.paused:
            self.status = (
                self._halted or f"paused at frame {self.session.frame} (t = {self.session.sim.time:.3f} s)"
            )
        else:
            frame_dt = self.session.sim.frame_dt
            lat = self.session.latencies[-20:]
            self.status = (
                f"{self.fps:.1f} frames/s = {self.fps * frame_dt:.2f}x real time (aim {self.time_scale:g}x)"
                + (f"; drag latency {1e3 * float(np.median(lat)):.0f} ms" if lat else "")
            )
        if "status" in self._gui:
            self._gui["status"].value = self.status

    def start(self) -> None:
        """Start the stepping thread (``serve_live`` does, unless told not to)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._loop, daemon=True, name="pliant-live")
            self._thread.start()

    def stop(self) -> None:
        """Stop stepping and the server."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
        self.server.stop()

    @property
    def colliders(self) -> dict[str, np.ndarray]:
        """Collider node name → the points [m], [V, 3] float64, it draws now."""
        return drawn_colliders(self._handles)

    # ------------------------------------------------------------------ controls
    def record(self) -> list[Path]:
        """Toggle recording: the first call starts, the second writes ``live_<n>.npz`` and ``.mp4`` into
        :attr:`record_dir` and returns them."""
        if not self.session.recording:
            self.session.start_recording()
            return []
        n = len(list(self.record_dir.glob("live_*.npz")))
        files = self.session.stop_recording(self.record_dir / f"live_{n}.npz")
        self.recorded += files
        return files


def splat_arrays(splats: Any, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """viser's Gaussian splat arrays of the bound splats at model positions ``x``: centres [G, 3],
    covariances Σ = A R S Sᵀ Rᵀ Aᵀ [G, 3, 3], RGB [G, 3] in [0, 1] (the view-independent SH term, as
    pliant's rasteriser computes it) and opacities [G, 1].

    Args:
        splats: the scene's bound splats (:func:`pliant.gaussians._scene.scene_splats`).
        x: model positions [m], [N, 3].
    """
    from ..gaussians import quat_matrices

    g = splats.place(np.asarray(x)).numpy()
    q = g["quats"] / np.linalg.norm(g["quats"], axis=1, keepdims=True)
    M = quat_matrices(q) * np.exp(g["log_scales"])[:, None, :]
    if "transforms" in g:
        M = g["transforms"] @ M
    cov = M @ M.transpose(0, 2, 1)
    rgb = np.clip(0.28209479177387814 * g["sh"][:, 0] + 0.5, 0.0, 1.0)
    opacity = 1.0 / (1.0 + np.exp(-g["opacity_logits"]))
    return (
        g["means"].astype(np.float32),
        cov.astype(np.float32),
        rgb.astype(np.float32),
        opacity.reshape(-1, 1).astype(np.float32),
    )


def _client_id(ev: object) -> int | None:
    """The id of the browser tab an event came from (None for a script's event without one)."""
    cid = getattr(ev, "client_id", None)
    return cid if cid is not None else getattr(getattr(ev, "client", None), "client_id", None)


def _bind_drag(v: LiveViewer, handle: Any, part: Any) -> None:
    """A left-drag on this node grabs the particle under the cursor and drags it in the camera-facing plane
    (viser projects the pointer onto it: ``end_position``); release lets go. The tab that grabbed owns the
    grab: another tab's moves and releases do not touch it (its own drag start takes the grab over), and
    the owner's disconnecting lets go (:func:`_release_on_disconnect`)."""
    s = v.session
    span = (part.start, part.start + part.count)

    async def on_drag(ev: Any) -> None:  # async: viser runs these in order on its event loop
        who = _client_id(ev)
        if ev.phase == "start":
            if ev.instance_index is not None and part.kind == "spheres":
                p = part.start + int(ev.instance_index)
            else:
                cam = np.asarray(ev.client.camera.position, float)
                hit = np.asarray(ev.start_position, float)
                if not np.all(np.isfinite(hit)):
                    return
                p = s.pick(cam, hit - cam, hit=hit, among=span)
            if p is not None and span[0] <= p < span[1] and s._inv_mass[p] > 0 and _finite(ev.end_position):
                s.grab(p, ev.end_position)
                v._grab_owner = who
        elif s.grabbed is None or v._grab_owner != who:
            return  # not this tab's grab
        elif ev.phase == "update":
            if _finite(ev.end_position):
                s.move(ev.end_position)
        else:
            s.release()
            v._grab_owner = None

    handle.on_drag(on_drag)


def _finite(point: object) -> bool:
    """Whether a point from the page is three finite numbers."""
    try:
        return bool(np.all(np.isfinite(np.asarray(point, float).reshape(3))))
    except (TypeError, ValueError):
        return False


def _release_on_disconnect(v: LiveViewer) -> None:
    """A tab that closes (or loses its connection) mid-drag lets go of its grab: the page's drag end never
    comes."""

    @v.server.on_client_disconnect
    def _(client: Any) -> None:
        if v.session.grabbed is not None and v._grab_owner == client.client_id:
            v.session.release()
            v._grab_owner = None


def _refuse(v: LiveViewer, slider: Any, good: float, why: str) -> None:
    """Put a slider back on its last accepted value (every page shows it) and say why in the panel."""
    v.note = why
    if "note" in v._gui:
        v._gui["note"].value = why
    slider.value = good


def _panel(v: LiveViewer) -> None:
    gui = v.server.gui
    s = v.session
    v._gui["status"] = gui.add_text("rate", initial_value="starting", disabled=True)
    v._gui["note"] = gui.add_text("note", initial_value="", disabled=True)
    pause = gui.add_button("pause / run")
    step = gui.add_button("step one frame")
    reset = gui.add_button("reset")
    lo, hi = TIME_SCALE
    scale = gui.add_slider("time scale", min=lo, max=hi, step=0.05, initial_value=v.time_scale)
    v._gui["time scale"] = scale

    @pause.on_click
    def _(_: Any) -> None:
        v.paused = not v.paused
        v._halted = None
        v._say()

    @step.on_click
    def _(_: Any) -> None:
        v.paused = True
        v._single.set()

    @reset.on_click
    def _(_: Any) -> None:
        s.reset()
        v._halted, v._grab_owner = None, None
        v.paused = False
        v.show(s.x)

    @scale.on_update
    def _(_: Any) -> None:
        # The page's slider stays in [lo, hi]; a value typed in its box, or sent by another client, may not.
        value = _number(scale.value)
        if value is None or not lo <= value <= hi:
            _refuse(v, scale, v.time_scale, f"time scale {scale.value!r} refused: not in [{lo}, {hi}]")
            return
        v.time_scale = value

    with gui.add_folder("material"):
        for name, p in s.parameters.items():
            label = f"{name} [1/s]" if name == "damping_rate" else f"{name} x"
            step_ = (p.hi - p.lo) / 200.0
            slider = gui.add_slider(label, min=p.lo, max=p.hi, step=step_, initial_value=p.value, hint=p.doc)

            def update(_: Any, name: str = name, slider: Any = slider) -> None:
                param = s.parameters[name]
                value = _number(slider.value)
                if value is not None and value == param.value:
                    return
                try:
                    if value is None:
                        raise ValueError(f"{name}: {slider.value!r} is not a number")
                    write_parameter(s, name, value)
                except ValueError as exc:
                    _refuse(v, slider, param.value, f"refused: {exc}")
                    return
                v.note = s.note
                v._gui["note"].value = v.note

            slider.on_update(update)
            v._gui[f"param:{name}"] = slider
    rec = gui.add_button("record / save")
    v._gui["recorded"] = gui.add_text("recorded", initial_value="", disabled=True)

    @rec.on_click
    def _(_: Any) -> None:
        files = v.record()
        rec.label = "stop and save" if s.recording else "record / save"
        v._gui["recorded"].value = ", ".join(str(f) for f in files) if files else "recording..."


def _number(value: object) -> float | None:
    """``value`` as a finite float, or None (NaN, infinity, not a number)."""
    try:
        x = float(value)  # type: ignore[arg-type]  # anything the page sent; float() decides
    except (TypeError, ValueError):
        return None
    return x if np.isfinite(x) else None


def serve_live(
    session: LiveSession,
    *,
    host: str = "127.0.0.1",
    port: int = 8080,
    verbose: bool = False,
    start: bool = True,
    record_dir: str | Path = ".",
    splats: bool = True,
    token: str | None = None,
) -> LiveViewer:
    """Serve ``session`` live in the browser at ``http://host:port``.

    Args:
        session: the :class:`LiveSession` to step and drag.
        host: interface to listen on (``0.0.0.0`` to reach it from another machine).
        port: TCP port (viser moves to the next free one when it is taken; see ``LiveViewer.url``).
        verbose: let viser print its banner.
        start: start the stepping thread now (False: the caller steps with ``run_frame``, as tests do).
        record_dir: folder of the record button's ``live_<n>.npz`` / ``.mp4``.
        splats: show the scene's ``[gaussians]`` splats, bound to the simulation, when it has that section.
        token: a secret every client's websocket must carry (``LiveViewer.url`` has it; others are closed
            before they see or touch anything), or None to let any client that reaches the port drive it.

    Returns:
        The running :class:`LiveViewer` (call ``stop()`` to end it).
    """
    viser = load_viser()
    from ..io import Trajectory

    scene = session.scene
    m = session.model
    faces = m.render_faces if m.render_faces.size else None
    tets = m.tet_indices_np if m.tet_indices_np.size else None
    from ._session import scene_trajectory_meta

    meta = {"objects": m.objects, **scene_trajectory_meta(scene)}
    first = Trajectory(x=session.x[None], t=np.zeros(1), faces=faces, tets=tets, meta=meta)
    server = viser.ViserServer(host=host, port=port, verbose=verbose)
    if token:
        require_token(server, token)
    radius = float(np.median(m.particle_radius.numpy())) if m.particle_count else 0.01
    handles, nodes = add_object_nodes(server, first, session.x, spheres=min(max(radius, 0.005), 0.05))
    v = LiveViewer(
        server=server,
        url=viewer_url(host, server.get_port(), token),
        session=session,
        token=token or None,
        nodes=nodes,
        record_dir=Path(record_dir),
        _handles=handles,
    )
    size = float(np.max(np.ptp(session.x, axis=0))) if m.particle_count else 1.0
    v._marker = server.scene.add_icosphere(
        "/pliant/grab_target", radius=max(0.015 * size, 0.004), color=(230, 40, 40), visible=False
    )
    for h, part in handles:
        if part.kind in ("surface", "solid", "spheres"):
            _bind_drag(v, h, part)
    if splats and getattr(scene.config, "gaussians", None) is not None:
        from ..gaussians import scene_splats

        v._splats = scene_splats(scene.config, scene)
        c, cov, rgb, op = splat_arrays(v._splats, session.x)
        v._splat_node = server.scene.add_gaussian_splats(
            "/pliant/splats", centers=c, covariances=cov, rgbs=rgb, opacities=op
        )
        v.nodes["/pliant/splats"] = "splats"
    _panel(v)
    _release_on_disconnect(v)
    if start:
        v.start()
    return v
