"""What the fused frame's ground contact buys (issue #42): CPU seconds of FastMassSpring rollouts and fits
with a ground, before (step-by-step frames: a tree without it) and after, in paired, interleaved rounds.

    git archive 2c31b4f | tar -x -C /tmp/before      # the tree before the fused ground
    PYTHONPATH=$PWD python benchmarks/bench_fused_ground.py --before /tmp/before [--rounds 3] [--only fit]
    PYTHONPATH=$PWD python benchmarks/bench_fused_ground.py --before /tmp/before --only fit --only beam

Two rows, each run in a fresh process per tree and round (the same Warp kernel cache), order alternating:

- ``rollout``: the built-in ``cloth`` scene (24², 80 substeps, pinned corners, draping onto the ground at
  y = 0, friction 0.6) with ``solver.kind = fast_mass_spring``, 120 frames, 5 times; the end state's
  bytes compared.
- ``fit``: the default ``pliant fit`` (``--workers 1 --no-video``) on the MuJoCo cloth own-way fixture
  (``tests/data/foreign/mujoco_cloth_own``) with ``[solver] kind = "fast_mass_spring"`` and ``[ground]
  height = 0`` (the fixture itself uses ForceSolver and no ground; its cloth hangs above y = 0.3, so the
  ground is declared but not touched: the fallback's cost without the contact work); the CMA-ES stage's
  CPU seconds (its timer, and the gradient stage's, read through ``time.process_time``) and the whole
  process's, ``fitted.toml``'s SHA-256 compared.
- ``beam`` (only with ``--only beam``): the 117-particle beam's default fit of ``fit_workers.py``
  (``child_fit(1)``: implicit ForceSolver, replayed graphs), the same figures.

Prints one JSON line per run and the paired before/after ratios (the machine is shared: CPU seconds).

Measured 2026-11-28 on the shared 2-core box (load 2.5-3.5), 3 interleaved rounds, before = 2c31b4f:

- rollout (5 × 120 frames): 2.01 / 2.09 / 2.03 s before, 0.94 / 0.93 / 0.93 s after: 2.14×, 2.25×, 2.19×;
  end states identical.
- fit, CMA-ES stage: 10.88 / 11.32 / 11.34 s before, 6.97 / 7.45 / 5.82 s after: 1.56×, 1.52×, 1.95×
  (whole process 23.5 / 23.6 / 23.2 s → 14.7 / 16.1 / 12.7 s); fitted.toml byte-identical, held-out error
  34.558 mm either way.
- (by hand) a 64² cloth resting flat on the ground, every particle in contact every substep, 40 substeps:
  3.11 ms per frame fused, 4.97 step by step (1.60×), 1.96 fused without a ground; the 64² drape without
  ground 3.9-4.1 ms before and after (no cost to frames without contact).
- (by hand) what is left of the after fit's CMA-ES stage: ``pliant.sim.fingerprint``, which a replayed
  graph computes every frame, takes 3.5 of the fit's 15.2 CPU seconds (88 µs per frame, about what a fused
  169-particle frame of 40 substeps costs); with ``PLIANT_GRAPH=0`` (frames launched directly) the CMA-ES
  stage takes 4.8 / 4.5 s instead of 6.2 / 6.4 s, fitted.toml the same, but the gradient stage, whose taped
  rollouts need the graphs, 10× longer: skipping graphs for forward frames that are one fused launch, or a
  cheaper fingerprint, is the next step.

Measured 2026-11-28, same box (load 2.5-5.6), 3 interleaved rounds, before = fd96e3e, after = one-launch
frames without a graph (``Solver.frame_is_one_launch``) and the memoised fingerprint walk:

- fit, CMA-ES stage: 6.82 / 6.18 / 6.37 s before, 4.58 / 4.42 / 4.37 s after: 1.49×, 1.40×, 1.46× (what
  ``PLIANT_GRAPH=0`` gave); whole process 19.7 / 17.9 / 18.3 → 13.6 / 13.2 / 13.2 s; gradient stage
  1.07 / 0.96 / 0.95 → 1.02 / 0.91 / 0.91 s (its replays take the cheaper fingerprint); fitted.toml
  byte-identical.
- beam, CMA-ES stage: 5.70 / 5.46 / 5.55 s before, 5.15 / 5.32 / 5.17 s after: 1.11×, 1.03×, 1.07× (its
  fingerprint 100 → 50 µs of a ~500 µs frame); whole process 23.8 / 23.2 / 23.2 → 22.0 / 22.2 / 22.4 s;
  gradient stage 5.39 / 5.51 / 5.32 → 5.28 / 5.33 / 5.39 s; fitted.toml byte-identical.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "tests" / "data" / "foreign" / "mujoco_cloth_own"
REPEAT = 5  # rollouts per process in the rollout row (one is 0.2-0.4 s)
ROWS = ["rollout", "fit", "beam"]


def _rollout() -> dict:
    import numpy as np

    import pliant as pl
    from pliant.scene._build import build_scene
    from pliant.scene._load import load_scene

    text = (ROOT / "pliant" / "scenes" / "cloth.toml").read_text()
    text = text.replace('kind = "force"\nintegrator = "SymplecticEuler"', 'kind = "fast_mass_spring"')
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "cloth_fms.toml").write_text(text)
        sc = build_scene(load_scene(Path(tmp) / "cloth_fms.toml"))
    frame = pl.solvers.FrameStep(sc.solver, sc.frame_dt / sc.substeps, sc.substeps)
    s0, s1 = sc.model.state(), sc.model.state()
    control = sc.model.control()
    frame(s0, control, s1)  # compiles (not timed); then from the start, REPEAT times
    t0 = time.process_time()
    for _ in range(REPEAT):
        s0, s1 = sc.model.state(), sc.model.state()
        for _ in range(sc.frames):
            s0, s1 = frame(s0, control, s1)
    cpu = time.process_time() - t0
    x = np.concatenate([s0.particle_q.numpy(), s0.particle_qd.numpy()])
    low = float(x[: sc.model.particle_count, 1].min())
    blocker = getattr(sc.solver, "fused_frame_blocker", "n/a")
    return {"cpu_s": round(cpu, 3), "sha256": hashlib.sha256(x.tobytes()).hexdigest()[:16], "lowest_y": low,
            "frames": sc.frames, "substeps": sc.substeps, "fused_frame_blocker": blocker}  # fmt: skip


def _cpu_stage_timers() -> None:
    """The CMA-ES and gradient stages' timers as CPU time (one process: --workers 1)."""
    import types

    import pliant.fit._cmaes as cmaes
    import pliant.fit._gradient as gradient

    for mod in (cmaes, gradient):
        mod.time = types.SimpleNamespace(perf_counter=time.process_time, process_time=time.process_time)  # type: ignore[assignment]


