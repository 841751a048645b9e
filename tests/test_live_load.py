"""The live server under load and misuse (issue 41): bad slider values are refused, a tab that drops
mid-drag lets go, a token keeps other clients out, the rate box says when it is paused, and eight tabs
cost the simulation less than a fifth of its frame rate (slow). Clients are scripted tabs
(:mod:`pliant.live._probe`) on loopback; every loop ends by itself."""

from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

import pliant as pl

pytest.importorskip("viser", reason="the viewer extra: pip install 'pliant[viewer]'")

from pliant.live import LiveSession, serve_live, write_parameter  # noqa: E402


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cloth():
    """The demo cloth at 10 × 10 cells, pinned at two corners (force solver, symplectic Euler)."""
    scene = pl.scene.load_scene("cloth", ["objects[0].nx=10", "objects[0].ny=10", "scene.substeps=40"])
    return pl.scene.build_scene(scene, device="cpu")


def _wait(cond, seconds: float = 20.0) -> bool:
    t0 = time.perf_counter()
    while not cond() and time.perf_counter() - t0 < seconds:
        time.sleep(0.02)
    return cond()


def test_slider_values_out_of_range_or_not_finite_are_refused():
    """A page's box (or a client that is no page) can send any number: the server refuses one outside the
    parameter's [lo, hi], NaN, infinity, and puts every page's slider back on the last accepted value."""
    from pliant.live._probe import gui_update, probe

    session = LiveSession(_cloth())
    v = serve_live(session, port=_free_port(), start=False)
    try:
        k0 = session.model.spring_stiffness.numpy().copy()
        stiff, damp, scale = v._gui["param:stiffness"], v._gui["param:damping_rate"], v._gui["time scale"]
        p = session.parameters["stiffness"]
        assert (stiff.min, stiff.max) == (p.lo, p.hi)  # the page's slider cannot leave the range
        send = [
            (0.2, gui_update(stiff, 1.5)),
            (0.4, gui_update(stiff, p.hi * 1.01)),
            (0.6, gui_update(stiff, float("nan"))),
            (0.8, gui_update(damp, float("inf"))),
            (1.0, gui_update(damp, -1.0)),
            (1.2, gui_update(scale, float("nan"))),
            (1.4, gui_update(scale, 1e6)),
        ]
        asyncio.run(probe(v.url, 2.5, send))
        assert p.value == 1.5 and stiff.value == 1.5  # the one in range went through, the rest bounced
        np.testing.assert_allclose(session.model.spring_stiffness.numpy(), 1.5 * k0, rtol=1e-6)
        rate = session.parameters["damping_rate"]
        assert damp.value == rate.value and np.isfinite(session.sim.solver.damping_rate)
        assert v.time_scale == 1.0 and scale.value == 1.0 and "time scale" in v.note
        for bad in (-0.5, 11.0, float("nan"), float("-inf")):  # the same from the server's side
            stiff.value = bad
            assert p.value == 1.5 and stiff.value == 1.5 and "refused" in v.note
            with pytest.raises(ValueError, match="outside"):
                write_parameter(session, "stiffness", bad)
        assert v.run_frame() and np.all(np.isfinite(session.x))
    finally:
        v.stop()


