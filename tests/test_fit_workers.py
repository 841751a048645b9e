"""CMA-ES on worker processes (issue 42 item 2, pliant/fit/_workers.py): the same search bit for bit as one
process, the checkpoint resumable across worker counts, workers that stop with the search, and the rule of
``workers="auto"``."""

from __future__ import annotations

import copy
import os
import signal
import subprocess
import sys
import time

import pytest

import pliant as pl
import pliant.fit
import pliant.scene
from pliant.fit._cmaes import batchable, cmaes
from pliant.fit._workers import (
    AUTO_HORIZON,
    WORKER_START_S,
    auto_workers,
    close_workers,
    parse_workers,
    unsplittable,
)

# A 2×2×2-cell FEM box thrown onto the ground (explicit steps): 8 frames, a few ms per rollout.
BOX = """
[scene]
name = "box"
frame_dt = 0.03333333333333333
substeps = 20
frames = 8
dtype = "float64"
[[objects]]
kind = "soft_box"
model = "fem"
cells = [2, 2, 2]
size = [0.2, 0.2, 0.2]
origin = [0.0, 0.12, 0.0]
density = 500.0
velocity = [0.5, -0.5, 0.0]
[objects.material]
E = 2e4
nu = 0.35
[ground]
height = 0.0
friction = 0.5
[solver]
integrator = "SymplecticEuler"
damping_rate = 1.0
"""


class _Hook:
    """A checkpoint stage (``StageHook``'s interface) that keeps every saved state in memory."""

    def __init__(self, state: dict | None = None) -> None:
        self.state = copy.deepcopy(state)
        self.saved: list[dict] = []

    def save(self, state: dict, iteration: int) -> None:
        self.saved.append(copy.deepcopy(state))


def _problem(params: list[str]) -> pl.fit.Problem:
    cfg = pl.scene.parse_scene(BOX, "box")
    obs = pl.fit.observe(pl.scene.build_scene(cfg, device="cpu"), tracks=8, seed=1)
    start = pl.fit.apply_globals(cfg, {"E": 4e4, "nu": 0.25, "damping_rate": 3.0})
    return pl.fit.Problem(start, obs, params=params, device="cpu")


@pytest.mark.parametrize("params", [["E", "nu"], ["E", "damping_rate"]], ids=["batched", "one_by_one"])
def test_two_workers_search_bit_for_bit(params: list[str]) -> None:
    """Every candidate's loss, the best values and the history: equal (==) on 1 and 2 processes, batched
    (explicit steps: one copy per candidate) or one rollout per candidate; and a search saved after its
    first generation by one process and continued on two ends where the one-process search ends."""
    p = _problem(params)
    assert batchable(p) == (params == ["E", "nu"])
    assert unsplittable(p, batchable(p)) is None
    one, two, resumed = _Hook(), _Hook(), None
    try:
        a = cmaes(p, generations=3, checkpoint=one)
        b = cmaes(p, generations=3, checkpoint=two, workers=2)
        assert p.__dict__["_worker_pool"].n == 2  # kept on the problem for its next stage
        resumed = _Hook(one.saved[0])
        c = cmaes(p, generations=3, checkpoint=resumed, workers=2)
    finally:
        close_workers(p)
    assert [g["losses"] for g in two.saved[-1]["generations"]] == [
        g["losses"] for g in one.saved[-1]["generations"]
    ]
    assert len(one.saved[-1]["generations"]) == 3
    assert (b.values, b.loss, b.history, b.evaluations) == (a.values, a.loss, a.history, a.evaluations)
    assert resumed.saved[-1] == one.saved[-1]
    assert (c.values, c.history) == (a.values, a.history)


