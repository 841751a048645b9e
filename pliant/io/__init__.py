"""Files: trajectories and checkpoints (NPZ), scene files (TOML)."""

from ._scene import (
    Scene,
    SceneConfig,
    SceneError,
    build_scene,
    builtin_scenes,
    integrator_names,
    load_scene,
    make_integrator,
    parse_scene,
)
from ._trajectory import (
    CheckpointError,
    CheckpointSpec,
    Trajectory,
    atomic_savez,
    load_checkpoint,
    save_checkpoint,
)

__all__ = [
    "CheckpointError",
    "CheckpointSpec",
    "Scene",
    "SceneConfig",
    "SceneError",
    "Trajectory",
    "atomic_savez",
    "build_scene",
    "builtin_scenes",
    "integrator_names",
    "load_checkpoint",
    "load_scene",
    "make_integrator",
    "parse_scene",
    "save_checkpoint",
]
