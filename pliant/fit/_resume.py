"""Fit checkpoints (``pliant fit --resume``, issue 41): ``OUT/fit_checkpoint.json``, written atomically after
every CMA-ES generation and every gradient iteration, so that a killed fit continues where it stopped and
reaches the same ``fitted.toml``, byte for byte on the CPU, as the uninterrupted one.

The file holds no pickles (plain JSON; floats as Python's repr, which reads back exactly):

- ``format``, ``fit_version`` and ``pliant``: refused when any differs from this build's;
- ``digest``: SHA-256 of everything else, so that an edited or corrupted checkpoint whose JSON still parses
  (a flipped bit in a saved loss or candidate) is refused rather than continued into other values;
- ``scene``, ``observations``: SHA-256 of the scene's validated fields and of the observation arrays;
  ``options``: the fit's options (seed, generations, ...); each refused with one line naming what differs;
- ``stages``: the stages that finished (their :class:`~pliant.fit._cmaes.StageResult`), returned as they were;
- ``current``: the stage in progress and its state at its last iteration boundary. CMA-ES keeps every
  generation's candidates, losses and the random generator's state before its ``ask``: a resume replays the
  asks and tells (no simulation; the candidates are checked bit for bit) to rebuild ``cma``'s state exactly.
  The L-BFGS stages keep every evaluation of the loss and its gradient, replayed to SciPy in order; Adam
  keeps its moments.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..io import atomic_write_text
from ._params import FitError

if TYPE_CHECKING:
    from ..io import Observations
    from ..scene import SceneConfig
    from ._stage import StageResult

#: The checkpoint file in a fit's output folder.
CHECKPOINT_FILE = "fit_checkpoint.json"
#: The checkpoint's layout (2: with ``digest``).
FORMAT = 2
#: The fit's arithmetic: bump when a stage's sequence of evaluations changes, so that an older checkpoint
#: (whose replay would diverge) is refused rather than continued.
FIT_VERSION = 2  # 2: the global stages train without the validation frames (issue 38)


def _pliant_version() -> str:
    try:
        from importlib.metadata import version

        return version("pliant")
    except Exception:  # noqa: BLE001 - a source tree without metadata
        return "unknown"


def observations_hash(obs: Observations) -> str:
    """SHA-256 of every array of ``obs`` (name, dtype, shape and bytes), in field order."""
    h = hashlib.sha256()
    for f in dataclasses.fields(obs):
        a = getattr(obs, f.name)
        if isinstance(a, np.ndarray):
            a = np.ascontiguousarray(a)
            h.update(f"{f.name}:{a.dtype.str}:{a.shape};".encode())
            if a.size:  # (memoryview cannot cast an empty view: a file without tracks has points [T, 0, 3])
                h.update(a.tobytes())
    return h.hexdigest()


def scene_hash(cfg: SceneConfig) -> str:
    """SHA-256 of the scene's validated fields (overrides applied)."""
    return hashlib.sha256(cfg.model_dump_json().encode()).hexdigest()


def rng_state() -> list:
    """NumPy's global generator state (which ``cma`` draws from) as JSON: [name, key hex, pos, gauss]."""
    name, keys, pos, has_gauss, cached = np.random.get_state()  # noqa: NPY002 - cma's generator
    return [name, np.asarray(keys, "<u4").tobytes().hex(), int(pos), int(has_gauss), float(cached)]


def set_rng_state(s: list) -> None:
    """Restore :func:`rng_state`'s ``s``."""
    keys = np.frombuffer(bytes.fromhex(s[1]), "<u4").astype(np.uint32)
    np.random.set_state((s[0], keys, int(s[2]), int(s[3]), float(s[4])))  # noqa: NPY002


def _digest(data: dict) -> str:
    """SHA-256 of a checkpoint's contents but its ``digest`` (key order and float text fixed by ``json``)."""
    body = {k: v for k, v in data.items() if k != "digest"}
    return hashlib.sha256(json.dumps(body, sort_keys=True, allow_nan=True).encode()).hexdigest()


def _array(a: np.ndarray) -> dict:
    a = np.asarray(a)
    return {"dtype": a.dtype.str, "shape": list(a.shape), "data": a.ravel().tolist()}


def _unarray(d: dict) -> np.ndarray:
    return np.asarray(d["data"], dtype=np.dtype(d["dtype"])).reshape(d["shape"])


