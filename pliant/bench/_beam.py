"""Small implicit FEM on the CPU (issue 42): a 117-particle, 288-tet cantilever beam, ms per substep.

Scene: ``pliant/scenes/cantilever.toml`` (neo-Hookean, E = 1 MPa, ν = 0.3, 1000 kg/m³, 0.6 × 0.1 × 0.1 m
clamped at x = −0.3 m, backward Euler, damping rate 1/s, ``method="auto"``) with 12 × 2 × 2 cells (117
particles, 288 tets), 4 substeps per 1/30 s frame, 90 frames, in the scene's float32 (``dtype``: float64).

One run times, side by side after a warm-up run each (kernel builds, graph captures): ``method="auto"``
(on the CPU for this size: the device Newton with the banded LDLᵀ, frames replayed as CPU graphs; see
:mod:`pliant.solvers.minimizers._band`) and ``method="lbfgs"`` (what "auto" took before). Each reports ms per
substep, wall and process CPU time (on a loaded machine the CPU time is the steadier figure), and its
``trajectory_error``: max over frames and particles of |x − x_ref| [m] against a converged reference (the
same scene in float64, host Newton with SciPy's sparse LU, ``newton_tol`` 1e-9 m/s), beside the largest tip
sag of the reference [m] (the motion's scale).

``python -m pliant.bench._beam`` prints the row as one JSON line.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

import numpy as np

from ._common import print_rows, sig4

CELLS = (12, 2, 2)
SUBSTEPS = 4
FRAMES = 90
#: The minimisers compared: the new "auto" and L-BFGS, what "auto" took on the CPU before.
METHODS = {"auto": {"method": "auto"}, "lbfgs": {"method": "lbfgs"}}


def beam_scene(dtype: str, minimizer: dict, newton_tol: float | None = None):
    """The row's beam as a built Scene (``pliant.scene.Scene``), its minimiser and tolerance as given."""
    from ..scene import build_scene, load_scene

    cfg = load_scene("cantilever")
    cfg.scene.substeps = SUBSTEPS
    cfg.objects[0].cells = list(CELLS)
    cfg.solver.options = {**cfg.solver.options, "minimizer": minimizer}
    if newton_tol is not None:
        cfg.solver.integrator_options = {**cfg.solver.integrator_options, "newton_tol": newton_tol}
    return build_scene(cfg, device="cpu", dtype=dtype)


def _timed(dtype: str, minimizer: dict, frames: int) -> tuple[np.ndarray, float, float, str]:
    """Positions [frames + 1, n, 3] of a timed run after an untimed one of 2 frames of the same simulator
    (kernel builds, graph captures; then ``restart``, so the timed run is a fresh one: see
    ``Simulator.restart``), its wall and CPU seconds, and the minimiser's linear solver."""
    scene = beam_scene(dtype, minimizer)
    sim = scene.simulator()
    sim.run(2, progress=False)
    sim.restart()
    wall, cpu = time.perf_counter(), time.process_time()
    x = sim.run(frames, progress=False).x
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return x, wall, cpu, str(scene.solver.last_stats.linear_solver)


def beam_implicit(quick: bool = False, dtype: str = "float32") -> dict:
    """The 117-particle, 288-tet beam, 4 substeps per frame: ms per substep of method "auto" and of
    L-BFGS side by side, each with its trajectory error [m] against a converged float64 reference."""
    frames = 15 if quick else FRAMES
    reference = beam_scene("float64", {"method": "newton", "linear_solver": "direct"}, newton_tol=1e-9)
    ref = reference.simulator().run(frames, progress=False).x
    tip = np.isclose(ref[0, :, 0], ref[0, :, 0].max())
    row: dict = {
        "scene": "cantilever 12x2x2",
        "solver": "ForceSolver",
        "integrator": "BackwardEuler",
        "device": "cpu",
        "dtype": dtype,
        "particles": int(ref.shape[1]),
        "elements": int(reference.model.tet_count),
        "substeps": SUBSTEPS,
        "frames": frames,
        "reference_max_tip_sag_m": sig4(float((ref[0, tip, 1].mean() - ref[:, tip, 1].mean(axis=1)).max())),
    }
    steps = frames * SUBSTEPS
    for name, minimizer in METHODS.items():
        x, wall, cpu, linear = _timed(dtype, minimizer, frames)
        row[f"{name}_linear_solver"] = linear
        row[f"{name}_ms_per_substep_wall"] = sig4(1e3 * wall / steps)
        row[f"{name}_ms_per_substep_cpu"] = sig4(1e3 * cpu / steps)
        row[f"{name}_trajectory_error_m"] = sig4(float(np.abs(x - ref).max()))
    row["speedup_cpu"] = sig4(row["lbfgs_ms_per_substep_cpu"] / row["auto_ms_per_substep_cpu"])
    return row


BENCHMARKS: dict[str, Callable[..., dict]] = {"beam_implicit": beam_implicit}

if __name__ == "__main__":
    print_rows(BENCHMARKS, sys.argv[1:])
