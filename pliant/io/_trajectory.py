"""Trajectory (NPZ) and checkpoint files: written atomically, loaded without pickle."""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


def atomic_savez(path: str | os.PathLike, **arrays: Any) -> Path:
    """Write an NPZ through a temporary file and ``os.replace`` so a crash never leaves half a file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".tmp.npz", dir=path.parent)
    os.close(fd)
    try:
        np.savez(tmp, **arrays)
        # mkstemp creates 0600 files; give the output the permissions a plain open() would.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def _load_npz(path: str | os.PathLike, required: tuple[str, ...], what: str) -> dict[str, np.ndarray]:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{what} file not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as exc:  # a truncated or foreign file: say which and why
        raise ValueError(f"{path}: not a readable {what} NPZ ({exc})") from exc
    missing = [k for k in required if k not in data]
    if missing:
        raise ValueError(f"{path}: {what} is missing the fields {missing}")
    return data


@dataclass
class Trajectory:
    """Recorded motion: ``x`` [T, N, 3] positions [m] at times ``t`` [T] [s], plus topology and metadata."""

    x: np.ndarray
    t: np.ndarray
    v: np.ndarray | None = None
    faces: np.ndarray | None = None
    tets: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    @property
    def frame_count(self) -> int:
        """Number of recorded frames T."""
        return int(self.x.shape[0])

    def save(self, path: str | os.PathLike) -> Path:
        """Write the NPZ described in DESIGN.md (atomically)."""
        arrays: dict[str, Any] = {"x": self.x, "t": self.t, "meta": np.array(json.dumps(self.meta))}
        for k in ("v", "faces", "tets"):
            val = getattr(self, k)
            if val is not None:
                arrays[k] = val
        return atomic_savez(path, **arrays)

    @classmethod
    def load(cls, path: str | os.PathLike) -> Trajectory:
        """Read a trajectory NPZ (``allow_pickle=False``)."""
        d = _load_npz(path, ("x", "t"), "trajectory")
        x = d["x"]
        if x.ndim != 3 or x.shape[2] != 3 or d["t"].shape != (x.shape[0],):
            raise ValueError(f"{path}: x must be [T, N, 3] and t [T]; got {x.shape} and {d['t'].shape}")
        meta = json.loads(str(d["meta"])) if "meta" in d else {}
        return cls(x=x, t=d["t"], v=d.get("v"), faces=d.get("faces"), tets=d.get("tets"), meta=meta)

    def concatenate(self, other: Trajectory) -> Trajectory:
        """This trajectory followed by ``other`` (used when a resumed run appends to a checkpoint)."""
        v = None if self.v is None or other.v is None else np.concatenate([self.v, other.v])
        return Trajectory(
            np.concatenate([self.x, other.x]),
            np.concatenate([self.t, other.t]),
            v,
            self.faces,
            self.tets,
            self.meta,
        )


def save_checkpoint(
    path: str | os.PathLike,
    *,
    frame: int,
    time: float,
    x: np.ndarray,
    v: np.ndarray,
    params: dict[str, np.ndarray],
    traj_x: np.ndarray,
    traj_t: np.ndarray,
    traj_v: np.ndarray | None,
    meta: dict,
) -> Path:
    """Write state, model parameters and the trajectory so far, atomically."""
    arrays: dict[str, Any] = {
        "frame": np.array(frame),
        "time": np.array(time),
        "x": x,
        "v": v,
        "traj_x": traj_x,
        "traj_t": traj_t,
        "meta": np.array(json.dumps(meta)),
    }
    if traj_v is not None:
        arrays["traj_v"] = traj_v
    for k, a in params.items():
        arrays[f"param_{k}"] = a
    return atomic_savez(path, **arrays)


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Read a checkpoint written by :func:`save_checkpoint`."""
    d = _load_npz(path, ("frame", "time", "x", "v", "traj_x", "traj_t"), "checkpoint")
    out: dict[str, Any] = {
        "frame": int(d["frame"]),
        "time": float(d["time"]),
        "x": d["x"],
        "v": d["v"],
        "traj_x": d["traj_x"],
        "traj_t": d["traj_t"],
        "traj_v": d.get("traj_v"),
        "meta": json.loads(str(d["meta"])) if "meta" in d else {},
        "params": {k[len("param_") :]: a for k, a in d.items() if k.startswith("param_")},
    }
    return out