def test_a_client_that_drops_mid_drag_releases_the_grab():
    """Two tabs: A presses on the cloth and moves, then its connection drops (no drag end); B's moves and
    release while A holds it do nothing to A's grab. When A is gone the grab is released."""
    from pliant.live._probe import drag_message, probe

    session = LiveSession(_cloth())
    v = serve_live(session, port=_free_port(), start=False)
    try:
        x = session.x.astype(float)
        hit, up = x[60] + [0.001, 0.0, 0.0], x[60] + [0.0, 0.2, 0.0]

        async def tabs():
            a = probe(
                v.url,
                3.0,
                [
                    (0.3, drag_message("start", "/pliant/cloth", hit, hit)),
                    (0.5, drag_message("update", "/pliant/cloth", hit, up)),
                ],
                close_at=2.0,
            )
            far = x[60] + [0.0, -0.5, 0.0]
            b = probe(
                v.url,
                1.6,
                [
                    (1.0, drag_message("update", "/pliant/cloth", hit, far)),
                    (1.2, drag_message("end", "/pliant/cloth", hit, far)),
                ],
            )

            async def watch():
                await asyncio.sleep(1.5)  # A holds it, B has tried to move and release it
                return session.grabbed, None if session.target is None else session.target.copy()

            return await asyncio.gather(a, b, watch())

        _, _, (held, target) = asyncio.run(tabs())
        assert held == 60 and np.allclose(target, up)
        assert _wait(lambda: session.grabbed is None, 10.0)
        assert session.control.drag_index == -1
        v.run_frame()
        assert not v._marker.visible
    finally:
        v.stop()


def test_a_token_keeps_out_clients_without_it(capsys):
    """``token=``: a websocket without it, or with another, is closed (1008) before it receives anything;
    the URL the viewer prints carries it and connects."""
    from pliant.live._probe import probe

    session = LiveSession(_cloth())
    v = serve_live(session, port=_free_port(), start=False, token="s3cret-Token")
    try:
        assert v.url.endswith("?token=s3cret-Token") and "?websocket=ws://" in v.url
        base = v.url.split("/?websocket=")[0]

        async def three():
            return await asyncio.gather(
                probe(base, 2.0), probe(base + "/?token=wrong", 2.0), probe(v.url, 2.0)
            )

        none, wrong, good = asyncio.run(three())
        assert none.closed == 1008 and wrong.closed == 1008 and none.messages == wrong.messages == 0
        assert good.closed is None and good.messages > 0
        assert urllib.request.urlopen(base, timeout=10).status == 200  # the page itself is viser's, public
    finally:
        v.stop()


def test_the_rate_box_says_paused_while_paused():
    session = LiveSession(_cloth())
    v = serve_live(session, port=_free_port(), start=False)
    try:
        v.start()
        assert _wait(lambda: session.frame >= 5 and "frames/s" in v._gui["status"].value, 60)
        v.paused = True
        assert _wait(lambda: v._gui["status"].value.startswith("paused at frame"), 5)
        assert v.fps == 0.0 and "frames/s" not in v._gui["status"].value
        v._single.set()  # the step button
        f = session.frame
        assert _wait(lambda: f"frame {f + 1}" in v._gui["status"].value, 10)
    finally:
        v.stop()


def test_view_beyond_loopback_makes_a_token_and_says_who_can_drive(capsys):
    """Like Jupyter: ``--host 0.0.0.0`` without ``--token`` gets a random one, and stderr says that whoever
    reaches the port with it can drive the simulation; ``--token ''`` says ANYONE can; loopback needs none."""
    from argparse import Namespace

    from pliant.cli._view import view_token

    made = view_token(Namespace(host="0.0.0.0", port=8080, token=None, trajectory="cloth"))
    err = capsys.readouterr().err
    assert made and len(made) >= 20 and "can drive the simulation" in err and "0.0.0.0:8080" in err
    assert made != view_token(Namespace(host="0.0.0.0", port=8080, token=None, trajectory="cloth"))
    capsys.readouterr()
    assert view_token(Namespace(host="0.0.0.0", port=1, token="", trajectory="cloth")) is None
    assert "ANYONE" in capsys.readouterr().err
    assert view_token(Namespace(host="127.0.0.1", port=1, token=None, trajectory="cloth")) is None
    assert view_token(Namespace(host="::1", port=1, token="abc", trajectory="x.npz")) == "abc"
    assert capsys.readouterr().err == ""


