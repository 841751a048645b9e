"""Prototype (issue #42 item 4, "one cloth on every core"): the drape's fused CPU frame split over threads,
bit for bit with the one-thread frame. Not in pliant: on the shared 2-core box it is far slower.

Warp's CPU launches release the GIL (``benchmarks/bench_cpu_threads.py``), so T Python threads can each
launch a dim-1 kernel that runs part t of every substep, synchronised by a spin barrier on an int array
(``__atomic`` builtins; Warp's CPU JIT takes no inline asm, so a waiting thread cannot yield):

1. each thread computes the forces of its range of springs into a per-spring buffer (no shared writes);
2. barrier; each thread sums, for its range of particles, the forces of that particle's springs in spring
   order (a CSR of the spring graph sorted by spring index, the endpoint in the low bit: +F for the first
   end, −F for the second), which is exactly the scatter's sum, and updates the particle in place;
3. barrier, next substep.

Measured 2026-11-28 06:34 UTC (load average 4.2-5.3, ``taskset -c 0-1``), frames per second, wall, the
64² / 128² drape, against pliant's fused frame in the same process (two runs): the split on one thread
0.87-0.91× / 0.69-0.73× (the per-spring buffer's extra traffic: 790 kB at 128², more than L2), on two
threads 0.04-0.07× / 0.03-0.19×: with six agents' jobs on two cores a thread waits at each barrier (2 per
substep, 160-320 per frame) for its partner's next time slice; process CPU over wall 0.47-0.53. Both bit
for bit with the step-by-step frame.
Worth retrying on a machine with idle cores, with a yielding barrier (futex) and a split that keeps the
scatter's single pass (for instance colour-free particle blocks whose springs a thread owns).

    taskset -c 0-1 .venv/bin/python benchmarks/bench_cloth_threads.py 64 128
"""

from __future__ import annotations

import statistics
import sys
import threading
import time
from typing import Any

import numpy as np
import warp as wp

_CPP = """
    typedef decltype(dt) T;
    const int n = x_b.shape[0];
    const int springs = spring_pairs.shape[0];
    const auto* __restrict__ pairs = spring_pairs.data;
    const auto* __restrict__ prm = spring_param.data;
    const auto* __restrict__ inv_mass = particle_inv_mass.data;
    const auto* __restrict__ fe = f_ext.data;
    const int* __restrict__ off = row_offsets.data;
    const int* __restrict__ ent = row_entries.data;
    auto* __restrict__ fsp = f_spring.data;
    auto* __restrict__ fs = f_springs.data;
    auto* __restrict__ xa = x_a.data;
    auto* __restrict__ va = v_a.data;
    auto* __restrict__ xb = x_b.data;
    auto* __restrict__ vb = v_b.data;
    int* bar = barrier.data;
    const int p0 = (int)((long long)n * part / parts), p1 = (int)((long long)n * (part + 1) / parts);
    const int s0 = (int)((long long)springs * part / parts);
    const int s1 = (int)((long long)springs * (part + 1) / parts);
    auto sync = [&]() {
        if (parts == 1) return;
        const int gen = __atomic_load_n(&bar[1], __ATOMIC_ACQUIRE);
        if (__atomic_add_fetch(&bar[0], 1, __ATOMIC_ACQ_REL) == parts) {
            __atomic_store_n(&bar[0], 0, __ATOMIC_RELAXED);
            __atomic_store_n(&bar[1], gen + 1, __ATOMIC_RELEASE);
        } else {
            while (__atomic_load_n(&bar[1], __ATOMIC_ACQUIRE) == gen) {
                __builtin_ia32_pause();
            }
        }
    };
    for (int i = p0; i < p1; ++i) { xb[i] = xa[i]; vb[i] = va[i]; }
    sync();
    for (int k = 0; k < substeps; ++k) {
        for (int s = s0; s < s1; ++s) {
            const auto d = wp::sub(xb[pairs[s].c[0]], xb[pairs[s].c[1]]);
            const T l = wp::length(d);
            auto g = wp::mul(d, T(0.0));
            if (l > T(0.0)) g = wp::mul(d, wp::div(wp::mul(prm[s].c[1], wp::sub(l, prm[s].c[0])), l));
            fsp[s] = wp::neg(g);
        }
        sync();
        for (int i = p0; i < p1; ++i) {
            auto acc = fs[i];
            for (int e = off[i]; e < off[i + 1]; ++e) {
                const int q = ent[e];
                acc = (q & 1) ? wp::sub(acc, fsp[q >> 1]) : wp::add(acc, fsp[q >> 1]);
            }
            const auto f = wp::add(acc, fe[i]);
            fs[i] = wp::mul(f, T(0.0));
            const T w = inv_mass[i];
            auto v1 = wp::mul(delta, wp::add(vb[i], wp::mul(dt, wp::add(gravity, wp::mul(w, f)))));
            if (w == T(0.0)) v1 = vb[i];
            xb[i] = wp::add(xb[i], wp::mul(dt, v1));
            vb[i] = v1;
        }
        sync();
    }
    if (substeps % 2 == 0) for (int i = p0; i < p1; ++i) { xa[i] = xb[i]; va[i] = vb[i]; }
"""