def _beam() -> dict:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from fit_workers import child_fit

    _cpu_stage_timers()
    row = child_fit(1)
    return {"cpu_s": round(row["cpu_s"], 2), "cmaes_cpu_s": round(row["stage_wall_time"]["cmaes"], 2),
            "stages_s": {k: round(v, 2) for k, v in row["stage_wall_time"].items()},
            "test_mm": round(row["error_test_mm"], 3),
            "fitted_sha256": hashlib.sha256(row["fitted_toml"].encode()).hexdigest()[:16]}  # fmt: skip


def _fit() -> dict:
    from pliant.cli import main

    _cpu_stage_timers()
    # One scene path for every run: fitted.toml names its source, and is then byte for byte comparable.
    scene = Path(tempfile.gettempdir()) / "bench_fused_ground" / "cloth_fms.toml"
    scene.parent.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        text = (FIXTURE.with_suffix(".toml")).read_text()
        text = text.replace('integrator = "SymplecticEuler"', 'kind = "fast_mass_spring"')
        scene.write_text(text + "\n[ground]\nheight = 0.0\n")
        out = Path(tmp) / "out"
        t0 = time.process_time()
        rc = main(["fit", str(scene), str(FIXTURE.with_suffix(".npz")), "--out", str(out), "--no-video", "-q",
                   "--workers", "1"])  # fmt: skip
        cpu = time.process_time() - t0
        rep = json.loads((out / "fit.json").read_text())
        digest = hashlib.sha256((out / "fitted.toml").read_bytes()).hexdigest()[:16]
    return {"rc": rc, "cpu_s": round(cpu, 2), "cmaes_cpu_s": round(rep["stage_wall_time"]["cmaes"], 2),
            "stages_s": {k: round(v, 2) for k, v in rep["stage_wall_time"].items()},
            "test_mm": round(rep["error"]["test"] * 1e3, 3), "fitted_sha256": digest}  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--before", help="the tree before the fused ground (git archive of its parent)")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--only", choices=ROWS, action="append")
    p.add_argument("--child", choices=ROWS, help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.child:
        print(json.dumps({"rollout": _rollout, "fit": _fit, "beam": _beam}[a.child]()), flush=True)
        return
    if not a.before:
        p.error("--before DIR: the tree before the fused ground (see the docstring)")
    trees = {"before": Path(a.before).resolve(), "after": ROOT}
    rows: dict[str, dict[str, list[dict]]] = {}
    for what in a.only or ["rollout", "fit"]:  # beam: only when asked (minutes)
        rows[what] = {"before": [], "after": []}
        for r in range(a.rounds):
            for name in ("before", "after") if r % 2 == 0 else ("after", "before"):
                env = {**os.environ, "PYTHONPATH": str(trees[name])}
                cmd = [sys.executable, str(Path(__file__).resolve()), "--child", what]
                res = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=trees[name])
                line = res.stdout.strip().splitlines()[-1] if res.stdout.strip() else res.stderr[-400:]
                row = {"bench": what, "tree": name, "round": r, "load": round(os.getloadavg()[0], 1)}
                row.update(json.loads(line) if line.startswith("{") else {"error": line})
                print(json.dumps(row), flush=True)
                rows[what][name].append(row)
        key = "cpu_s" if what == "rollout" else "cmaes_cpu_s"
        pairs = [b[key] / f[key] for b, f in zip(rows[what]["before"], rows[what]["after"], strict=True)]
        same = {r.get("sha256", r.get("fitted_sha256")) for t in rows[what].values() for r in t}
        ratios = [round(x, 2) for x in pairs]
        print(f"{what}: {key} before/after per round {ratios}; identical: {len(same) == 1}")
        if what != "rollout":  # the whole process and the gradient stage (CPU seconds too)
            both = list(zip(rows[what]["before"], rows[what]["after"], strict=True))
            for name in ("cpu_s", "gradient"):
                get = (lambda r: r["cpu_s"]) if name == "cpu_s" else (lambda r: r["stages_s"]["gradient"])
                print(f"{what}: {name} before/after per round {[round(get(b) / get(f), 2) for b, f in both]}")


if __name__ == "__main__":
    main()
