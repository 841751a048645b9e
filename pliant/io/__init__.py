"""Files: trajectories and checkpoints (NPZ). Scene files (TOML) are :mod:`pliant.scene`."""

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
    "Trajectory",
    "atomic_savez",
    "load_checkpoint",
    "save_checkpoint",
]
