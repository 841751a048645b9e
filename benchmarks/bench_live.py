"""Live view figures: frames per second of a scene stepped live with a drag in progress, and the latency
from a drag event to the particle positions that follow it.

    taskset -c 1 python benchmarks/bench_live.py              # the 64² cloth and the 10³ soft FEM box
    python benchmarks/bench_live.py --screenshot docs/figures/live_twin.png   # the tutorial's picture

Flat out: the stepping thread of ``pliant view SCENE`` with the pacing off (time scale 100), while the
"mouse" (this script's main thread) moves the grab target on a circle 20 times a second, as viser's
throttled drag events do. Latency: from ``LiveSession.move`` to the end of the first frame that read it.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import pliant as pl
from pliant.live import LiveSession, serve_live

#: The drape of pliant.bench._mass_spring (64 × 64 cells, 1 m, 0.5 kg, E·t = 1000 N/m, two pinned corners) at
#: its symplectic substeps (80 per 1/60 s frame), and README's soft box (0.5 m neo-Hookean cube of 10³ cells,
#: E = 1e5 Pa, 1000 kg/m³) with its fastest row's symplectic Euler at 16 substeps, both float32.
CLOTH = """
[scene]
name = "live_cloth_64"
frame_dt = 0.016666666666666666
substeps = 80
[[objects]]
kind = "cloth"
name = "cloth"
nx = 64
ny = 64
size = 1.0
origin = [-0.5, 1.0, -0.5]
plane = "xz"
mass = 0.5
pin = "top-corners"
[objects.material]
Et = 1000.0
nu = 0.3
[ground]
height = 0.0
[solver]
kind = "force"
integrator = "SymplecticEuler"
damping_rate = 0.5
"""
BOX = """
[scene]
name = "live_box_10"
frame_dt = 0.016666666666666666
substeps = 16
[[objects]]
kind = "soft_box"
name = "box"
model = "fem"
cells = [10, 10, 10]
size = [0.5, 0.5, 0.5]
origin = [0.0, 0.35, 0.0]
density = 1000.0
[objects.material]
E = 1e5
nu = 0.3
law = "neohookean"
[ground]
height = 0.0
friction = 0.5
[solver]
kind = "force"
integrator = "SymplecticEuler"
damping_rate = 0.5
"""
CLOTH_FAST = CLOTH.replace('kind = "force"\nintegrator = "SymplecticEuler"', 'kind = "fast_mass_spring"')
SCENES = {
    "cloth 64x64 (force solver, symplectic Euler, 80 substeps/frame)": CLOTH,
    "cloth 64x64 (FastMassSpring, symplectic, 80 substeps/frame)": CLOTH_FAST,
    "soft box 10^3 cells FEM (force solver, symplectic Euler, 16 substeps/frame)": BOX,
}


def measure(text: str, seconds: float, device: str) -> dict:
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.toml"
        path.write_text(text)
        scene = pl.scene.build_scene(pl.scene.load_scene(str(path)), device=device)
    session = LiveSession(scene)
    v = serve_live(session, port=0, start=False)
    try:
        v.run_frame()  # compile
        x = session.x
        free = np.flatnonzero(session._inv_mass > 0)
        p = int(free[np.argmax(x[free, 1])])
        centre = x[p].astype(float) + [0.0, 0.15, 0.0]
        session.grab(p, centre)
        v.time_scale = 100.0  # flat out: how fast the machine can go
        v.start()
        t0 = time.perf_counter()
        f0 = session.frame
        while time.perf_counter() - t0 < seconds:
            a = 2 * np.pi * (time.perf_counter() - t0) / 2.0
            session.move(centre + 0.1 * np.array([np.cos(a), 0.0, np.sin(a)]))
            time.sleep(0.05)
        frames = session.frame - f0
        wall = time.perf_counter() - t0
    finally:
        v.stop()
    lat = np.array(session.latencies[1:]) * 1e3  # the first is the grab, before the thread started
    return {
        "particles": scene.model.particle_count,
        "substeps": scene.substeps,
        "fps": frames / wall,
        "real_time_factor": frames / wall * scene.frame_dt,
        "latency_ms_median": float(np.median(lat)) if lat.size else None,
        "latency_ms_p90": float(np.percentile(lat, 90)) if lat.size else None,
        "frames": frames,
        "status": v.status,
    }


def screenshot(path: str) -> None:
    """The tutorial's picture: the demo cloth, a free corner grabbed and lifted, in headless Chromium."""
    from pliant.render._viewer import screenshot_page

    session = LiveSession(pl.scene.build_scene(pl.scene.load_scene("cloth"), device="cpu"))
    v = serve_live(session, port=0, start=False)
    try:
        x = session.x
        corner = int(np.argmax(np.where(session._inv_mass > 0, x[:, 0] - x[:, 2], -np.inf)))
        session.grab(corner, x[corner] + [0.1, 0.5, 0.3])
        for _ in range(40):
            v.run_frame()
        v._say()  # the rate line as the running view shows it
        screenshot_page(v.url, path, width=1000, height=640, budget_ms=20000)
    finally:
        v.stop()
    print(f"wrote {path}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=20.0, help="wall time per scene")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--only", help="only the scenes whose label contains this")
    ap.add_argument("--screenshot", help="write the tutorial's screenshot here instead")
    args = ap.parse_args()
    if args.screenshot:
        screenshot(args.screenshot)
        return
    for label, text in SCENES.items():
        if args.only and args.only not in label:
            continue
        print(label, json.dumps(measure(text, args.seconds, args.device)), flush=True)


if __name__ == "__main__":
    main()
