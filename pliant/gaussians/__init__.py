"""3D Gaussian splats: a differentiable rasteriser in Warp (CPU and CUDA), PLY files, and bindings that move
Gaussians with simulated particles.

Typical use::

    import pliant as pl
    g = pl.gaussians.load_ply("object.ply")
    cam = pl.gaussians.Camera(K, world_to_camera, width=640, height=480)
    colour, alpha, depth = pl.gaussians.render(g, cam, background=(1, 1, 1))
    pl.gaussians.save_ply(g, "copy.ply")

Methods: 3D Gaussian splatting (Kerbl, Kopanas, Leimkühler, Drettakis 2023) and EWA splatting (Zwicker et al.
2002); the implementation here is pliant's own, written from the papers' equations.
"""

from ._appearance import AppearanceResult, fit_splat_appearance
from ._bind import Binding, bind
from ._camera import Camera
from ._correct import VisualCorrector
from ._fit import DEFAULT_LRS, fit_appearance
from ._gaussians import SH_C0, Gaussians, quat_matrices
from ._init import INIT_LRS, SplatInit, separate_particles, splats_from_particles
from ._optim import Adam, iou, photometric_loss, psnr
from ._ply import PlyError, load_ply, save_ply
from ._render import RenderOutput, render
from ._scene import SceneSplats, SplatSceneError, gaussians_section, scene_gaussians, scene_splats
from ._session import RENDERERS, SplatSession, splat_session
from ._surface import GENERATED_BACKGROUND, ring_cameras

__all__ = [
    "GENERATED_BACKGROUND",
    "ring_cameras",
    "quat_matrices",
    "gaussians_section",
    "scene_gaussians",
    "scene_splats",
    "DEFAULT_LRS",
    "INIT_LRS",
    "SH_C0",
    "Adam",
    "AppearanceResult",
    "Binding",
    "Camera",
    "Gaussians",
    "RENDERERS",
    "PlyError",
    "RenderOutput",
    "SceneSplats",
    "SplatInit",
    "SplatSceneError",
    "SplatSession",
    "VisualCorrector",
    "bind",
    "fit_appearance",
    "fit_splat_appearance",
    "iou",
    "load_ply",
    "photometric_loss",
    "psnr",
    "render",
    "save_ply",
    "separate_particles",
    "splats_from_particles",
    "splat_session",
]