TABS = """
import asyncio, json, sys
from pliant.live._probe import drag_message, probe
url, tabs, seconds, (hit, up) = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), json.loads(sys.argv[4])
drag = [(0.5, drag_message("start", "/pliant/cloth", hit, hit))]
drag += [(0.5 + 0.1 * i, drag_message("update", "/pliant/cloth", hit, up)) for i in range(1, 10)]

async def main():
    # One tab drags and drops its connection mid-drag, halfway through; the others watch to the end.
    dropper = probe(url, seconds, drag, close_at=0.5 * seconds) if tabs > 1 else None
    rest = [probe(url, seconds) for _ in range(tabs - (dropper is not None))]
    out = await asyncio.gather(*rest, *([dropper] if dropper else []))
    print(json.dumps([[r.messages, r.closed] for r in out]), flush=True)

asyncio.run(main())
"""


def _frame_rate(v, tabs: int, seconds: float, points) -> tuple[float, list]:
    """Frames per wall second the stepping thread reaches while ``tabs`` scripted tabs, in a child process
    as browsers are, receive every update (one of them dropping mid-drag when there are several)."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    args = [v.url, str(tabs), str(seconds + 3.0), json.dumps(points)]
    proc = subprocess.Popen([sys.executable, "-c", TABS, *args], stdout=subprocess.PIPE, text=True, env=env)
    try:
        time.sleep(2.0)  # connected, the scene sent
        f0, t0 = v.session.frame, time.perf_counter()
        time.sleep(seconds)
        f1, t1 = v.session.frame, time.perf_counter()
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    return (f1 - f0) / (t1 - t0), json.loads(out.strip().splitlines()[-1])


@pytest.mark.slow
def test_eight_tabs_cost_less_than_a_fifth_of_the_frame_rate():
    """Flat out (the pacing never waits), 1 then 8 tabs, three times: the frames stepped with 8 are at least
    80 % of those with 1 (totals over the runs: the machine is shared). Every tab received updates; the
    one that dropped mid-drag held the grab until it went, and then let go."""
    session = LiveSession(_cloth())
    v = serve_live(session, port=_free_port(), start=False)
    try:
        for _ in range(5):
            v.run_frame()
        x = session.x.astype(float)
        points = [(x[60] + [0.001, 0.0, 0.0]).tolist(), (x[60] + [0.0, 0.2, 0.0]).tolist()]
        v.time_scale = 100.0
        v.start()
        one, eight = [], []
        for _ in range(3):
            fps, seen = _frame_rate(v, 1, 4.0, points)
            one.append(fps)
            assert seen[0][0] > 10 and seen[0][1] is None
            fps, seen = _frame_rate(v, 8, 4.0, points)
            eight.append(fps)
            assert all(m > 10 and c is None for m, c in seen), seen
            assert session.grabbed is None and session.control.drag_index == -1
            assert session.latencies, "the dropped tab's drag never reached the simulation"
    finally:
        v.stop()
    print(f"frames/s with 1 tab {np.round(one, 1)}, with 8 {np.round(eight, 1)}")
    assert sum(eight) >= 0.8 * sum(one), (one, eight)


def test_the_live_camera_keeps_a_falling_rope_in_view():
    """A live view starts from one frame: the camera's box reaches down by the objects' size (to the ground
    at most), so the rope, straight at first and then hanging from its pin, stays in an 800 × 600 view and
    spans a good part of it."""
    sys.path.insert(0, str(Path(__file__).parent))
    from test_viewer import _pixels

    session = LiveSession(pl.scene.build_scene(pl.scene.load_scene("rope"), device="cpu"))
    v = serve_live(session, port=_free_port(), start=False)
    try:
        cam = v.server.initial_camera
        shots = [session.x.astype(float)]
        for _ in range(60):
            v.run_frame()
        shots.append(session.x.astype(float))
        for x in shots:
            px = _pixels(x, cam.position, cam.look_at, cam.fov)
            assert np.all(px.min(axis=0) >= 0) and np.all(px.max(axis=0) <= [800, 600]), px
            assert max(np.ptp(px[:, 0]) / 800, np.ptp(px[:, 1]) / 600) > 0.3
    finally:
        v.stop()
