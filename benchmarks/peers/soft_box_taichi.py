"""pliant's soft box drop (``pliant/bench/_fem.py``) in Taichi: one JSON line like ``soft_box_newton.py``'s,
for ``run_side_by_side.py``.

The same mesh and lumped masses (``_scene.box_tets``, ρV/4), pliant's stable neo-Hookean (Smith 2018:
ψ = μ/2 (I_C − 3) − μ (J − 1) + (λ + μ)/2 (J − 1)², E = 1e5 Pa, ν = 0.3) and pliant's ground: the penalty
force κ m_i max(0, r − y_i) (κ = 1e6 s⁻², r = 5 mm) inside the step, then Coulomb friction (μ = 0.5) for the
penalty's impulse κ d Δt on the tangential velocity, the position shifted by Δt times that change (without
pliant's stick-velocity smoothing). Symplectic Euler, ``--substeps`` per frame, float32 (``--f64``: float64,
for the converged reference), a frame's substeps in one kernel (serial loops around the three passes) on
Taichi's CPU backend with one thread. Needs Taichi in the peers' venv (``pip install taichi``, 1.7.4 here).

    /work/peers-venv/bin/python benchmarks/peers/soft_box_taichi.py --substeps 16
"""

# No `from __future__ import annotations`: Taichi reads its kernels' annotations as types.
import argparse
import json
import time

import numpy as np
from _scene import (
    DENSITY,
    FRAME_DT,
    FRAMES,
    FRICTION,
    GRAVITY,
    LAM,
    MU,
    RADIUS,
    box_tets,
    heights,
    lumped_mass,
    peak_mem_mb,
)

KAPPA = 1.0e6  # pliant's GroundPenalty stiffness [1/s²]


def main(argv=None) -> dict:  # noqa: ANN001
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--substeps", type=int, default=16)
    ap.add_argument("--frames", type=int, default=FRAMES)
    ap.add_argument("--f64", action="store_true")
    args = ap.parse_args(argv)

    import taichi as ti

    t0 = time.perf_counter()
    real = ti.f64 if args.f64 else ti.f32
    npr = np.float64 if args.f64 else np.float32
    ti.init(arch=ti.cpu, cpu_max_num_threads=1, default_fp=real, log_level=ti.WARN)
    points, tets = box_tets(args.n)
    mass = lumped_mass(points, tets, DENSITY)
    p = points[tets]
    dm = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)  # columns
    vol = np.abs(np.linalg.det(dm)) / 6.0
    n_p, n_t = len(points), len(tets)
    x = ti.Vector.field(3, real, n_p)
    v = ti.Vector.field(3, real, n_p)
    f = ti.Vector.field(3, real, n_p)
    m = ti.field(real, n_p)
    tet = ti.Vector.field(4, ti.i32, n_t)
    dm_inv = ti.Matrix.field(3, 3, real, n_t)
    w = ti.field(real, n_t)
    m.from_numpy(mass.astype(npr))
    tet.from_numpy(tets.astype(np.int32))
    dm_inv.from_numpy(np.linalg.inv(dm).astype(npr))
    w.from_numpy(vol.astype(npr))
    mu, lam = MU, LAM

    @ti.kernel
    def frame(n_sub: ti.i32, dt: real):
        ti.loop_config(serialize=True)
        for _ in range(n_sub):
            for i in range(n_p):  # gravity and the ground penalty
                fi = ti.Vector([0.0, -GRAVITY, 0.0], real) * m[i]
                d = RADIUS - x[i][1]
                if d > 0.0:
                    fi[1] += KAPPA * m[i] * d
                f[i] = fi
            for e in range(n_t):  # stable neo-Hookean: P = μ F + (−μ + (λ + μ)(J − 1)) cof(F)
                a, b, c, d = tet[e][0], tet[e][1], tet[e][2], tet[e][3]
                ds = ti.Matrix.cols([x[b] - x[a], x[c] - x[a], x[d] - x[a]])
                fm = ds @ dm_inv[e]
                j = fm.determinant()
                c0 = ti.Vector([fm[0, 0], fm[1, 0], fm[2, 0]])
                c1 = ti.Vector([fm[0, 1], fm[1, 1], fm[2, 1]])
                c2 = ti.Vector([fm[0, 2], fm[1, 2], fm[2, 2]])
                cof = ti.Matrix.cols([c1.cross(c2), c2.cross(c0), c0.cross(c1)])
                pk = mu * fm + (-mu + (lam + mu) * (j - 1.0)) * cof
                h = -w[e] * pk @ dm_inv[e].transpose()
                fb = ti.Vector([h[0, 0], h[1, 0], h[2, 0]])
                fc = ti.Vector([h[0, 1], h[1, 1], h[2, 1]])
                fd = ti.Vector([h[0, 2], h[1, 2], h[2, 2]])
                f[b] += fb
                f[c] += fc
                f[d] += fd
                f[a] -= fb + fc + fd
            for i in range(n_p):  # symplectic Euler, then friction for the penalty's impulse
                vi = v[i] + dt * f[i] / m[i]
                xi = x[i] + dt * vi
                d = RADIUS - xi[1]
                if d > 0.0:
                    speed = ti.sqrt(vi[0] * vi[0] + vi[2] * vi[2])
                    budget = FRICTION * KAPPA * d * dt
                    s = 0.0
                    if speed > budget:
                        s = (speed - budget) / speed
                    xi[0] += dt * (s - 1.0) * vi[0]
                    xi[2] += dt * (s - 1.0) * vi[2]
                    vi[0] *= s
                    vi[2] *= s
                v[i] = vi
                x[i] = xi

    def reset() -> None:
        x.from_numpy(points.astype(npr))
        v.from_numpy(np.zeros_like(points, dtype=npr))

    dt = FRAME_DT / args.substeps
    reset()
    frame(1, dt)  # warm-up: compilation
    ti.sync()
    reset()
    compile_s = time.perf_counter() - t0
    com = []
    t0 = time.perf_counter()
    for _ in range(args.frames):
        frame(args.substeps, dt)
        com.append(float(mass @ x.to_numpy()[:, 1].astype(np.float64) / mass.sum()))  # one read per frame
    wall = time.perf_counter() - t0
    sim_s = args.frames * FRAME_DT
    row = {
        "benchmark": f"taichi_soft_box_drop_{args.n}_symplectic",
        "scene": f"soft_box_drop_{args.n}x{args.n}x{args.n}",
        "peer": f"taichi {'.'.join(map(str, ti.__version__))}",
        "solver": "symplectic Euler, ground penalty + Coulomb friction, 1 kernel/frame",
        "material": "stable neo-Hookean (Smith 2018), pliant's form",
        "device": "cpu",
        "dtype": "float64" if args.f64 else "float32",
        "particles": n_p,
        "elements": n_t,
        "frames": args.frames,
        "substeps": args.substeps,
        "dt": dt,
        "wall_s": round(wall, 4),
        "wall_per_sim_s": round(wall / sim_s, 4),
        "compile_s": round(compile_s, 3),
        "time_per_step_s": float(f"{wall / (args.frames * args.substeps):.4g}"),
        "peak_mem_mb": peak_mem_mb(),
        **heights(x.to_numpy(), v.to_numpy(), mass),
        "com_curve": com,
    }
    print(json.dumps(row), flush=True)
    return row


if __name__ == "__main__":
    main()