def result_json(r: StageResult) -> dict:
    """A StageResult as JSON (values, loss, history, counts, per-element arrays, flags)."""
    return {
        "values": {k: float(v) for k, v in r.values.items()},
        "loss": float(r.loss),
        "history": [float(v) for v in r.history],
        "evaluations": int(r.evaluations),
        "wall_time": float(r.wall_time),
        "interrupted": bool(r.interrupted),
        "per_element": {k: _array(a) for k, a in r.per_element.items()},
        "kept": bool(r.kept),
        "validation": r.validation,
        "stop": r.stop,
    }


def result_from_json(d: dict) -> StageResult:
    """The StageResult of :func:`result_json`'s ``d``."""
    from ._stage import StageResult

    return StageResult(
        values=dict(d["values"]),
        loss=float(d["loss"]),
        history=list(d["history"]),
        evaluations=int(d["evaluations"]),
        wall_time=float(d["wall_time"]),
        interrupted=bool(d["interrupted"]),
        per_element={k: _unarray(a) for k, a in d["per_element"].items()},
        kept=bool(d["kept"]),
        validation=d["validation"],
        stop=str(d["stop"]),
    )


def read_checkpoint(path: Path) -> dict:
    """A fit checkpoint's contents, refused unless readable, of this format, fit and pliant version, and
    matching its digest (what can be checked without the scene and the observations: ``pliant twin
    --resume`` checks its models' checkpoints so before any work).

    Raises:
        FitError: one line naming ``path`` and what is wrong.
    """
    again = "run without --resume to start over"
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        if not isinstance(data, dict) or not isinstance(data.get("stages"), dict):
            raise ValueError("not a fit checkpoint's layout")
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        why = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise FitError(f"{path}: not a readable fit checkpoint ({why}); {again}") from None
    this = {"format": FORMAT, "fit_version": FIT_VERSION, "pliant": _pliant_version()}
    for key, what in (
        ("format", "another checkpoint format"),
        ("fit_version", "another version of the fit"),
        ("pliant", "another version of pliant"),
    ):
        if data.get(key) != this[key]:
            raise FitError(f"{path}: written by {what} ({data.get(key)!r}, this one {this[key]!r}); {again}")
    if data.get("digest") != _digest(data):  # an edit or a flipped bit that still parses as JSON
        raise FitError(
            f"{path}: the checkpoint's contents do not match its digest (edited or corrupted); {again}"
        )
    return data


