"""CMA-ES on several cores (issue 42 item 2): the 117-particle, 288-tet beam fitted from 60 tracks, on one
process pinned to one core against worker processes on two cores, side by side in one run.

    python benchmarks/fit_workers.py [--generations 8] [--repeats 2] [--no-fit] [--ray] [--json out.jsonl]

The beam is ``pliant bench beam_implicit``'s (``pliant/scenes/cantilever.toml`` with 12 × 2 × 2 cells,
4 substeps per frame, 90 frames, backward Euler, method "auto"). Its observations: 60 tracks
(``pl.fit.observe``, seed 3) of the beam with E × 1.6 and damping rate 2/s; the fit starts from the scene's
own values with the default parameters (E, ν, damping rate).

Rows (one JSON line each), every measurement a child process pinned with ``taskset`` (workers inherit it):

- ``per_generation``: ``pl.fit.cmaes`` for ``--generations`` generations (convergence off), on 1 core with
  1 process and on 2 cores with ``workers=2``, alternated ``--repeats`` times; the median seconds per
  generation after the first (whose 2-worker time includes the workers' start, reported as ``warmup_s``),
  their ratio; the CPU seconds per generation of the one process and of the busiest of the two
  (``cpu_speedup``: their ratio, the wall-time ratio a quiet machine would show, less the pipe's
  latency); and whether the two searches' losses are equal bit for bit; with ``--ray`` the two-core arm
  runs on 2 Ray actors of a local Ray cluster of 2 CPUs instead (``per_generation_ray``; Ray's own
  processes, its GCS and raylet, are not in the CPU seconds);
- ``fit``: the default ``pl.fit.fit`` (``pliant fit``'s defaults: 40 generations at most, per-element E
  kept where it lowers the validation loss; no video) on 1 core with ``workers=1`` and on 2 cores with
  ``workers="auto"``: wall seconds, the parent process's CPU seconds (on a quiet machine about the wall
  time, the workers running beside it), the workers "auto" took, and whether ``fitted.toml`` is byte for
  byte the same.

The box these figures come from may be shared: the ratios are measured side by side, so both arms see the
same load; absolute seconds are only as good as the box was quiet. Where Linux groups a session's processes
for the scheduler (``/proc/sys/kernel/sched_autogroup_enabled`` = 1, as on the shared 2-core box) and other
sessions keep the cores busy, the session gets its share of the machine however many processes it runs:
the wall-time ratio then stays near 1, and the CPU seconds are the figure that carries over.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CELLS = [12, 2, 2]
TRUTH = {"E": 1.6e6, "damping_rate": 2.0}


def _beam():
    """(start config, observations) of the beam fit."""
    import pliant as pl
    import pliant.fit
    import pliant.scene

    cfg = pl.scene.load_scene("cantilever")
    cfg.scene.substeps, cfg.scene.frames = 4, 90
    cfg.objects[0].cells = list(CELLS)
    truth = pl.scene.build_scene(pl.fit.apply_globals(cfg, TRUTH), device="cpu")
    return cfg, pl.fit.observe(truth, tracks=60, seed=3)


def child_generations(workers: int, generations: int, ray: bool = False) -> dict:
    """Seconds per generation of ``pl.fit.cmaes`` on ``workers`` processes (``ray``: Ray actors of a local
    cluster of ``workers`` CPUs), and its losses."""
    import pliant as pl
    import pliant.fit
    from pliant.fit._ray import use_ray
    from pliant.fit._workers import close_workers

    cfg, obs = _beam()
    problem = pl.fit.Problem(cfg, obs, device="cpu")
    if ray:
        import ray as ray_

        ray_.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
        use_ray(problem)
    stamps: list[float] = []
    cpu: list[float] = []

    class Hook:
        state = None
        losses: list = []

        def save(self, state: dict, iteration: int) -> None:
            self.losses = [g["losses"] for g in state["generations"]]

    hook = Hook()
    t0, c0 = time.perf_counter(), time.process_time()
    pl.fit.cmaes(
        problem,
        generations=generations,
        rtol=0.0,
        workers=workers,
        checkpoint=hook,
        callback=lambda g, f: (stamps.append(time.perf_counter()), cpu.append(time.process_time())),
    )
    pool = problem.__dict__.get("_worker_pool")
    warm = None if pool is None else pool.warmup_s
    shares = None if pool is None else pool.cpu_s[1:]  # after the first generation
    busiest = None if shares is None else float(np.median([max(c) for c in shares]))
    total = None if shares is None else float(np.median([sum(c) for c in shares]))
    close_workers(problem)
    gens = np.diff([t0, *stamps])
    return {
        "workers": workers,
        "ray": ray,
        "first_s": float(gens[0]),
        "per_generation_s": float(np.median(gens[1:])),
        "parent_cpu_per_generation_s": float(np.median(np.diff([c0, *cpu])[1:])),
        "warmup_s": warm,
        # the busiest process's CPU seconds per generation: the wall time on a quiet machine
        "busiest_cpu_per_generation_s": busiest,
        "total_cpu_per_generation_s": total,  # beside the one process's: the workers' overhead
        "losses": hook.losses,
        "params": [b.name for b in problem.globals],
        "shooting": problem.shooting,
    }


def child_fit(workers: int | str) -> dict:
    """Wall seconds of the default fit on ``workers`` processes, and its fitted.toml."""
    import logging

    import pliant as pl
    import pliant.fit

    seen: list[str] = []

    class Catch(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            seen.append(record.getMessage())

    log = logging.getLogger("pliant.fit")
    log.setLevel(logging.INFO)
    log.addHandler(Catch())
    cfg, obs = _beam()
    with tempfile.TemporaryDirectory() as out:
        t0, c0 = time.perf_counter(), time.process_time()
        rep = pl.fit.fit(cfg, obs, out, per_element="auto", progress=False, video=False, workers=workers)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        toml = (Path(out) / "fitted.toml").read_text()
    ready = [m for m in seen if "worker processes ready" in m]
    return {
        "workers": workers,
        "wall_s": wall,
        "cpu_s": cpu,
        "stage_wall_time": rep["stage_wall_time"],
        "evaluations": rep["evaluations"],
        "values": {k: p["value"] for k, p in rep["params"].items()},
        "error_test_mm": 1e3 * rep["error"]["test"],
        "workers_started": ready,
        "fitted_toml": toml,
    }


def _run(cores: str, args: list[str]) -> dict:
    """A child of this script pinned to ``cores`` (taskset), its JSON answer."""
    cmd = ["taskset", "-c", cores, sys.executable, __file__, "--child", *args]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=os.environ).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--generations", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--no-fit", action="store_true", help="only the per-generation row")
    ap.add_argument("--ray", action="store_true", help="the two-core arm on Ray actors (pliant[ray])")
    ap.add_argument("--json", help="append the rows to this JSONL file")
    ap.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        kind, w = a.child[0], a.child[1]
        w = w if w == "auto" else int(w)
        row = child_fit(w) if kind == "fit" else child_generations(w, int(a.child[2]), kind == "ray")
        print(json.dumps(row))
        return
    rows = []
    one, two = [], []
    for _ in range(a.repeats):
        one.append(_run("0", ["gen", "1", str(a.generations)]))
        two.append(_run("0,1", ["ray" if a.ray else "gen", "2", str(a.generations)]))
    t1 = float(np.median([r["per_generation_s"] for r in one]))
    t2 = float(np.median([r["per_generation_s"] for r in two]))
    rows.append(
        {
            "row": "per_generation_ray" if a.ray else "per_generation",
            "scene": "cantilever 12x2x2 (117 particles, 288 tets), 60 tracks",
            "params": one[0]["params"],
            "shooting": one[0]["shooting"],
            "generations": a.generations,
            "one_core_s": [r["per_generation_s"] for r in one],
            "two_cores_s": [r["per_generation_s"] for r in two],
            "speedup": t1 / t2,
            "cpu_speedup": float(
                np.median([r["parent_cpu_per_generation_s"] for r in one])
                / np.median([r["busiest_cpu_per_generation_s"] for r in two])
            ),
            "cpu_per_generation_s": {
                "one": [r["parent_cpu_per_generation_s"] for r in one],
                "two_busiest": [r["busiest_cpu_per_generation_s"] for r in two],
                "two_total": [r["total_cpu_per_generation_s"] for r in two],
            },
            "warmup_s": [r["warmup_s"] for r in two],
            "first_generation_s": {"one": [r["first_s"] for r in one], "two": [r["first_s"] for r in two]},
            "bit_for_bit": all(r["losses"] == one[0]["losses"] for r in one + two),
            "cpu_count": os.cpu_count(),
            "loadavg": os.getloadavg(),
        }
    )
    print(json.dumps(rows[-1]), flush=True)
    if not a.no_fit:
        f1 = _run("0", ["fit", "1"])
        f2 = _run("0,1", ["fit", "auto"])
        rows.append(
            {
                "row": "fit",
                "one_core_wall_s": f1["wall_s"],
                "two_cores_wall_s": f2["wall_s"],
                "speedup": f1["wall_s"] / f2["wall_s"],
                # this process's CPU seconds (the workers' excluded): about the wall time on a quiet box
                "one_core_cpu_s": f1["cpu_s"],
                "two_cores_parent_cpu_s": f2["cpu_s"],
                "stage_wall_time": {"one": f1["stage_wall_time"], "two": f2["stage_wall_time"]},
                "evaluations": f1["evaluations"],
                "auto_started": f2["workers_started"],
                "values": f1["values"],
                "error_test_mm": f1["error_test_mm"],
                "fitted_toml_equal": f1["fitted_toml"] == f2["fitted_toml"],
                "loadavg": os.getloadavg(),
            }
        )
        print(json.dumps(rows[-1]), flush=True)
    if a.json:
        with open(a.json, "a") as fh:
            fh.writelines(json.dumps(r) + "\n" for r in rows)


if __name__ == "__main__":
    main()
