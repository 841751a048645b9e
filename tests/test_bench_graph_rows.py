"""``pliant bench --graph`` (``PLIANT_BENCH_GRAPH=1``): the rows' timed frames replay one captured graph, as
the Simulator runs them, and end in the same state bit for bit as frames launched step by step."""

from __future__ import annotations

import numpy as np
import pytest

from pliant.bench._common import run_timed
from pliant.bench._mass_spring import cloth_drape_model, make_solver
from pliant.solvers import XPBD


def _final(device: str, solver_kind: str, substeps: int, monkeypatch, graph: bool):
    monkeypatch.setenv("PLIANT_BENCH_GRAPH", "1" if graph else "0")
    model = cloth_drape_model(8, device=device, dtype="float32")
    if solver_kind == "xpbd":
        solver = XPBD(model, iterations=1, schedule="coloring")
    else:
        solver = make_solver(model, "symplectic")
    state, timing = run_timed(
        model,
        solver,
        model.control(),
        1 / 60 / substeps,
        frames=3,
        substeps=substeps,
        device=device,
        started=0.0,
        reuse_states=solver_kind == "xpbd",
    )
    return state.particle_q.numpy().copy(), timing


@pytest.mark.parametrize("solver_kind", ["fast_mass_spring", "xpbd"])
def test_graph_rows_replay_the_same_frames(device, solver_kind, monkeypatch):
    direct, t_direct = _final(device, solver_kind, 8, monkeypatch, graph=False)
    replayed, t_graph = _final(device, solver_kind, 8, monkeypatch, graph=True)
    assert not t_direct.graph and t_graph.graph
    assert np.all(np.isfinite(replayed))
    assert direct[:, 1].min() < cloth_drape_model(8, device=device).particle_q.numpy()[:, 1].min() - 1e-3
    np.testing.assert_array_equal(replayed, direct)


def test_odd_substeps_run_directly(monkeypatch):
    """A frame of an odd substep count ends in the other buffer: it cannot be replayed in place."""
    _, timing = _final("cpu", "fast_mass_spring", 7, monkeypatch, graph=True)
    assert not timing.graph
