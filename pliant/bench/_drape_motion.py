"""The drape's whole motion, not only its rest: the sag per frame against a converged reference.

A speed figure means little if the solver buys it by damping the motion away (truncated CG acts as heavy
damping; a benchmark's extra velocity damping slows the fall). ``trajectory_error`` is the largest deviation
of a run's sag curve (pin height minus the lowest particle, every frame) from the converged curve of the
same physics, relative to the reference's final sag, over the fall: the first 30 frames (0.5 s), where
truncated iterations and extra damping show (the issue's 128 × 128 drape: sag 0.61 m at frame 30 with 20 CG
iterations, 0.97 m converged). Later the undamped drape (no dashpots, no bending) folds chaotically and no
run converges over long windows (n = 16, 60 frames: 320 and 640 substeps per frame still differ by 8 %),
so the window stops at the fall. The references are float64 symplectic Euler at 640 substeps per frame
(n = 16: 320 substeps are within 6e-5 of it, first-order convergence measured 40 → 320), undamped, computed
once and stored in ``pliant/bench/references/cloth_drape_<n>.npz``; regenerate with
``python -m pliant.bench._drape_motion N`` (n = 16: a second; n = 128: about a minute on one core).

Sizes without a stored reference (256, 512: 5e9 and 4e10 particle-substeps in float64, about 5 minutes and
an hour on one core) get one on the device of the row that needs it (:func:`reference_for`: seconds on a
GPU), cached in ``$PLIANT_BENCH_CACHE`` (default ``~/.cache/pliant/bench``) with its substeps and device; on
the CPU it is not computed above :data:`CPU_REFERENCE_MAX` cells per side (``trajectory_error`` None, the
row's ``reference`` column says why). A cached file can be committed to ``references/`` as it is
(``python -m pliant.bench._drape_motion 512 --device cuda:0`` writes it there directly).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ._common import REFERENCES, curve_deviation, frame_curve, load_reference
from ._drape_scene import FRAME_DT, cloth_drape_model, make_solver, sag

if TYPE_CHECKING:
    from ..model import Model
    from ..solvers import Solver

#: Substeps per frame of the references (8× or more the stable benchmark setting; other sizes: 10 n, at
#: least 640, :func:`reference_substeps`).
REFERENCE_SUBSTEPS = {16: 640, 64: 640, 128: 1280, 256: 2560, 512: 5120}
#: Largest cells per side whose missing reference is computed on the CPU (256 takes minutes of one core).
CPU_REFERENCE_MAX = 128
#: Frames of 1/60 s the references cover: the fall.
REFERENCE_FRAMES = 30


def sag_curve(
    n: int,
    method: str,
    *,
    substeps: int,
    cg_iterations: int = 100,
    cg_tol: float = 1.0e-2,
    damping_rate: float = 0.0,
    frames: int = REFERENCE_FRAMES,
    dtype: str = "float32",
    device: str | None = "cpu",
) -> np.ndarray:
    """Sag [m] at frames 0 … ``frames`` of the n × n drape run with a benchmark solver (``method``:
    "implicit", "symplectic" or "force"; see :func:`pliant.bench._drape_scene.make_solver`)."""
    model = cloth_drape_model(n, device=device, dtype=dtype)
    solver = make_solver(model, method, cg_iterations=cg_iterations, cg_tol=cg_tol, damping_rate=damping_rate)
    return solver_curve(model, solver, substeps=substeps, frames=frames)


def solver_curve(
    model: Model, solver: Solver, *, substeps: int, frames: int = REFERENCE_FRAMES
) -> np.ndarray:
    """Sag [m] at frames 0 … ``frames`` of ``solver`` stepping ``model`` from its initial state, ``substeps``
    steps of 1/60 s / ``substeps`` per frame (any pliant solver: mass-spring, XPBD, ...)."""
    return frame_curve(
        model, solver, lambda x: sag(model, x), substeps=substeps, frames=frames, frame_dt=FRAME_DT
    )


def reference_curve(n: int) -> np.ndarray:
    """The stored converged sag curve [m] of the n × n drape (frames 0 … 30)."""
    return load_reference(f"cloth_drape_{n}", "sag", f"python -m pliant.bench._drape_motion {n}")


def reference_substeps(n: int) -> int:
    """Substeps per frame of the n × n reference: :data:`REFERENCE_SUBSTEPS`, else max(640, 10 n) (the
    stable symplectic setting is 1.25 n: 8× that)."""
    return REFERENCE_SUBSTEPS.get(n, max(640, 10 * n))


def compute_reference(n: int, device: str | None = "cpu") -> np.ndarray:
    """The converged curve: float64 symplectic Euler, undamped, at :func:`reference_substeps`, on
    ``device``."""
    return sag_curve(n, "symplectic", substeps=reference_substeps(n), dtype="float64", device=device)


def cache_dir() -> Path:
    """Where references computed on demand are kept: ``$PLIANT_BENCH_CACHE`` or ``~/.cache/pliant/bench``."""
    raw = os.environ.get("PLIANT_BENCH_CACHE", "").strip()
    return Path(raw).expanduser() if raw else Path.home() / ".cache" / "pliant" / "bench"


def save_reference(path: Path, n: int, curve: np.ndarray, device: str) -> None:
    """Write a reference ``curve`` of the n × n drape to ``path`` (atomically: parallel rows may race)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
    np.savez(tmp, sag=curve, substeps=reference_substeps(n), device=device)
    os.replace(tmp, path)


