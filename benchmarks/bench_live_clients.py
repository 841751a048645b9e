"""The live view under load: the simulation's frame rate with 1 and with 8 browser clients on one ``pliant
view``, and the memory of a long session with drags every few seconds (a soak).

    taskset -c 1 python benchmarks/bench_live_clients.py                   # frame rate, 1 vs 8 clients
    taskset -c 1 python benchmarks/bench_live_clients.py --soak 30         # 30 min, a drag every 3 s

The server (this process: the stepping thread and viser's event loop) runs where ``taskset`` puts it; the
clients are scripted tabs (:mod:`pliant.live._probe`: they report a camera and receive every scene update,
as a page does, without drawing) in a child process, so their decoding does not count against the
server's core. Frame rates are measured flat out (time scale 100: the pacing never waits) and at the
scene's real time, over ``--seconds`` after the clients have connected; runs alternate 1 and 8 clients
``--repeat`` times (the machine is shared: the median of the pairs is the figure). Loopback only.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

import pliant as pl
from pliant.live import LiveSession, serve_live

CLIENTS = """
import asyncio, sys
from pliant.live._probe import probes
r = asyncio.run(probes(sys.argv[1], int(sys.argv[2]), float(sys.argv[3])))
mb = sum(x.bytes for x in r) / 1e6
bad = [x.closed for x in r if x.closed is not None]
n = sum(x.messages for x in r)
print(f"  clients: {len(r)} received {n} messages, {mb:.1f} MB, closed {bad}", flush=True)
"""
SOAK_CLIENT = """
import asyncio, json, sys
from pliant.live._probe import drag_script, probe
url, node, seconds, every = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
start, up = json.loads(sys.argv[5])
asyncio.run(probe(url, seconds, drag_script(node, start, up, seconds, every)))
"""


def _rss_mib() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def _spawn(code: str, *args: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([os.getcwd(), os.environ.get("PYTHONPATH", "")])}
    cpu = os.environ.get("PLIANT_BENCH_CLIENT_CPUS")  # keep the clients off the server's core
    cmd = [sys.executable, "-c", code, *args]
    if cpu:
        cmd = ["taskset", "-c", cpu, *cmd]
    return subprocess.Popen(cmd, env=env)


def frame_rate(v, clients: int, seconds: float, warmup: float = 2.0) -> float:
    """Frames per wall second the stepping thread reaches with ``clients`` scripted tabs connected."""
    proc = _spawn(CLIENTS, v.url, str(clients), str(seconds + warmup + 2.0)) if clients else None
    try:
        t_end = time.perf_counter() + warmup
        while time.perf_counter() < t_end:
            time.sleep(0.05)
        f0, t0 = v.session.frame, time.perf_counter()
        time.sleep(seconds)
        f1, t1 = v.session.frame, time.perf_counter()
    finally:
        if proc is not None:
            proc.wait(timeout=seconds + warmup + 60)
    return (f1 - f0) / (t1 - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="rope", help="a built-in scene (default rope, as `pliant view rope`)")
    ap.add_argument("--clients", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=8.0, help="measuring window per run [s]")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--soak", type=float, default=0.0, help="instead: a soak of this many minutes")
    ap.add_argument("--every", type=float, default=3.0, help="soak: seconds between drags")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args()

    scene = pl.scene.build_scene(pl.scene.load_scene(args.scene), device="cpu")
    scene.prebuild_kernels()
    session = LiveSession(scene)
    v = serve_live(session, port=0, start=False)
    out: dict = {
        "scene": args.scene,
        "particles": scene.model.particle_count,
        "cpus": len(os.sched_getaffinity(0)),
    }
    try:
        for _ in range(20):  # compile and warm
            v.run_frame()
        if args.soak > 0:
            out["soak"] = soak(v, args.soak * 60.0, args.every)
        else:
            for label, scale in (("flat out", 100.0), ("real time", 1.0)):
                v.time_scale = scale
                v.start()
                runs = []
                for _ in range(args.repeat):
                    one = frame_rate(v, 1, args.seconds)
                    many = frame_rate(v, args.clients, args.seconds)
                    runs.append((one, many))
                    print(
                        f"{label}: 1 client {one:.1f} frames/s, {args.clients} clients {many:.1f}", flush=True
                    )
                ratios = [m / o for o, m in runs]
                out[label] = {"runs": runs, "median_ratio": float(np.median(ratios))}
                print(
                    f"{label}: {args.clients} clients / 1 = {np.median(ratios):.3f} (median of {len(runs)})"
                )
    finally:
        v.stop()
    print(json.dumps(out, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


def soak(v, seconds: float, every: float) -> dict:
    """Step at real time for ``seconds`` with one tab dragging the object every ``every`` s and two more
    watching; the process's resident memory every 10 s."""
    v.time_scale = 1.0
    v.start()
    node, kind = next((n, k) for n, k in v.nodes.items() if k in ("mesh", "spheres"))
    handle, part = next((h, p) for h, p in v._handles if h.name == node)
    free = np.flatnonzero(v.session._inv_mass[part.start : part.start + part.count] > 0)
    p = part.start + int(free[len(free) // 2])
    start = v.session.x[p].astype(float).tolist()
    up = (v.session.x[p] + [0.0, 0.2, 0.1]).astype(float).tolist()
    procs = [_spawn(SOAK_CLIENT, v.url, node, str(seconds), str(every), json.dumps([start, up]))]
    procs += [_spawn(CLIENTS, v.url, "2", str(seconds))]
    t0 = time.perf_counter()
    samples = []
    try:
        while (t := time.perf_counter() - t0) < seconds + 1.0:
            samples.append((round(t, 1), round(_rss_mib(), 1), v.session.frame, len(v.session.latencies)))
            print(f"t={t:7.1f} s  rss={samples[-1][1]:.1f} MiB  frame={samples[-1][2]}", flush=True)
            time.sleep(min(10.0, max(seconds + 1.0 - t, 0.01)))
    finally:
        for pr in procs:
            pr.wait(timeout=120)
    rss = np.array([s[1] for s in samples])
    base = rss[min(3, len(rss) - 1)]  # after the clients connected and the first drags compiled
    return {
        "samples": samples,
        "rss_start_mib": float(base),
        "rss_end_mib": float(rss[-1]),
        "growth": float(rss[-1] / base - 1.0),
    }


if __name__ == "__main__":
    main()
