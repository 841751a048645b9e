"""Trajectory (NPZ) and checkpoint files: written atomically, loaded without pickle."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._npz import read_npz


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path beside ``path`` (same suffix, so writers that go by it pick the format) to write
    into; on a clean exit it replaces ``path`` with ``os.replace``, so a crash or a kill never leaves half a
    file at ``path`` (the old one, or none, stays). On an error the temporary file is removed.

    Args:
        path: The output file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        # mkstemp creates 0600 files; give the output the permissions a plain open() would.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def atomic_savez(path: str | os.PathLike, **arrays: Any) -> Path:
    """Write an NPZ through a temporary file and ``os.replace`` so a crash never leaves half a file."""
    with atomic_output(path) as tmp, open(tmp, "wb") as f:  # a file object: np.savez adds no suffix
        np.savez(f, **arrays)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` through :func:`atomic_output`."""
    with atomic_output(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


#: Default bound on the uncompressed size of an NPZ pliant reads [bytes] (a compressed member could
#: otherwise expand to any size: the check reads the ZIP directory, before anything is allocated).
MAX_NPZ_BYTES = 8 << 30


def _load_npz(
    path: str | os.PathLike, required: tuple[str, ...], what: str, max_bytes: int = MAX_NPZ_BYTES
) -> dict[str, np.ndarray]:
    import zipfile

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{what} file not found: {path}")
    try:
        with zipfile.ZipFile(path) as zf:
            size = sum(info.file_size for info in zf.infolist())
    except Exception:
        size = 0  # not a ZIP: np.load below says what it is
    if size > max_bytes:
        raise ValueError(
            f"{path}: the {what} NPZ expands to {size / 2**30:.3g} GiB, more than the "
            f"{max_bytes / 2**30:.3g} GiB it can need; it is not a file pliant wrote for this run"
        )
    data = read_npz(path, what)
    missing = [k for k in required if k not in data]
    if missing:
        raise ValueError(f"{path}: {what} is missing the fields {missing}")
    return data


@dataclass
class Trajectory:
    """Recorded motion: ``x`` [T, N, 3] positions [m] at times ``t`` [s] (shape [T]), topology, metadata."""

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

    @property
    def frame_dt(self) -> float | None:
        """The frame duration [s] recorded in ``meta``: its ``frame_dt``, or ``dt`` in files written before
        that key (where ``dt`` named the frame, not a solver step); None when neither is there."""
        value = self.meta.get("frame_dt", self.meta.get("dt"))
        return None if value is None else float(value)

    @property
    def world_count(self) -> int:
        """Number of worlds recorded together (1 unless the model was replicated)."""
        return int(self.meta.get("worlds", {}).get("count", 1))

    def world(self, w: int) -> Trajectory:
        """World ``w``'s particles as a trajectory of their own: faces and tets of that world re-indexed,
        the world's objects in ``meta`` (starts re-based), ``meta["world"] = w``.

        Raises:
            ValueError: ``w`` out of range.
        """
        n = self.world_count
        if isinstance(w, bool) or not isinstance(w, (int, np.integer)) or not 0 <= w < n:
            raise ValueError(f"world index {w!r} out of range [0, {n}) (this trajectory has {n} worlds)")
        if n == 1:
            return self
        off = self.meta["worlds"]["particle_offsets"]
        lo, hi = int(off[w]), int(off[w + 1])

        def local(cells: np.ndarray | None) -> np.ndarray | None:
            if cells is None:
                return None
            keep = np.all((cells >= lo) & (cells < hi), axis=1)
            return (cells[keep] - lo).astype(cells.dtype)

        meta = {k: v for k, v in self.meta.items() if k != "worlds"}
        meta["objects"] = [
            {**o, "start": int(o["start"]) - lo}
            for o in self.meta.get("objects", [])
            if o.get("world", 0) == w
        ]
        meta["world"] = int(w)
        diverged = self.meta["worlds"].get("diverged", {}).get(str(w))
        if diverged is not None:
            meta["diverged"] = diverged
        v = None if self.v is None else self.v[:, lo:hi]
        return Trajectory(self.x[:, lo:hi], self.t, v, local(self.faces), local(self.tets), meta)

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


class CheckpointError(ValueError):
    """A checkpoint file that cannot be resumed from; the message names the file, the key and the fix."""


#: Checkpoint keys besides ``param_<name>`` (model parameters) and ``solver_<name>`` (solver state).
CHECKPOINT_KEYS = ("frame", "time", "x", "v", "traj_x", "traj_t", "traj_v", "meta")


@dataclass
class CheckpointSpec:
    """What a checkpoint must match to be resumed by a given simulator.

    Attributes:
        particle_count: N: ``x``, ``v`` are [N, 3], ``traj_x`` [frame + 1, N, 3].
        dtype: NumPy dtype name of the model's positions ("float32" or "float64").
        params: allowed ``param_<name>`` keys and the shape each must have (the model's arrays).
        max_frame: the largest allowed ``frame`` (the frames the run asks for); None: no bound.
    """

    particle_count: int
    dtype: str
    params: dict[str, tuple[int, ...]] = field(default_factory=dict)
    max_frame: int | None = None


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
    solver_state: dict[str, np.ndarray] | None = None,
) -> Path:
    """Write state, model parameters, solver state and the trajectory so far, atomically.

    ``solver_state`` (from ``Solver.checkpoint_state()``) is stored under ``solver_<name>`` keys.
    """
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
    for k, a in (solver_state or {}).items():
        arrays[f"solver_{k}"] = np.asarray(a)
    return atomic_savez(path, **arrays)


