"""Files: trajectories, checkpoints and observations (NPZ). Scene files (TOML) are :mod:`pliant.scene`."""

from ._npz import available_memory, npz_headers, npz_memory_problem
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
    "CheckpointError",
    "CheckpointSpec",
    "ObservationError",
    "Observations",
    "Trajectory",
    "atomic_output",
    "atomic_savez",
    "atomic_write_text",
    "available_memory",
    "load_checkpoint",
    "npz_headers",
    "npz_memory_problem",
    "save_checkpoint",
]
