"""pliant's cloth drape in Taichi with the *same* spring network as ``cloth_drape_newton.py``: one JSON line
with the timing and the sag per frame, for the equal-accuracy comparison of ``cloth_side_by_side.py``.

The network (positions, lumped masses, pins, springs with their rest lengths and stiffnesses) comes from the
NPZ pliant writes (``python -m pliant.bench._drape_motion export N FILE``). The step is symplectic Euler on
undamped springs with gravity, float32, as Newton's ``SolverSemiImplicit`` and pliant's
``FastMassSpring(method="symplectic")`` take it: accumulate spring forces (added to both ends), then
v += dt (g + f / m) and x += dt v for the free particles. Taichi runs on its CPU backend with one thread
(``cpu_max_num_threads=1``; the driver also pins the process to one core). ``--launch frame`` runs a frame's
substeps in one kernel (a serial loop around the three passes: the fewest launches Taichi allows);
``--launch substep`` launches one kernel per substep (Taichi's own mass-spring examples). Needs Taichi in
the peers' venv (``pip install taichi``, 1.7.4 here); never imported by pliant.

    /work/peers-venv/bin/python benchmarks/peers/cloth_drape_taichi.py --network /tmp/drape64.npz \\
        --substeps 80
"""

# No `from __future__ import annotations`: Taichi reads its kernels' annotations as types.
import argparse
import json
import resource
import time

import numpy as np

FRAME_DT = 1.0 / 60.0


def main(argv=None) -> dict:  # noqa: ANN001
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--network", required=True, help="NPZ from `python -m pliant.bench._drape_motion export`")
    ap.add_argument("--substeps", type=int, default=80)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--launch", choices=["frame", "substep"], default="frame")
    args = ap.parse_args(argv)

    import taichi as ti

    started = time.perf_counter()
    ti.init(arch=ti.cpu, cpu_max_num_threads=1, default_fp=ti.f32, log_level=ti.WARN)
    d = np.load(args.network)
    x0 = d["x"].astype(np.float32)
    free = d["free"].astype(bool)
    inv_m = np.where(free, 1.0 / np.maximum(d["mass"], 1e-30), 0.0).astype(np.float32)
    springs = d["springs"].astype(np.int32)
    n_p, n_s = len(x0), len(springs)
    x = ti.Vector.field(3, ti.f32, n_p)
    v = ti.Vector.field(3, ti.f32, n_p)
    f = ti.Vector.field(3, ti.f32, n_p)
    w = ti.field(ti.f32, n_p)
    ij = ti.Vector.field(2, ti.i32, n_s)
    rest = ti.field(ti.f32, n_s)
    k = ti.field(ti.f32, n_s)
    w.from_numpy(inv_m)
    ij.from_numpy(springs)
    rest.from_numpy(d["rest"].astype(np.float32))
    k.from_numpy(d["stiffness"].astype(np.float32))
    g = ti.Vector([0.0, -9.81, 0.0])

    @ti.func
    def substep(dt: ti.f32):
        for i in range(n_p):
            f[i] = ti.Vector([0.0, 0.0, 0.0])
        for s in range(n_s):
            a, b = ij[s][0], ij[s][1]
            dx = x[b] - x[a]
            length = dx.norm()
            fs = k[s] * (length - rest[s]) / ti.max(length, 1e-12) * dx
            f[a] += fs
            f[b] -= fs
        for i in range(n_p):
            if w[i] > 0.0:
                v[i] += dt * (g + f[i] * w[i])
                x[i] += dt * v[i]

    @ti.kernel
    def frame_kernel(n_sub: ti.i32, dt: ti.f32):
        ti.loop_config(serialize=True)
        for _ in range(n_sub):
            substep(dt)

    @ti.kernel
    def forces():
        for i in range(n_p):
            f[i] = ti.Vector([0.0, 0.0, 0.0])
        for s in range(n_s):
            a, b = ij[s][0], ij[s][1]
            dx = x[b] - x[a]
            length = dx.norm()
            fs = k[s] * (length - rest[s]) / ti.max(length, 1e-12) * dx
            f[a] += fs
            f[b] -= fs

    @ti.kernel
    def integrate(dt: ti.f32):
        for i in range(n_p):
            if w[i] > 0.0:
                v[i] += dt * (g + f[i] * w[i])
                x[i] += dt * v[i]

    dt = FRAME_DT / args.substeps

    def run_frame() -> None:
        if args.launch == "frame":
            frame_kernel(args.substeps, dt)
        else:
            for _ in range(args.substeps):
                forces()
                integrate(dt)

    def reset() -> None:
        x.from_numpy(x0)
        v.from_numpy(np.zeros_like(x0))

    pinned = ~free

    def sag(q: np.ndarray) -> float:
        return float(q[pinned, 1].mean() - q[:, 1].min())

    # Warm-up: compile (as pliant's and Newton's rows do), then start again from the initial state.
    reset()
    run_frame()
    ti.sync()
    reset()
    compile_s = time.perf_counter() - started
    curve = [sag(x.to_numpy())]
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(args.frames):
        run_frame()
        curve.append(sag(x.to_numpy()))  # one read per frame, as pliant's motion check does
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    row = {
        "engine": f"taichi {'.'.join(map(str, ti.__version__))}",
        "solver": f"symplectic ({args.launch} kernels)",
        "particles": n_p,
        "springs": n_s,
        "frames": args.frames,
        "substeps": args.substeps,
        "wall_s": round(wall, 4),
        "compile_s": round(compile_s, 3),
        "fps": round(args.frames / wall, 3),
        # Frames per second of this process's CPU time: less sensitive to other jobs on a shared core.
        "fps_cpu_time": round(args.frames / max(cpu, 1e-9), 3),
        "peak_mem_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
        "sag_curve": [round(val, 7) for val in curve],
    }
    print(json.dumps(row), flush=True)
    return row


if __name__ == "__main__":
    main()
