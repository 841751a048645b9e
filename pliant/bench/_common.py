"""Shared pieces of the benchmark modules: the timed stepping loop and the speed columns of a row.

No ``BENCHMARKS`` here: :func:`pliant.bench.discover` skips this module.
"""

from __future__ import annotations

import json
import os
import resource
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .._time import substep_dt

if TYPE_CHECKING:
    import numpy as np
    import warp as wp

    from ..model import Control, Model, State
    from ..solvers import FrameStep, Solver


@dataclass(frozen=True)
class Timing:
    """A timed benchmark run: ``wall`` and process ``cpu`` seconds of the ``frames`` × ``substeps`` timed
    steps on ``device``, and ``compile``, the seconds of set-up plus the two warm-up steps (kernel
    compilation or cache load, launch recording)."""

    wall: float
    cpu: float
    compile: float
    frames: int
    substeps: int
    device: str
    #: Whether the timed frames were replayed as one captured graph each (``PLIANT_BENCH_GRAPH=1``).
    graph: bool = False


def run_timed(
    model: Model,
    solver: Solver,
    control: Control | None,
    dt: float,
    *,
    frames: int,
    substeps: int,
    device: str,
    started: float,
    reuse_states: bool = False,
    on_step: Callable[[], None] | None = None,
) -> tuple[Any, Timing]:
    """Warm up with two steps, then time ``frames`` × ``substeps`` steps of ``dt`` [s] from the initial state.

    ``started`` is the ``time.perf_counter()`` taken before the model was built: the compile time counts
    from there. ``reuse_states`` restarts from the initial state in the warmed-up state arrays (for solvers
    that replay launches recorded for those arrays, e.g. XPBD) instead of in fresh ones. ``on_step`` runs
    after each timed step (e.g. to collect solver statistics). Returns the final state and the timing.

    With ``PLIANT_BENCH_GRAPH=1`` (``pliant bench --graph``) a frame is captured once as a graph (a CUDA
    graph on a GPU, Warp's CPU graph on the CPU) and the timed frames replay it, as the Simulator does by
    default; the same final state bit for bit. Not when the solver names a graph blocker, with
    ``on_step`` (a host call per step) or an odd substep count (a frame would end in the other buffer).
    """
    import warp as wp

    s0, s1 = model.state(), model.state()
    solver.step(s0, s1, control, dt)
    solver.step(s1, s0, control, dt)
    wp.synchronize_device(device)
    compile_s = time.perf_counter() - started
    from ..solvers import FrameStep

    frame = FrameStep(solver, dt, substeps, on_step=on_step)
    graph = _frame_graph(frame, solver, s0, s1, control, device) if _graph_asked(substeps, on_step) else None
    if reuse_states or graph is not None:  # a graph (or XPBD's recorded launches) holds these arrays
        s0.assign(model.state())
        s1.assign(model.state())
    else:
        s0, s1 = model.state(), model.state()
    wp.synchronize_device(device)
    t0 = time.perf_counter()
    c0 = time.process_time()
    if graph is not None:
        for _ in range(frames):
            wp.capture_launch(graph)
    else:
        for _ in range(frames):
            s0, s1 = frame(s0, control, s1)
    wp.synchronize_device(device)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return s0, Timing(wall, cpu, compile_s, frames, substeps, device, graph is not None)


def _graph_asked(substeps: int, on_step: Callable[[], None] | None) -> bool:
    """Whether ``PLIANT_BENCH_GRAPH=1`` asks for graph replay and this run allows it (see run_timed)."""
    return os.environ.get("PLIANT_BENCH_GRAPH") == "1" and on_step is None and substeps % 2 == 0


def _frame_graph(
    frame: FrameStep, solver: Solver, s0: State, s1: State, control: Control | None, device: str
) -> wp.Graph | None:
    """One frame of ``frame`` from ``s0`` (back in ``s0`` after its even substep count) captured as a graph,
    or None when the solver names a graph blocker or the capture fails (the frames then run directly)."""
    import warp as wp

    blocker = getattr(solver, "graph_blocker", None)
    if callable(blocker) and blocker() is not None:
        return None
    try:
        with wp.ScopedCapture(device=device) as cap:
            end, _ = frame(s0, control, s1)
    except Exception:  # a solver that reads the host mid-step on CUDA: time it launch by launch
        return None
    return cap.graph if end is s0 else None