def _float_array(
    path: Path, key: str, a: np.ndarray, shape: tuple[int, ...], dtype: str | None
) -> np.ndarray:
    """``a`` checked for exact shape, a float dtype (``dtype`` when given) and finite values."""
    if a.shape != shape:
        raise CheckpointError(
            f"{path}: {key}: shape {a.shape}, expected {shape}; resume with the scene (and settings) "
            "that wrote the checkpoint, or delete it to start over"
        )
    if a.dtype.kind != "f" or (dtype is not None and a.dtype != np.dtype(dtype)):
        raise CheckpointError(
            f"{path}: {key}: dtype {a.dtype}, expected {dtype or 'a float type'}; resume with the dtype "
            "that wrote the checkpoint, or delete it to start over"
        )
    if not np.all(np.isfinite(a)):
        raise CheckpointError(f"{path}: {key}: contains NaN or inf; the file is corrupt, delete it")
    return a


def _scalar(path: Path, key: str, a: np.ndarray, kind: str) -> float:
    if a.shape != () or a.dtype.kind not in kind:
        raise CheckpointError(f"{path}: {key}: expected a scalar number, got {a.dtype} {a.shape}")
    value = a.item()
    if not np.isfinite(value):
        raise CheckpointError(f"{path}: {key}: {value} is not finite; the file is corrupt, delete it")
    return value


def load_checkpoint(path: str | os.PathLike, spec: CheckpointSpec | None = None) -> dict[str, Any]:
    """Read and validate a checkpoint written by :func:`save_checkpoint`.

    Args:
        path: the checkpoint NPZ.
        spec: what the resuming simulator expects (particle count, dtype, parameter arrays, frame bound);
            without it only the file's own consistency is checked.

    Returns:
        A dict with frame, time, x, v, traj_x, traj_t, traj_v, meta, params (name → array) and
        solver_state (name → array, the ``solver_`` prefix removed).

    Raises:
        FileNotFoundError: no such file.
        CheckpointError: unreadable file, unknown or missing keys, wrong shapes or dtypes, non-finite
            values, a frame out of range; the message names the file and the key.
    """
    path = Path(path)
    budget = MAX_NPZ_BYTES
    if spec is not None and spec.max_frame is not None:
        # traj_x and traj_v in float64, x and v, the parameters and solver state: generously bounded.
        budget = 64 * (spec.max_frame + 2) * spec.particle_count * 3 * 8 + (256 << 20)
    try:
        d = _load_npz(path, ("frame", "time", "x", "v", "traj_x", "traj_t"), "checkpoint", budget)
    except FileNotFoundError:
        raise
    except ValueError as exc:
        raise CheckpointError(f"{exc}; delete the checkpoint to start over") from None
    params_allowed = None if spec is None else spec.params
    for k in d:
        if k in CHECKPOINT_KEYS or k.startswith("solver_"):
            continue
        name = k[len("param_") :] if k.startswith("param_") else None
        if name is not None and (params_allowed is None or name in params_allowed):
            continue
        known = sorted(params_allowed or ())
        raise CheckpointError(
            f"{path}: unknown key {k!r}"
            + (f" (model parameters a checkpoint may hold: {', '.join(known)})" if name and known else "")
            + "; this file was not written by pliant's Simulator, delete it to start over"
        )
    frame_f = _scalar(path, "frame", d["frame"], "iu")
    frame = int(frame_f)
    if frame < 0 or (spec is not None and spec.max_frame is not None and frame > spec.max_frame):
        bound = ""
        if spec is not None and spec.max_frame is not None:
            bound = f", at most the {spec.max_frame} frames asked for"
        raise CheckpointError(
            f"{path}: frame: {frame} is out of range (expected >= 0{bound}); "
            "ask for more frames, or delete the checkpoint to start over"
        )
    time = float(_scalar(path, "time", d["time"], "f"))
    n = spec.particle_count if spec is not None else (d["x"].shape[0] if d["x"].ndim == 2 else -1)
    dtype = spec.dtype if spec is not None else None
    x = _float_array(path, "x", d["x"], (n, 3), dtype)
    v = _float_array(path, "v", d["v"], (n, 3), dtype)
    traj_x = _float_array(path, "traj_x", d["traj_x"], (frame + 1, n, 3), dtype)
    traj_t = _float_array(path, "traj_t", d["traj_t"], (frame + 1,), None)
    traj_v = d.get("traj_v")
    if traj_v is not None:
        traj_v = _float_array(path, "traj_v", traj_v, (frame + 1, n, 3), dtype)
    meta: dict = {}
    if "meta" in d:
        try:
            meta = json.loads(str(d["meta"]))
        except ValueError:
            raise CheckpointError(f"{path}: meta: not JSON; the file is corrupt, delete it") from None
        if not isinstance(meta, dict):
            raise CheckpointError(f"{path}: meta: expected a JSON object; the file is corrupt, delete it")
    params = {}
    for k, a in d.items():
        if k.startswith("param_"):
            name = k[len("param_") :]
            shape = spec.params[name] if spec is not None else a.shape
            params[name] = _float_array(path, k, a, tuple(shape), None)
    return {
        "frame": frame,
        "time": time,
        "x": x,
        "v": v,
        "traj_x": traj_x,
        "traj_t": traj_t,
        "traj_v": traj_v,
        "meta": meta,
        "params": params,
        "solver_state": {k[len("solver_") :]: a for k, a in d.items() if k.startswith("solver_")},
    }
