"""Files: trajectories and checkpoints (NPZ), scene files (TOML)."""

from ._trajectory import Trajectory, atomic_savez, load_checkpoint, save_checkpoint

__all__ = ["Trajectory", "atomic_savez", "load_checkpoint", "save_checkpoint"]
