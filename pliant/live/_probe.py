"""A scripted browser tab for the live view: a websocket client that speaks viser's protocol as the page does
(it reports a camera, receives every scene update, and drags a node), so tests and benchmarks load
``pliant view`` with many clients, drop one mid-drag, or send slider values a page would not, without a
browser. Loopback use only: every loop ends by itself after ``seconds``."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal


@dataclass
class ProbeResult:
    """What one scripted client saw.

    Attributes:
        messages: websocket messages received (each a window of viser messages).
        bytes: their total size [B].
        closed: the close code when the server closed the connection (1008: a missing or wrong token),
            or None when the client closed it.
    """

    messages: int = 0
    bytes: int = 0
    closed: int | None = None


def _encode(message: Any) -> bytes:
    import msgspec.msgpack

    return msgspec.msgpack.encode(message.as_serializable_dict())


def _camera() -> Any:
    from viser import _messages as vm

    return vm.ViewerCameraMessage(
        wxyz=(1.0, 0.0, 0.0, 0.0),
        position=(0.0, 1.0, 3.0),
        fov=1.0,
        near=0.01,
        far=100.0,
        image_height=600,
        image_width=800,
        look_at=(0.0, 0.5, 0.0),
        up_direction=(0.0, 1.0, 0.0),
    )


def drag_message(
    phase: Literal["start", "update", "end"],
    node: str,
    start: Sequence[float],
    end: Sequence[float],
    index: int | None = None,
):
    """viser's ``SceneNodeDragMessage`` a left-drag on scene node ``node`` sends.

    Args:
        phase: ``"start"``, ``"update"`` or ``"end"``.
        node: the scene node's name (a key of ``LiveViewer.nodes``).
        start: the world point [m] the press landed on.
        end: the pointer on the camera-facing drag plane [m].
        index: the instance under the pointer of a batched node (a rope's particle spheres), else None.
    """
    from viser import _messages as vm

    return vm.SceneNodeDragMessage(
        phase=phase,
        name=node,
        instance_index=index,
        start_position=(float(start[0]), float(start[1]), float(start[2])),
        start_screen_pos=(0.5, 0.5),
        end_position=(float(end[0]), float(end[1]), float(end[2])),
        end_screen_pos=(0.5, 0.5),
        button="left",
        modifier=None,
    )


def gui_update(slider: Any, value: object):
    """viser's ``GuiUpdateMessage`` that sets GUI element ``slider`` (its handle, e.g.
    ``LiveViewer._gui["param:stiffness"]``, or its uuid) to ``value``, as a page sends what its box holds."""
    from viser import _messages as vm

    uuid = slider if isinstance(slider, str) else slider._impl.uuid
    return vm.GuiUpdateMessage(uuid, {"value": value})


async def probe(
    url: str, seconds: float, send: Sequence[tuple[float, Any]] = (), close_at: float | None = None
):
    """Connect to the live view at ``url`` (``http://host:port``, with ``?token=...`` when it has one), say
    where the camera is, receive for ``seconds`` and send ``send``'s messages at their times.

    Args:
        url: the viewer's address (``LiveViewer.url``).
        seconds: how long to stay [s] (the loop ends then, whatever the server does).
        send: (time after connecting [s], viser message) pairs, in time order.
        close_at: drop the connection at this time [s] without ending a drag (a tab closed mid-drag).

    Returns:
        A :class:`ProbeResult`.
    """
    import viser
    import websockets.asyncio.client
    import websockets.exceptions
    from websockets.typing import Subprotocol

    ws_url = url.split("?websocket=", 1)[1] if "?websocket=" in url else url.replace("http://", "ws://", 1)
    out = ProbeResult()
    t0 = time.perf_counter()
    end = t0 + (seconds if close_at is None else min(seconds, close_at))
    queue = list(send)
    try:
        async with websockets.asyncio.client.connect(
            ws_url,
            subprotocols=[Subprotocol(f"viser-v{viser.__version__}")],
            max_size=None,
            open_timeout=30,
        ) as ws:
            await ws.send(_encode(_camera()))
            while (now := time.perf_counter()) < end:
                while queue and queue[0][0] <= now - t0:
                    await ws.send(_encode(queue.pop(0)[1]))
                wait = min(end - now, (queue[0][0] - (now - t0)) if queue else end - now, 0.05)
                try:
                    msg = await asyncio.wait_for(ws.recv(), timeout=max(wait, 1e-3))
                except asyncio.TimeoutError:
                    continue
                out.messages += 1
                out.bytes += len(msg)
    except websockets.exceptions.ConnectionClosed as exc:
        out.closed = exc.rcvd.code if exc.rcvd is not None else -1
    except websockets.exceptions.InvalidStatus as exc:
        out.closed = exc.response.status_code
    return out


async def probes(url: str, clients: int, seconds: float) -> list[ProbeResult]:
    """``clients`` tabs on ``url`` at once, each receiving for ``seconds``.

    Args:
        url: the viewer's address (``LiveViewer.url``).
        clients: how many tabs.
        seconds: how long each stays [s].
    """
    return list(await asyncio.gather(*(probe(url, seconds) for _ in range(clients))))


def drag_script(
    node: str, start: Sequence[float], to: Sequence[float], seconds: float, every: float
) -> list[tuple[float, Any]]:
    """A drag every ``every`` s for ``seconds``: press on ``start`` [m], ten moves to ``to`` [m] over one
    second, release; for :func:`probe`'s ``send``."""
    a, b = [float(c) for c in start], [float(c) for c in to]
    send, t = [], 1.0
    while t + 1.0 < seconds:
        send.append((t, drag_message("start", node, a, a)))
        for i in range(1, 11):
            at = [x + i / 10 * (y - x) for x, y in zip(a, b, strict=True)]
            send.append((t + 0.1 * i - 0.05, drag_message("update", node, a, at)))
        send.append((t + 1.0, drag_message("end", node, a, b)))
        t += every
    return send
