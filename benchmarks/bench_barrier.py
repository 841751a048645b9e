"""Barrier contact at Δt = 0.1 s (pl.energies.BarrierContact): one JSON line per scene, on one CPU core.

Scenes, backward Euler with one step per frame of 0.1 s, float32:
  cloth_ground  a 16 × 16 cloth dropped from 0.3 m onto the ground (d̂ = 2 mm, self-contact on);
  two_cloths    a 12 × 12 cloth dropped onto another lying on the ground (d̂ = 2 mm, self-contact on);
  box_sphere    a 4 × 4 × 4-cell FEM box (E = 20 kPa) thrown at 3 m/s into a 0.3 m sphere (d̂ = 2 mm).

Each line: the smallest gap over all frames (ground height, sphere distance) [m], frames that intersect by
ipctk.has_intersections (the IPC Toolkit, an independent check), Newton iterations per step (mean, max),
steps that converged, and ms per step (mean over the steps after the first, which compiles kernels).

Usage:
    python benchmarks/bench_barrier.py [--frames 20]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one CPU core; must precede the NumPy import

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402


def _scene(name: str):
    import pliant as pl

    E = pl.energies
    if name == "box_sphere":
        cols = pl.collision.Colliders()
        cols.add_sphere((0.0, 0.0, 0.0), 0.3)
        b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
        b.add_soft_box(
            cells=(4, 4, 4), size=(0.2, 0.2, 0.2), origin=(-0.5, 0.05, 0.0), density=500.0, E=2e4, nu=0.3,
            velocity=(3.0, 0.0, 0.0),
        )  # fmt: skip
        model = b.finalize(device="cpu", dtype="float32")
        bar = E.BarrierContact(dhat=2e-3, ground=False, colliders=cols)
        terms = [E.NeoHookean(), bar]

        def gap(x):
            return float((np.linalg.norm(x, axis=1) - 0.3).min())

        return model, terms, gap, None
    b = pl.ModelBuilder()
    if name == "cloth_ground":
        b.add_cloth_grid(nx=16, ny=16, size=0.5, mass=0.1, stiffness=200.0, origin=(0.0, 0.3, 0.0))
    else:
        b.add_cloth_grid(nx=12, ny=12, size=0.4, mass=0.05, stiffness=100.0, origin=(0.0, 0.0, 0.0))
        b.add_cloth_grid(
            nx=12, ny=12, size=0.3, mass=0.05, stiffness=100.0, origin=(0.03, 0.15, 0.02), name="top"
        )
    b.add_ground(height=-0.01)
    model = b.finalize(device="cpu", dtype="float32")
    terms = [*E.mass_spring(), E.BarrierContact(dhat=2e-3, self_contact=True)]

    def gap(x):
        return float(x[:, 1].min() + 0.01)

    return model, terms, gap, model.tri_indices.numpy().reshape(-1, 3)


def run(name: str, frames: int) -> dict:
    import ipctk

    import pliant as pl

    model, terms, gap, faces = _scene(name)
    solver = pl.solvers.ForceSolver(model, terms, pl.integrators.BackwardEuler())
    if faces is None:  # the box: its surface triangles
        faces = np.asarray(model.render_faces).reshape(-1, 3)
    faces = np.ascontiguousarray(faces.astype(np.int32))
    cm = ipctk.CollisionMesh(model.particle_q_np.astype(np.float64), ipctk.edges(faces), faces)
    s0, s1 = model.state(), model.state()
    its, conv, ms, gaps, bad = [], [], [], [], 0
    for _ in range(frames):
        t0 = time.perf_counter()
        solver.step(s0, s1, None, 0.1)
        ms.append(1e3 * (time.perf_counter() - t0))
        s0, s1 = s1, s0
        st = solver.last_stats
        its.append(st.iterations)
        conv.append(st.converged)
        x = s0.particle_q.numpy().astype(np.float64)
        gaps.append(gap(x))
        bad += int(ipctk.has_intersections(cm, x))
    return {
        "scene": name,
        "particles": model.particle_count,
        "dt": 0.1,
        "frames": frames,
        "min_gap_m": min(gaps),
        "intersecting_frames": bad,
        "newton_mean": float(np.mean(its)),
        "newton_max": int(max(its)),
        "converged": f"{sum(conv)}/{frames}",
        "ms_per_step": float(np.mean(ms[1:])),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--scenes", nargs="+", default=["cloth_ground", "two_cloths", "box_sphere"])
    args = ap.parse_args()
    for name in args.scenes:
        print(json.dumps(run(name, args.frames)), flush=True)


if __name__ == "__main__":
    main()
