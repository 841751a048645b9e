"""No host reads where a GPU would stall or a CUDA graph capture would fail (issue 24), checked on any device
by counting the calls that would be reads on a GPU (tests/host_reads.py):

* every built-in scene whose frames the Simulator replays as graphs steps a frame with no host read and no
  upload, launched directly and while captured;
* every gradient row's taped rollout (tests/test_devices_grad.py) that replays as a graph reads nothing back
  while it is captured — the forward steps, the losses and the adjoints recorded on the tape.
"""

from __future__ import annotations

import pytest
from host_reads import HostReads
from test_devices_grad import ROWS, weighted_loss

import pliant as pl
import pliant.scene
from pliant.scene import builtin_scenes

#: Rows whose rollouts run directly by design, and the words of their reason.
DIRECT_ROWS = {"implicit-backward-euler": "implicit-function adjoint"}


@pytest.mark.parametrize("name", builtin_scenes())
def test_replayable_scene_frames_read_nothing_back(name: str) -> None:
    """A frame of a scene the Simulator replays: zero host reads per frame launched one by one (after a
    warm-up frame that allocates and builds; a scripted handle's positions may be uploaded between frames),
    and zero reads and uploads inside the capture of its graph."""
    cfg = pl.scene.load_scene(name)
    sim = pl.scene.build_scene(cfg).simulator()
    if sim.graph_reason is not None:
        pytest.skip(f"{name} steps directly by design: {sim.graph_reason}")
    sim.set_graph(False)
    sim.step_frame()
    with HostReads() as direct:
        sim.step_frame()
    assert direct.counts["read"] == 0, f"{name}: host reads in a direct frame: {direct.report()}"
    sim.set_graph(True)
    with HostReads(capture_only=True) as captured:
        for _ in range(3):
            sim.step_frame()
    assert sim._graphs.captures >= 1 and sim.graph_reason is None
    assert captured.total() == 0, f"{name}: host reads while capturing: {captured.report()}"


@pytest.mark.parametrize("row", list(ROWS))
def test_replayed_rollouts_read_nothing_back_while_captured(row: str) -> None:
    """Each solver family's gradient rollout: its capturing call makes no host read or upload on the
    capturing device (a CUDA capture would fail there), and the rollout then replays."""
    make_model, make_solver, name, frames, substeps, dt, every, _ = ROWS[row]
    m = make_model("cpu")
    solver = make_solver(m)
    loss = weighted_loss(m, "cpu")
    kw = {"frames": frames, "substeps": substeps, "dt": dt, "params": [name], "checkpoint_every": every}
    with HostReads(capture_only=True) as reads:
        results = [pl.diff.rollout(m, solver, loss, **kw) for _ in range(3)]
    if row in DIRECT_ROWS:
        assert DIRECT_ROWS[row] in (results[-1].graph_reason or "")
        return
    assert results[-1].replayed, f"{row}: {results[-1].graph_reason}"
    assert reads.total() == 0, f"{row}: host reads while capturing: {reads.report()}"
