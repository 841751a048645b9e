"""A twin from calibrated pictures (``pliant twin``): the object's volume carved from masks and depth,
splats trained on the first frame, a physical model on the carved volume, what holds it and the ground found
from the motion, the physical parameters fitted on the first frames, and the prediction of the rest scored.

Typical use::

    obs = pl.io.Observations.load("beam.npz")         # images, K, world_to_camera, masks (+ depth)
    report = pl.twin.build_twin(obs, "out/twin")       # writes out/twin/twin.toml, twin.json, pictures
    scene = pl.scene.build_scene(pl.scene.load_scene("out/twin/twin.toml"))

The steps follow Physically Embodied Gaussians' builder and PhysTwin's processing (``docs/twin.md``).
"""

from ._detect import FixedRegions, Ground, detect_fixed, detect_ground, surface_motion
from ._evaluate import chamfer_per_frame, evaluate
from ._pipeline import TWIN_MODELS, TwinError, TwinOptions, build_twin, check_observations

__all__ = [
    "TWIN_MODELS",
    "FixedRegions",
    "Ground",
    "TwinError",
    "TwinOptions",
    "build_twin",
    "chamfer_per_frame",
    "check_observations",
    "detect_fixed",
    "detect_ground",
    "evaluate",
    "surface_motion",
]
