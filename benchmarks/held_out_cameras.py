"""The splat corrector seen from cameras it never used: ``pliant run splat_cloth --cameras`` against images of
its "real" twin (stiffness 300 N/m) taken by two held-out cameras, with and without the correction.

The twin is run alone and rendered at 160x120 by two cameras that are not the corrector's ring cameras; the
images (uint8), masks (alpha > 0.5) and times go into a camera file. Then the built-in scene (springs 3x
too soft) runs twice, corrected (as ``pliant run splat_cloth`` does) and without its correction, each
rendered from the file's cameras and scored (``pl.run_scene(..., cameras=)``). Prints one JSON line per
run: per camera the PSNR [dB] and mask IoU over the 46 frames.

Usage: python benchmarks/held_out_cameras.py [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

import pliant as pl
from pliant.scene import build_scene, load_scene

EYES = [(1.4, 1.0, 1.8), (-1.2, 1.2, 1.5)]  # [m], looking at (0, 0.2, 0); not the corrector's ring


def camera_file(path: Path, out: Path) -> Path:
    """Render the real twin from the held-out cameras into the camera file ``path``."""
    cfg = load_scene("splat_cloth", ["objects[0].material.stiffness=300.0"])
    cfg.gaussians.correction = None
    rep = pl.run_scene(cfg, out / "twin", video=False)
    session = pl.gaussians.SplatSession(cfg, build_scene(cfg))
    cams = [pl.gaussians.Camera.look_at(e, (0.0, 0.2, 0.0), fov_y=50.0, width=160, height=120) for e in EYES]
    renders = [[session.render(x, c) for x in rep.trajectory.x] for c in cams]
    rgb = np.stack([np.stack([r.colour.numpy() for r in rs]) for rs in renders])
    alpha = np.stack([np.stack([r.alpha.numpy() for r in rs]) for rs in renders])
    np.savez(
        path,
        K=np.stack([c.K for c in cams]),
        world_to_camera=np.stack([c.world_to_camera for c in cams]),
        images=np.round(rgb * 255).astype(np.uint8),
        masks=alpha > 0.5,
        t=rep.trajectory.t,
    )
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="output folder (default: a temporary one)")
    args = ap.parse_args()
    out = Path(args.out or tempfile.mkdtemp(prefix="pliant-held-out-"))
    cams = camera_file(out / "cams.npz", out)
    for corrected in (True, False):
        cfg = load_scene("splat_cloth")
        if not corrected:
            cfg.gaussians.correction = None
        rep = pl.run_scene(cfg, out / ("corrected" if corrected else "plain"), video=False, cameras=cams)
        row = {
            "run": "corrected" if corrected else "uncorrected",
            "psnr_db": [round(s.psnr, 2) for s in rep.cameras],
            "mask_iou": [round(s.iou, 3) for s in rep.cameras],
            "frames": rep.cameras[0].frames,
        }
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