#: References found or computed in this process, by (n, cache folder): one provenance per size, and the
#: cache read once.
_RESOLVED: dict[tuple[int, str], tuple[np.ndarray, str]] = {}


def reference_for(n: int, device: str | None = "cpu") -> tuple[np.ndarray | None, str]:
    """The converged sag curve of the n × n drape and where it came from: the stored file, the cache, or
    computed now on ``device`` (then cached; not on the CPU above :data:`CPU_REFERENCE_MAX`). ``(None,
    why)`` when there is none."""
    if (REFERENCES / f"cloth_drape_{n}.npz").exists():
        return reference_curve(n), "stored"
    cached = cache_dir() / f"cloth_drape_{n}.npz"
    key = (n, str(cached))
    if key in _RESOLVED:
        return _RESOLVED[key]
    if cached.exists():
        with np.load(cached, allow_pickle=False) as d:
            if int(d["substeps"]) == reference_substeps(n):
                _RESOLVED[key] = np.asarray(d["sag"], dtype=np.float64), f"cached {cached} ({d['device']})"
                return _RESOLVED[key]
    dev = "cpu" if device is None else str(device)
    if dev == "cpu" and n > CPU_REFERENCE_MAX:
        return None, (
            f"none: not computed on the CPU above {CPU_REFERENCE_MAX}² (run the row on a GPU, or "
            f"`python -m pliant.bench._drape_motion {n} --device cuda:0`)"
        )
    t0 = time.perf_counter()
    curve = compute_reference(n, dev)
    save_reference(cached, n, curve, dev)
    _RESOLVED[key] = curve, f"computed on {dev} in {time.perf_counter() - t0:.1f} s, cached {cached}"
    return _RESOLVED[key]


def trajectory_error(curve: np.ndarray, reference: np.ndarray) -> float:
    """max_k |curve_k − reference_k| / reference_final over the frames both have (inf if not finite)."""
    return curve_deviation(curve, reference, abs(reference[-1]))


def curve_error(n: int, curve: np.ndarray, device: str | None = "cpu") -> dict:
    """``{"trajectory_error": ..., "reference": ...}`` of a sag ``curve`` of the n × n drape against
    :func:`reference_for` on ``device`` (None, and why, without a reference)."""
    ref, source = reference_for(n, device)
    error = None if ref is None else round(trajectory_error(curve, ref), 5)
    return {"trajectory_error": error, "reference": source}


def motion_fields(
    n: int, method: str, substeps: int, cg_iterations: int, damping_rate: float, **kw: Any
) -> dict:
    """The ``trajectory_error`` and ``reference`` columns of a drape row: a second, untimed run of the
    row's settings (``kw``: dtype, device) over the reference's frames (None, and why, when there is no
    reference for n)."""
    device = kw.get("device", "cpu")
    ref, source = reference_for(n, device)
    if ref is None:
        return {"trajectory_error": None, "reference": source}
    curve = sag_curve(
        n, method, substeps=substeps, cg_iterations=cg_iterations, damping_rate=damping_rate, **kw
    )
    return curve_error(n, curve, device)


def export_network(n: int, path: str) -> None:
    """Write the n × n drape's spring network for peers (benchmarks/peers/cloth_drape_newton.py): positions
    ``x`` [P, 3] m, lumped ``mass`` [P] kg, ``free`` [P] (False: pinned), ``springs`` [S, 2], ``rest`` [S] m
    and ``stiffness`` [S] N/m."""
    model = cloth_drape_model(n, device="cpu", dtype="float64")
    np.savez(
        path,
        x=model.particle_q.numpy(),
        mass=model.particle_mass.numpy(),
        free=model.particle_inv_mass.numpy() > 0,
        springs=model.spring_indices.numpy(),
        rest=model.spring_rest_length.numpy(),
        stiffness=model.spring_stiffness.numpy(),
    )


if __name__ == "__main__":
    if sys.argv[1:2] == ["export"]:
        export_network(int(sys.argv[2]), sys.argv[3])
        sys.exit(0)
    args, dev = sys.argv[1:], "cpu"
    if "--device" in args:
        i = args.index("--device")
        dev, args = args[i + 1], args[:i] + args[i + 2 :]
    for arg in args:
        size = int(arg)
        curve = compute_reference(size, dev)
        save_reference(REFERENCES / f"cloth_drape_{size}.npz", size, curve, dev)
        print(f"cloth_drape_{size}: final sag {curve[-1]:.6f} m, max {curve.max():.6f} m ({dev})")
