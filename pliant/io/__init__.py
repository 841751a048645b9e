"""Files: trajectories, checkpoints, observations and camera files (NPZ). Scene files (TOML) are
:mod:`pliant.scene`."""

from ._camera_file import CameraFile, CameraFileError, load_camera_file
from ._observations import ObservationError, Observations
from ._trajectory import (
    CheckpointError,
    CheckpointSpec,
    Trajectory,
    atomic_savez,
    load_checkpoint,
    save_checkpoint,
)

__all__ = [
    "CameraFile",
    "CameraFileError",
    "CheckpointError",
    "CheckpointSpec",
    "ObservationError",
    "Observations",
    "Trajectory",
    "atomic_savez",
    "load_camera_file",
    "load_checkpoint",
    "save_checkpoint",
]
