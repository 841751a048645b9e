"""The twin's pictures: the reconstruction drawn over every camera's first image, and the fit's curves."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..io import Observations

#: Most free particles drawn per camera (every k-th beyond it: the picture stays readable; held ones are
#: all drawn).
MAX_DOTS = 800
#: Enlargement of the camera images in ``reconstruction.png`` (small footage stays readable).
SCALE = 3


def draw_reconstruction(path: Path, obs: Observations, particles: np.ndarray, fixed: np.ndarray) -> Path:
    """Every camera's frame-0 image, enlarged, with the twin's particles projected onto it (green; fixed
    ones red) and the mask's outline (white), side by side in one PNG.

    Args:
        path: Output PNG.
        obs: Observations with images, cameras and masks.
        particles: [N, 3] the twin's particles at frame 0 [m].
        fixed: [N] bool, the kinematic ones.
    """
    from PIL import Image, ImageDraw

    from ..geometry import project

    assert obs.K is not None and obs.world_to_camera is not None and obs.images is not None
    tiles = []
    for c in range(obs.cameras):
        img = np.round(np.clip(np.asarray(obs.image(c, 0), dtype=np.float64), 0, 1) * 255).astype(np.uint8)
        mask = obs.mask(c, 0)
        if mask is not None:
            m = np.asarray(mask) > 0.5
            edge = m & ~(np.roll(m, 1, 0) & np.roll(m, -1, 0) & np.roll(m, 1, 1) & np.roll(m, -1, 1))
            img[edge] = 255
        big = Image.fromarray(np.repeat(np.repeat(img, SCALE, 0), SCALE, 1))
        draw = ImageDraw.Draw(big)
        uv, z = project(particles, obs.K[c], obs.world_to_camera[c])
        free = np.flatnonzero(~fixed)
        shown = np.concatenate([free[:: max(1, len(free) // MAX_DOTS)], np.flatnonzero(fixed)])
        order = shown[np.argsort(-z[shown])]  # far first, so near particles are drawn on top
        for i in order[z[order] > 0]:  # one dot per drawn particle: drawing, not a hot path
            x, y = (uv[i] + 0.5) * SCALE
            r, colour = (2.5, (230, 40, 40)) if fixed[i] else (1.5, (40, 220, 60))
            draw.ellipse((x - r, y - r, x + r, y + r), fill=colour)
        draw.text((4, 2), f"camera {c}", fill=(255, 255, 255))
        tiles.append(np.asarray(big))
    Image.fromarray(np.concatenate(tiles, axis=1)).save(path)
    return path


def draw_fit(path: Path, metrics: dict[str, Any], fits: dict[str, Any], n_train: int) -> Path:
    """The per-frame Chamfer distance of the twin and of a twin that does not move, with the train / held-out
    split, beside each model's best training loss: per CMA-ES generation of the coarse stage, then per
    rollout of the fine stage's searches (``fits``: the pipeline's rows, with ``report`` and
    ``scale_history``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.8))
    pf = metrics["per_frame"]
    a.plot(pf["chamfer_mm"], label="twin")
    a.plot(pf["chamfer_still_mm"], "--", label="a twin that does not move")
    a.axvline(n_train - 0.5, color="k", lw=0.8)
    a.text(n_train, a.get_ylim()[1] * 0.95, " held out", va="top")
    a.set_xlabel("frame")
    a.set_ylabel("Chamfer, observed → twin [mm]")
    a.legend()
    for m, row in fits.items():
        hist = row["report"].get("loss_history", {}).get("cmaes") or []
        if hist:
            b.semilogy(np.arange(1, len(hist) + 1), hist, marker=".", label=f"{m}: coarse, CMA-ES")
        fine = [v for _, _, v in row["scale_history"]]
        if fine:
            n = len(hist)
            b.semilogy(
                np.arange(n + 1, n + len(fine) + 1),
                np.minimum.accumulate(fine),
                marker=".",
                label=f"{m}: fine, golden sections",
            )
    b.set_xlabel("CMA-ES generation, then fine rollout")
    b.set_ylabel("best training loss")
    if b.get_legend_handles_labels()[0]:
        b.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


__all__ = ["draw_fit", "draw_reconstruction"]