@wp.func_native(_CPP)
def _part_cpp(
    part: int,
    parts: int,
    spring_pairs: wp.array(dtype=wp.vec2i),
    spring_param: wp.array(dtype=Any),
    particle_inv_mass: wp.array(dtype=Any),
    gravity: Any,
    f_ext: wp.array(dtype=Any),
    substeps: int,
    dt: Any,
    delta: Any,
    row_offsets: wp.array(dtype=wp.int32),
    row_entries: wp.array(dtype=wp.int32),
    f_spring: wp.array(dtype=Any),
    f_springs: wp.array(dtype=Any),
    barrier: wp.array(dtype=wp.int32),
    x_a: wp.array(dtype=Any),
    v_a: wp.array(dtype=Any),
    x_b: wp.array(dtype=Any),
    v_b: wp.array(dtype=Any),
): ...


@wp.kernel
def _part_kernel(
    part: int,
    parts: int,
    spring_pairs: wp.array(dtype=wp.vec2i),
    spring_param: wp.array(dtype=Any),
    particle_inv_mass: wp.array(dtype=Any),
    gravity: Any,
    f_ext: wp.array(dtype=Any),
    substeps: int,
    dt: Any,
    delta: Any,
    row_offsets: wp.array(dtype=wp.int32),
    row_entries: wp.array(dtype=wp.int32),
    f_spring: wp.array(dtype=Any),
    f_springs: wp.array(dtype=Any),
    barrier: wp.array(dtype=wp.int32),
    x_a: wp.array(dtype=Any),
    v_a: wp.array(dtype=Any),
    x_b: wp.array(dtype=Any),
    v_b: wp.array(dtype=Any),
):
    _part_cpp(part, parts, spring_pairs, spring_param, particle_inv_mass, gravity, f_ext, substeps, dt, delta,
              row_offsets, row_entries, f_spring, f_springs, barrier, x_a, v_a, x_b, v_b)  # fmt: skip


def rows_by_spring(pairs: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """CSR rows [n + 1] and entries (2 s + end) of the spring graph, each row sorted by spring index."""
    ends = np.concatenate([pairs[:, 0], pairs[:, 1]])
    code = np.concatenate([2 * np.arange(len(pairs)), 2 * np.arange(len(pairs)) + 1])
    order = np.lexsort((code, ends))
    off = np.zeros(n + 1, np.int64)
    np.add.at(off, ends + 1, 1)
    return np.cumsum(off).astype(np.int32), code[order].astype(np.int32)


def main(sizes: list[int]) -> None:
    wp.config.quiet = True
    from pliant.bench._mass_spring import FRAME_DT, SYMPLECTIC_SUBSTEPS, cloth_drape_model
    from pliant.solvers import FastMassSpring, FrameStep

    for n in sizes:
        m = cloth_drape_model(n)
        sub = SYMPLECTIC_SUBSTEPS[n]
        dt = FRAME_DT / sub
        ctl = m.control()
        sol = FastMassSpring(m)
        fr = FrameStep(sol, dt, sub)
        st = [m.state(), m.state()]

        def fused(fr=fr, st=st, ctl=ctl) -> None:
            st[0], st[1] = fr(st[0], ctl, st[1])

        off, ent = rows_by_spring(sol._spring_pairs.numpy(), m.particle_count)
        off, ent = wp.array(off, dtype=wp.int32), wp.array(ent, dtype=wp.int32)
        fsp = wp.zeros(m.spring_count, dtype=m.vec3)
        acc = wp.zeros(m.particle_count, dtype=m.vec3)
        bar = wp.zeros(2, dtype=wp.int32)
        b0, b1 = m.state(), m.state()
        args = [sol._spring_pairs, sol._fused.param, m.particle_inv_mass, m.gravity_vec, ctl.particle_f, sub]
        args += [m.s(dt), m.s(1.0), off, ent, fsp, acc, bar, b0.particle_q, b0.particle_qd, b1.particle_q]
        args += [b1.particle_qd]
        cmds = {
            t: [wp.launch(_part_kernel, 1, [p, t, *args], record_cmd=True) for p in range(t)] for t in (1, 2)
        }

        def split(t: int, cmds=cmds) -> None:
            others = [threading.Thread(target=c.launch) for c in cmds[t][1:]]
            for th in others:
                th.start()
            cmds[t][0].launch()
            for th in others:
                th.join()

        for t in (1, 2):  # bit for bit against the fused frame over 3 frames
            for s in (b0, b1, *st):
                s.assign(m.state())
            acc.zero_()
            for _ in range(3):
                fused()
                split(t)
            same = np.array_equal(st[0].particle_q.numpy(), b0.particle_q.numpy())
            same &= np.array_equal(st[0].particle_qd.numpy(), b0.particle_qd.numpy())
            print(f"{n}² split over {t} thread(s) equals the fused frame bit for bit: {same}")
        wall: dict[str, list[float]] = {"fused": [], "1 thread": [], "2 threads": []}
        runs = {"fused": fused, "1 thread": lambda: split(1), "2 threads": lambda: split(2)}
        for _ in range(8):
            for k, fn in runs.items():
                t0 = time.perf_counter()
                fn()
                wall[k].append(time.perf_counter() - t0)
        fps = {k: round(1 / statistics.median(v), 1) for k, v in wall.items()}
        ratio = {
            k: round(statistics.median(a / b for a, b in zip(wall["fused"], v, strict=True)), 2)
            for k, v in wall.items()
        }
        print(f"{n}²: fps {fps}, over the fused frame {ratio}")


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]] or [64, 128])
