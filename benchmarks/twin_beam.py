"""Issue 37's figures: ``pliant twin`` on MuJoCo's footage of a clamped soft beam (4 cameras, 200 × 150 px,
3 s at 30 frames/s; SYNTHETIC footage from another engine's physics, masses and renderer,
``benchmarks/peers/observe_mujoco_beam.py``), judged against MuJoCo's truth with ``tests/twin_truth.py``.

    python benchmarks/twin_beam.py [--variants depth masks] [--json out.jsonl] [--out DIR]

One JSON line per variant (``depth``: masks and depth; ``masks``: the depth dropped):

- ``chamfer_mm``: the twin's particles at frame 0 against the true solid (two-sided, the sum of the one-sided
  means: a 1 cm grid inside scores 4.8 mm); goal ≤ 6 mm;
- ``motion_ratio``: the twin's particles' mean error on the held-out last 30 % of the frames over that of
  the best shape that does not move; goal ≤ 0.6 (a one-frame lag scores 0.39);
- ``wall_s``: the whole command (goal ≤ 600 s on one CPU core: run under ``taskset -c 0``);
- ``heldout_camera``: PSNR [dB] (whole image, over the twin's background colour) and mask IoU of the
  twin's splats in a fifth camera it never saw (``pliant run twin.toml --cameras mujoco_beam_heldout.npz``);
- the twin's own report: its held-out Chamfer to the observed clouds and that of a twin standing still.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from twin_truth import score_twin  # noqa: E402

DATA = ROOT / "tests" / "data" / "foreign"
VIDEO = DATA / "mujoco_beam_video.npz"
HELDOUT = DATA / "mujoco_beam_heldout.npz"


def footage(variant: str, folder: Path) -> Path:
    """The observation file of a variant: the fixture itself, or a copy without depth (``masks``)."""
    if variant == "depth":
        return VIDEO
    with np.load(VIDEO, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if k != "depth"}
    path = folder / "beam_masks_only.npz"
    np.savez(path, **arrays)
    return path


def run(variant: str, out: Path, extra: list[str]) -> dict:
    """Run ``pliant twin`` on a variant into ``out``; its figures as one dict."""
    obs = footage(variant, out.parent)
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "pliant.cli", "twin", str(obs), "--out", str(out), "-q", *extra], check=True
    )
    wall = time.perf_counter() - t0
    rep = json.loads((out / "twin.json").read_text())
    row = {"variant": variant, "wall_s": wall, **score_twin(out)}
    m = rep["metrics"]
    row.update(
        particles=rep["particles"],
        spacing_mm=1e3 * rep["spacing_m"],
        fixed=rep["fixed"]["fixed_particles"],
        ground=rep["ground"]["height"],
        values=rep["models"][rep["model"]]["values"],
        twin_chamfer_mm=m["chamfer_mm"],
        still_chamfer_mm=m["chamfer_still_mm"],
        iou=m["iou"],
        psnr_db=m["psnr_db"],
        steps={s["step"]: round(s["seconds"], 1) for s in rep["steps"]},
    )
    import pliant as pl

    rep_run = pl.run_scene(
        pl.scene.load_scene(out / "twin.toml"), out / "heldout", cameras=HELDOUT, video=False
    )
    row["heldout_camera"] = [{"psnr_db": c.psnr, "iou": c.iou, "frames": c.frames} for c in rep_run.cameras]
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", nargs="+", default=["depth", "masks"], choices=["depth", "masks"])
    ap.add_argument("--json", help="append the rows to this JSONL file")
    ap.add_argument("--out", help="keep the twins here (default: a temporary folder)")
    ap.add_argument("twin_args", nargs="*", help="extra arguments for pliant twin (after --)")
    a = ap.parse_args()
    base = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="twin_beam_"))
    for v in a.variants:
        row = run(v, base / v, a.twin_args)
        line = json.dumps(row, default=float)
        print(line, flush=True)
        if a.json:
            with open(a.json, "a") as f:
                f.write(line + "\n")


if __name__ == "__main__":
    main()
