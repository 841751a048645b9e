"""Files: trajectories, checkpoints, observations and camera files (NPZ). Scene files (TOML) are
:mod:`pliant.scene`."""

from ._camera_file import CameraFile, CameraFileError, load_camera_file
from ._npz import available_memory, npz_headers, npz_memory_problem, read_npz
from ._observations import ObservationError, Observations
from ._trajectory import (
    CheckpointError,
    CheckpointSpec,
    Trajectory,
    atomic_output,
    atomic_savez,
    atomic_write_text,
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
    "atomic_output",
    "atomic_savez",
    "load_camera_file",
    "atomic_write_text",
    "available_memory",
    "load_checkpoint",
    "npz_headers",
    "npz_memory_problem",
    "read_npz",
    "save_checkpoint",
]