class FitCheckpoint:
    """The checkpoint of one fit (see the module docstring); :meth:`open` reads or starts it.

    Stages use :meth:`state` (their saved state, or None), :meth:`save` (after each iteration) and
    :meth:`finish`; :meth:`finished` gives a finished stage's result. ``saved`` is called after every write
    (``saved(stage, iteration)``): a hook for tests that stop a fit at a given point.
    """

    def __init__(self, path: Path, head: dict, data: dict | None = None) -> None:
        self.path, self.head = path, head
        self.data = data if data is not None else {**head, "stages": {}, "current": None}
        self.writes = 0

    @classmethod
    def open(
        cls, out: Path, cfg: SceneConfig, obs: Observations, options: dict[str, Any], resume: bool
    ) -> FitCheckpoint:
        """The checkpoint of a fit writing into ``out``: read and checked with ``resume``, else a new one
        (the file is overwritten at the first iteration).

        Args:
            out: The fit's output folder.
            cfg: The scene (its fields are hashed).
            obs: The observations (their arrays are hashed).
            options: The fit's options that change its result (JSON values).
            resume: Continue from ``out/fit_checkpoint.json``.

        Raises:
            FitError: with ``resume``, no checkpoint, an unreadable one, or one from another scene, other
                observations, other options or another version of the fit (one line each).
        """
        path = Path(out) / CHECKPOINT_FILE
        head = {
            "format": FORMAT,
            "fit_version": FIT_VERSION,
            "pliant": _pliant_version(),
            "scene": scene_hash(cfg),
            "observations": observations_hash(obs),
            "options": json.loads(json.dumps(options)),
        }
        if not resume:
            return cls(path, head)
        if not path.exists():
            raise FitError(f"--resume: no fit checkpoint at {path}; run once without --resume first")
        data = read_checkpoint(path)
        again = "run without --resume to start over"
        if data.get("scene") != head["scene"]:
            raise FitError(f"{path}: the checkpoint is from another scene than {cfg.source}; {again}")
        if data.get("observations") != head["observations"]:
            raise FitError(f"{path}: the checkpoint is from other observations than {obs.source}; {again}")
        saved = data.get("options")
        theirs: dict = saved if isinstance(saved, dict) else {}
        diff = sorted(
            k for k in set(theirs) | set(head["options"]) if theirs.get(k) != head["options"].get(k)
        )
        if diff:
            k = diff[0]
            raise FitError(
                f"{path}: the checkpoint is from a fit with other options ({k} {theirs.get(k)!r}, now "
                f"{head['options'].get(k)!r}); pass the same options, or {again}"
            )
        return cls(path, head, data)

    # ------------------------------------------------------------------ stages
    def finished(self, stage: str) -> StageResult | None:
        """The result of ``stage`` if it finished before, else None."""
        d = self.data["stages"].get(stage)
        return None if d is None else result_from_json(d)

    def stage(self, name: str) -> StageHook:
        """The hook a stage saves through: its saved ``state`` (or None) and ``save(state, iteration)``."""
        return StageHook(self, name)

    def state(self, stage: str) -> dict | None:
        """The saved state of ``stage`` when it is the one in progress, else None."""
        cur = self.data.get("current")
        return cur["state"] if isinstance(cur, dict) and cur.get("stage") == stage else None

    def save(self, stage: str, state: dict, iteration: int) -> None:
        """Record ``stage``'s ``state`` at the end of ``iteration`` (atomically)."""
        self.data["current"] = {"stage": stage, "iteration": iteration, "state": state}
        self._write()
        self.saved(stage, iteration)

    def finish(self, stage: str, result: StageResult) -> None:
        """Record that ``stage`` finished with ``result`` (not for an interrupted stage)."""
        self.data["stages"][stage] = result_json(result)
        self.data["current"] = None
        self._write()
        self.saved(stage, -1)

    def saved(self, stage: str, iteration: int) -> None:
        """Called after each write (``iteration`` -1: the stage finished); nothing by default."""

    def _write(self) -> None:
        self.data["digest"] = _digest(self.data)
        atomic_write_text(self.path, json.dumps(self.data, allow_nan=True) + "\n")
        self.writes += 1


class StageHook:
    """One stage's view of a :class:`FitCheckpoint`: ``state`` (its saved state when a resume continues
    it, else None) and :meth:`save`."""

    def __init__(self, checkpoint: FitCheckpoint, name: str) -> None:
        self.checkpoint, self.name = checkpoint, name
        self.state = checkpoint.state(name)

    def save(self, state: dict, iteration: int) -> None:
        """Record the stage's ``state`` at the end of ``iteration`` (1-based)."""
        self.checkpoint.save(self.name, state, iteration)


class Journal:
    """The evaluations of a deterministic optimiser's objective (L-BFGS-B's ``fun``): recorded as they are
    made, and on a resume returned in order for the same arguments (checked bit for bit) instead of
    computed, which brings SciPy's state back exactly.

    Args:
        saved: The evaluations of the checkpoint (``[[theta], value, [grad]]`` each), or None.
    """

    def __init__(self, saved: list | None) -> None:
        self.entries: list = list(saved or [])
        self.replay = len(self.entries)
        self.next = 0

    def __call__(
        self, fun: Callable[[np.ndarray], tuple[float, np.ndarray]], theta: np.ndarray
    ) -> tuple[float, np.ndarray]:
        """``fun(theta)``, or the recorded evaluation while replaying."""
        if self.next < self.replay:
            th, value, g = self.entries[self.next]
            if not np.array_equal(np.asarray(th, np.float64), np.asarray(theta, np.float64)):
                raise FitError(
                    f"the checkpoint's evaluation {self.next} does not replay (another optimiser version?); "
                    "run without --resume to start over"
                )
            self.next += 1
            return float(value), np.asarray(g, np.float64)
        value, g = fun(theta)
        self.entries.append([np.asarray(theta, np.float64).tolist(), float(value), np.asarray(g).tolist()])
        self.next += 1
        return value, g

    @property
    def replaying(self) -> bool:
        """Whether recorded evaluations remain to be returned."""
        return self.next < self.replay


__all__ = [
    "CHECKPOINT_FILE",
    "FIT_VERSION",
    "FitCheckpoint",
    "Journal",
    "StageHook",
    "observations_hash",
    "read_checkpoint",
    "rng_state",
    "scene_hash",
    "set_rng_state",
]