def test_workers_search_the_held_back_window_as_one_process_does() -> None:
    """The validation gate holds back the last training frames while the global stage searches
    (``held_back``): workers, whose problems were built before, search the same shortened window (a pool
    that ignored it searched all the training frames, and a fit on two cores wrote other values)."""
    from pliant.fit._gate import held_back

    p = _problem(["E", "nu"])
    n = p.n_train
    try:
        with held_back(p, n - 3):
            a = cmaes(p, generations=2)
            b = cmaes(p, generations=2, workers=2)
        c = cmaes(p, generations=2, workers=2)  # the whole window again, on the same pool
    finally:
        close_workers(p)
    assert (b.values, b.loss, b.history) == (a.values, a.loss, a.history)
    assert c.loss != a.loss  # a different window: a different loss


def test_workers_stop_on_an_error() -> None:
    """A worker that cannot build its problem: a FitError naming it, and no worker left running; an
    exception in the search (here its callback) stops the workers too."""
    p = _problem(["E", "nu"])
    good = p.recipe
    p.recipe = (good[0], good[1], {**good[2], "params": ["no_such_parameter"]})
    with pytest.raises(pl.fit.FitError, match=r"CMA-ES worker [12] of 2 failed: FitError"):
        cmaes(p, generations=2, workers=2)
    assert "_worker_pool" not in p.__dict__

    p.recipe = good
    procs = []

    def boom(gen: int, loss: float) -> None:
        procs.extend(p.__dict__["_worker_pool"].backend.procs)
        raise RuntimeError("stop here")

    with pytest.raises(RuntimeError, match="stop here"):
        cmaes(p, generations=2, workers=2, callback=boom)
    assert procs and not any(proc.is_alive() for proc in procs)
    assert "_worker_pool" not in p.__dict__


_KILLED_PARENT = """
import sys, time
sys.path.insert(0, {tests!r})
from test_fit_workers import _problem
from pliant.fit._workers import pool_for

if __name__ == "__main__":
    p = _problem(["E", "damping_rate"])
    pool = pool_for(p, 2, False, True)
    pool.evaluate(p, [p.nominal] * 2)
    print(*[q.pid for q in pool.backend.procs], flush=True)
    time.sleep(600)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:  # a zombie is dead (its parent is gone too: reaped by init)
        return f.read().split(")")[-1].split()[0] != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG and /proc: Linux")
def test_workers_die_with_a_killed_parent() -> None:
    """A parent killed outright (SIGKILL: no cleanup runs) takes its workers with it within seconds."""
    code = _KILLED_PARENT.format(tests=os.path.dirname(__file__))
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        pids = [int(w) for w in parent.stdout.readline().split()]
        assert len(pids) == 2 and all(_alive(pid) for pid in pids)
    finally:
        parent.send_signal(signal.SIGKILL)
        parent.wait()
    deadline = time.monotonic() + 10.0
    while any(_alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(_alive(pid) for pid in pids)


def test_auto_rule() -> None:
    """``auto``: all the cores (at most one per candidate) where they save a worker's start over the next
    generations, else one process; an implicit batched generation stays in one process; bad counts fail."""
    long_gen = 4.0 * WORKER_START_S / AUTO_HORIZON  # 2 processes save half: 2 × the start
    short_gen = 1.0 * WORKER_START_S / AUTO_HORIZON  # 2 processes save half: 0.5 × the start
    assert auto_workers(2, 10, long_gen, 40) == 2
    assert auto_workers(16, 10, long_gen, 40) == 10
    assert auto_workers(2, 10, short_gen, 40) == 1
    assert auto_workers(2, 10, long_gen, 1) == 1  # one generation left: 0.4 × the start
    assert auto_workers(1, 10, 100.0, 40) == 1
    assert parse_workers("auto") is None and parse_workers("3") == 3
    for bad in (0, -1, "many", True, 1.5):
        with pytest.raises(pl.fit.FitError, match="--workers"):
            parse_workers(bad)
    implicit = _problem(["E", "nu"])
    implicit.cfg.solver.integrator = "BackwardEuler"
    assert "losses would change" in unsplittable(implicit, True)
    assert unsplittable(implicit, False) is None