def sig4(value: float) -> float:
    """``value`` rounded to 4 significant digits (rates and residuals in the rows)."""
    return float(f"{value:.4g}")


def peak_mem_mb(device: str) -> float:
    """Peak memory [MiB]: the Warp mempool high-water mark on CUDA, this process's max RSS on the CPU."""
    if device.startswith("cuda"):
        import warp as wp

        return wp.get_mempool_used_mem_high(device) / 2**20
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def speed_fields(timing: Timing, particles: int, *, process: bool = True) -> dict:
    """The speed columns of a row for ``particles`` particles: wall_s, compile_s, fps, particle_substeps_per_s
    and, with ``process``, cpu_s, load_avg_1min, fps_cpu_time and peak_mem_mb (machine load and memory)."""
    wall, cpu, frames, device = timing.wall, timing.cpu, timing.frames, timing.device
    row: dict[str, Any] = {"wall_s": round(wall, 4)}
    if process:
        row["cpu_s"] = round(cpu, 4)  # this process's CPU time: the figure to trust on a shared machine
        row["load_avg_1min"] = round(os.getloadavg()[0], 2)
    row["compile_s"] = round(timing.compile, 3)
    row["fps"] = round(frames / wall, 2)
    row["graph"] = timing.graph
    if process:
        row["fps_cpu_time"] = round(frames / cpu, 2) if device == "cpu" and cpu > 0 else None
    row["particle_substeps_per_s"] = sig4(particles * frames * timing.substeps / wall)
    if process:
        row["peak_mem_mb"] = round(peak_mem_mb(device), 1)
    return row


def print_rows(benchmarks: Mapping[str, Callable[..., dict]], names: Sequence[str]) -> None:
    """Run the named benchmarks (all when ``names`` is empty) and print one JSON line each."""
    for name in names or list(benchmarks):
        print(json.dumps({"benchmark": name, **benchmarks[name]()}), flush=True)


#: Converged motion references stored with the package (pliant/bench/references/*.npz).
REFERENCES = Path(__file__).parent / "references"


def load_reference(stem: str, key: str, remake: str) -> np.ndarray:
    """Array ``key`` of ``references/<stem>.npz`` as float64; FileNotFoundError naming ``remake`` (the
    command that makes it) when the file is missing."""
    import numpy as np

    path = REFERENCES / f"{stem}.npz"
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such reference; make it with {remake}")
    with np.load(path, allow_pickle=False) as d:
        return np.asarray(d[key], dtype=np.float64)


def curve_deviation(curve: np.ndarray, reference: np.ndarray, scale: float) -> float:
    """max_k |curve_k − reference_k| / ``scale`` over the frames both have; inf if ``curve`` is not finite
    there (the ``trajectory_error`` of the motion benchmarks)."""
    import numpy as np

    k = min(len(curve), len(reference))
    if not np.all(np.isfinite(curve[:k])):
        return float("inf")
    return float(np.max(np.abs(np.asarray(curve[:k]) - np.asarray(reference[:k]))) / scale)


def frame_curve(
    model: Model,
    solver: Solver,
    measure: Callable[[np.ndarray], float],
    *,
    substeps: int,
    frames: int,
    frame_dt: float,
    include_start: bool = True,
) -> np.ndarray:
    """``measure(positions)`` at every frame of ``solver`` stepping ``model`` from its initial state:
    ``frames`` frames of ``substeps`` steps of ``frame_dt / substeps`` [s] (frame 0 first when
    ``include_start``). The sanity curve of the motion benchmarks (sag, centre-of-mass height)."""
    import numpy as np

    control = model.control()
    s0, s1 = model.state(), model.state()
    out = [measure(s0.particle_q.numpy())] if include_start else []
    from ..solvers import FrameStep

    frame = FrameStep(solver, substep_dt(frame_dt, substeps), substeps)
    for _ in range(frames):
        s0, s1 = frame(s0, control, s1)
        out.append(measure(s0.particle_q.numpy()))
    return np.asarray(out)
