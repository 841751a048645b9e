"""The twin's splats: Gaussians at the carved voxel centres trained on the first frame
(:func:`pliant.gaussians.splats_from_particles`, the seed's steps 3–6); voxels whose splat ends transparent
are not part of the object (the visual hull's excess in concavities the masks cannot see into) and go."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..io import Observations

if TYPE_CHECKING:
    from ..gaussians import SplatInit


@dataclass
class TwinSplats:
    """Kept voxel centres and what the splat stage found.

    Attributes:
        particles: [M, 3] the voxel centres kept [m] (on the carving grid).
        init: The :class:`pliant.gaussians.SplatInit` of the stage.
        ply: Where the visual splats were written.
    """

    particles: np.ndarray
    init: SplatInit
    ply: Path

    def __str__(self) -> str:
        i = self.init
        return (
            f"{len(self.particles)} voxels kept ({i.pruned} pruned by opacity), {i.gaussians.count} splats; "
            f"frame-0 PSNR {i.psnr_before:.1f} -> {i.psnr_after:.1f} dB, IoU {i.iou_before:.3f} -> "
            f"{i.iou_after:.3f}"
        )

    def summary(self) -> dict[str, Any]:
        """JSON-ready figures for ``twin.json``."""
        i = self.init
        return {
            "voxels_kept": len(self.particles),
            "pruned": int(i.pruned),
            "splats": int(i.gaussians.count),
            "psnr_db": {"before": i.psnr_before, "particles": i.psnr_particles, "after": i.psnr_after},
            "iou": {"before": i.iou_before, "particles": i.iou_particles, "after": i.iou_after},
            "seconds": i.wall_time,
        }


def train_splats(
    obs: Observations, centres: np.ndarray, spacing: float, ply: Path, *, iterations: int, seed: int
) -> TwinSplats:
    """Train splats at ``centres`` [M, 3] on frame 0 of every camera and write them to ``ply``.

    Args:
        obs: Observations with images, masks and cameras.
        centres: Carved voxel centres [m].
        spacing: Voxel side [m]; the splats' radius is half of it.
        ply: Output PLY path.
        iterations: Adam iterations of each of the two training stages.
        seed: Seed of the random backgrounds.
    """
    from ..gaussians import Camera, save_ply, splats_from_particles

    assert obs.K is not None and obs.world_to_camera is not None and obs.images is not None
    H, W = obs.images.shape[2:4]
    cams = [Camera(obs.K[c], obs.world_to_camera[c], W, H) for c in range(obs.cameras)]
    images = [np.asarray(obs.image(c, 0), dtype=np.float32) for c in range(obs.cameras)]
    masks = [np.asarray(obs.mask(c, 0)) > 0.5 for c in range(obs.cameras)]
    init = splats_from_particles(
        centres,
        cams,
        images,
        masks,
        radius=0.5 * spacing,
        iterations=iterations,
        visual_iterations=iterations,
        seed=seed,
    )
    save_ply(init.gaussians, ply)
    return TwinSplats(np.asarray(centres)[init.kept], init, ply)


__all__ = ["TwinSplats", "train_splats"]
