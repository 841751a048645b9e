"""Files: trajectories, checkpoints, observations and camera files (NPZ). Scene files (TOML) are
:mod:`pliant.scene`."""

from ._camera_file import CameraFile, CameraFileError, load_camera_file
from ._npz import available_memory, npz_headers, npz_memory_problem, read_npz
from ._observation_images import to_unit_float
from ._observations import ObservationError, Observations
from ._paths import OutputPathError, check_file_stem, check_out_dir, check_writable_dir, confined
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
    "to_unit_float",
    "OutputPathError",
    "check_file_stem",
    "check_out_dir",
    "check_writable_dir",
    "confined",
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
