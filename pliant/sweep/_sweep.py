"""The sweep: grid of overrides → chunks (batched copies when allowed) → rows of results.csv."""

from __future__ import annotations

import csv
import itertools
import json
import os
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..io import atomic_write_text

if TYPE_CHECKING:
    from ..scene import Scene, SceneConfig

#: Columns of results.csv after the override columns.
COLUMNS = [
    "status",
    "error",
    "centroid_x",
    "centroid_y",
    "centroid_z",
    "sag",
    "max_speed",
    "frames",
    "batched",
    "wall_time",
]
#: Columns that are equal whatever executes the runs (all but how and how long).
FIGURES = ["status", "error", "centroid_x", "centroid_y", "centroid_z", "sag", "max_speed", "frames"]


class SweepError(ValueError):
    """A malformed ``--set`` list or sweep option (the message names it and the fix)."""


def _split_values(text: str) -> list[str]:
    """``100,200`` → ["100", "200"]; commas inside brackets or quotes stay (``[0,1,0],[1,0,0]``)."""
    out, depth, quote, cur = [], 0, "", ""
    for ch in text:
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch == "[":
            depth += 1
        elif ch == "]":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append(cur)
            cur = ""
            continue
        cur += ch
    out.append(cur)
    return [v.strip() for v in out]


def grid(sets: Sequence[str]) -> list[list[str]]:
    """The cartesian product of ``PATH=V1,V2,...`` lists, as lists of ``PATH=V`` overrides (one per run).

    Raises:
        SweepError: a list without ``=`` or with an empty value.
    """
    axes = []
    for s in sets:
        path, eq, values = s.partition("=")
        if not eq or not path.strip():
            raise SweepError(
                f"--set {s!r}: expected PATH=V1,V2,... (e.g. objects[0].material.stiffness=100,200)"
            )
        vals = _split_values(values)
        if any(v == "" for v in vals):
            raise SweepError(f"--set {s!r}: an empty value in the list; write PATH=V1,V2 without empty items")
        axes.append([f"{path.strip()}={v}" for v in vals])
    return [list(run) for run in itertools.product(*axes)] if axes else [[]]


def summarize(x: np.ndarray, frame_dt: float) -> dict[str, float]:
    """Summary figures of positions ``x`` (metres, shape [T, N, 3]): the final centroid [m], the sag (drop
    of the centroid's height from frame 0 to the last) [m] and the largest particle speed between frames
    [m/s]."""
    c0, c1 = x[0].mean(axis=0), x[-1].mean(axis=0)
    speed = np.linalg.norm(np.diff(x, axis=0), axis=2).max() / frame_dt if len(x) > 1 else 0.0
    return {
        "centroid_x": float(c1[0]),
        "centroid_y": float(c1[1]),
        "centroid_z": float(c1[2]),
        "sag": float(c0[1] - c1[1]),
        "max_speed": float(speed),
    }


def _object_only(run: Sequence[str]) -> bool:
    return all(o.strip().startswith("objects[") for o in run)


def run_chunk(
    scene: str, runs: list[list[str]], frames: int | None, traj_dir: str | None, force: bool = False
) -> list[dict]:
    """Run ``runs`` (override lists) of ``scene``: as worlds of one model when they change only material
    values (``ModelBuilder.replicate``, each world's parameters its own), else as copies of the objects in
    one simulation when they change only object sections, else (or when that fails) one by one. A run
    whose world diverges is run again alone, so its row is the one it has alone. ``force`` skips the scene
    size checks (``--force``). Returns one result dict per run."""
    from ..scene import coupled, load_scene, material_only, worlds_unsupported

    t0 = time.perf_counter()
    base = load_scene(scene, force=force)
    out = None
    if len(runs) > 1 and coupled(base) is None:
        if all(material_only(r) for r in runs) and worlds_unsupported(base) is None:
            out = _as_worlds(scene, runs, frames, traj_dir, force)
        if out is None and all(_object_only(r) for r in runs):
            out = _as_copies(scene, base, runs, frames, traj_dir, force)
    if out is None:
        return [_run_one(scene, r, frames, traj_dir, force) for r in runs]
    wall = (time.perf_counter() - t0) / len(runs)
    return [o if "wall_time" in o else {**o, "wall_time": wall} for o in out]


def _ok(x: np.ndarray, frame_dt: float, frames: int, batched: int) -> dict:
    return {"status": "ok", "error": "", **summarize(x, frame_dt), "frames": frames, "batched": batched}


def _as_worlds(
    scene: str, runs: list[list[str]], frames: int | None, traj_dir: str | None, force: bool
) -> list | None:
    """The runs as worlds of one model; None when they cannot be (the caller tries another way)."""
    from ..scene import SceneError, build_worlds, load_scene
    from ..sim import DivergenceError, Simulator

    try:
        built = build_worlds([load_scene(scene, r, force=force) for r in runs])
        n = frames if frames is not None else built.frames
        sim = Simulator(built.model, built.solver, **built.sim_kwargs)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="world .* diverged", category=RuntimeWarning)
            traj = sim.run(n, progress=False)
    except DivergenceError:  # every world diverged: each run alone (copies would diverge just the same)
        return [_run_one(scene, r, frames, traj_dir, force) for r in runs]
    except (SceneError, ValueError):
        return None
    out = []
    for w, r in enumerate(runs):
        if w in sim.diverged_worlds:
            out.append(_run_one(scene, r, frames, traj_dir, force))  # its own row, message and all
            continue
        x = traj.world(w).x
        _save(traj_dir, r, x, built.frame_dt)
        out.append(_ok(x, built.frame_dt, n, len(runs)))
    return out


def _as_copies(
    scene: str,
    base: SceneConfig,
    runs: list[list[str]],
    frames: int | None,
    traj_dir: str | None,
    force: bool,
):
    """The runs as copies of the objects in one scene; None when that fails (the caller runs them alone)."""
    from ..scene import SceneError, build_scene, load_scene
    from ..sim import DivergenceError

    try:
        cfgs = [load_scene(scene, r, force=force) for r in runs]
        merged = base.model_copy(deep=True)
        per = len(base.objects)
        merged.objects = [
            o.model_copy(update={"name": f"{o.name or 'object'}_w{w}"})
            for w, c in enumerate(cfgs)
            for o in c.objects
        ]
        built = build_scene(merged)
        n = frames if frames is not None else built.frames
        traj = _simulate(built, n)
    except (DivergenceError, SceneError, ValueError):
        return None  # one run alone at a time: the failure is then recorded for its run only
    spans = built.model.objects
    out = []
    for w, r in enumerate(runs):
        lo = spans[w * per]["start"]
        hi = spans[(w + 1) * per - 1]["start"] + spans[(w + 1) * per - 1]["count"]
        x = traj[:, lo:hi]
        _save(traj_dir, r, x, built.frame_dt)
        out.append(_ok(x, built.frame_dt, n, len(runs)))
    return out


def _simulate(built: Scene, frames: int) -> np.ndarray:
    from ..sim import Simulator

    built.prebuild_kernels()  # a built-in scene's kernels compile on both cores (once per process)
    sim = Simulator(built.model, built.solver, **built.sim_kwargs)
    return sim.run(frames, progress=False).x


def _run_one(scene: str, run: list[str], frames: int | None, traj_dir: str | None, force: bool) -> dict:
    from ..scene import SceneError, build_scene, load_scene
    from ..sim import DivergenceError

    t0 = time.perf_counter()
    row: dict[str, Any] = {"status": "ok", "error": "", "batched": 1}
    try:
        built = build_scene(load_scene(scene, run, force=force))
        n = frames if frames is not None else built.frames
        x = _simulate(built, n)
        _save(traj_dir, run, x, built.frame_dt)
        row.update(summarize(x, built.frame_dt), frames=n)
    except DivergenceError as exc:
        row.update(status="diverged", error=str(exc).splitlines()[0])
    except (SceneError, ValueError) as exc:
        row.update(status="error", error=str(exc).splitlines()[0])
    row["wall_time"] = time.perf_counter() - t0
    return row


def _key(run: Sequence[str]) -> str:
    return ";".join(run)


def _save(traj_dir: str | None, run: Sequence[str], x: np.ndarray, frame_dt: float) -> None:
    if traj_dir is None:
        return
    import hashlib

    from ..io import atomic_savez

    name = hashlib.sha1(_key(run).encode()).hexdigest()[:12]
    atomic_savez(
        Path(traj_dir) / f"run_{name}.npz", x=x, t=np.arange(len(x)) * frame_dt, overrides=np.array(_key(run))
    )


def _write(path: Path, paths: list[str], rows: list[dict]) -> None:
    tmp = path.with_suffix(".csv.tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=paths + COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow(r)
    os.replace(tmp, path)
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return
    pq.write_table(
        pa.Table.from_pylist([{k: r.get(k) for k in paths + COLUMNS} for r in rows]),
        path.with_suffix(".parquet"),
    )


def _done(path: Path) -> dict[str, dict]:
    """The finished runs of an earlier sweep into the same folder (numbers read back as numbers)."""
    if not path.exists():
        return {}
    with open(path, newline="", encoding="utf-8") as f:
        rows = {r["overrides"]: r for r in csv.DictReader(f) if r.get("status") == "ok"}
    for r in rows.values():
        for k in ("centroid_x", "centroid_y", "centroid_z", "sag", "max_speed", "wall_time"):
            r[k] = float(r[k])
        for k in ("frames", "batched"):
            r[k] = int(r[k])
    return rows


#: The folder's record of which sweep its results.csv holds (the scene's text and the frame count, hashed).
SWEEP_FILE = "sweep.json"


def _scene_tag(text: str, frames: int | None) -> str:
    """The identity of a sweep's runs apart from their overrides: the scene file's text (or the built-in
    scene's) and the frame count asked for."""
    import hashlib

    return hashlib.sha256(f"pliant sweep 1\n{frames}\n{text}".encode()).hexdigest()


def _check_folder(out: Path, tag: str) -> None:
    """SweepError when ``out`` holds the results of another sweep (another scene or frame count), or a
    record that cannot be read; a folder without a record (a sweep written before records) is taken."""
    record = out / SWEEP_FILE
    if not record.exists():
        return
    try:
        saved = json.loads(record.read_text(encoding="utf-8"))["scene"]
    except (OSError, ValueError, KeyError, TypeError):
        raise SweepError(
            f"{record}: not a sweep record; use another --out, or delete it and results.csv to start again"
        ) from None
    if saved != tag:
        raise SweepError(
            f"{out}: holds the results of a sweep of another scene or frame count ({SWEEP_FILE}); use "
            f"another --out, or delete {SWEEP_FILE} and results.csv there to start again"
        )


def run_sweep(
    scene: str,
    sets: Sequence[str],
    out: str | os.PathLike,
    *,
    worlds: int = 16,
    frames: int | None = None,
    ray: bool = False,
    address: str | None = None,
    save_trajectories: bool = False,
    force: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> list[dict]:
    """Run every combination of ``sets`` on ``scene`` and write ``out/results.csv``.

    Args:
        scene: A scene file or built-in scene name.
        sets: ``PATH=V1,V2,...`` lists (the grid is their cartesian product).
        out: Output folder (created).
        worlds: Runs per simulation (copies stepped together) when they change only objects (≥ 1).
        frames: Frames to simulate (default: the scene's).
        ray: Run chunks of ``worlds`` runs as Ray tasks (``pip install 'pliant[ray]'``).
        address: An existing Ray cluster (default with ``ray``: a local one).
        save_trajectories: Also write each run's positions to ``out/trajectories/run_<hash>.npz``.
        force: Build runs whose estimated memory exceeds the machine's (``--force``); without it such a
            first run is refused before any work, a later one is recorded as an error row.
        progress: ``progress(done, total)`` after each chunk.

    Returns:
        The rows of results.csv (dicts), in grid order.
    """
    from ..scene import load_scene

    if worlds < 1:
        raise SweepError(f"--worlds: expected at least 1, got {worlds}")
    runs = grid(sets)
    cfg = load_scene(scene, runs[0], force=force)  # a bad scene, path or size fails here, before any work
    out = Path(out)
    tag = _scene_tag(cfg.text or str(scene), frames)
    _check_folder(out, tag)  # rows of another scene are not this sweep's results: refused before any work
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / SWEEP_FILE, json.dumps({"scene": tag}) + "\n")
    traj_dir = str(out / "trajectories") if save_trajectories else None
    if traj_dir:
        Path(traj_dir).mkdir(exist_ok=True)
    table = out / "results.csv"
    done = _done(table)
    paths = ["overrides"]
    todo = [r for r in runs if _key(r) not in done]
    chunks = [todo[i : i + worlds] for i in range(0, len(todo), worlds)]
    results: dict[str, dict] = {k: dict(v) for k, v in done.items()}

    def keep(chunk: list[list[str]], rows: list[dict]) -> None:
        for r, row in zip(chunk, rows, strict=True):
            results[_key(r)] = {"overrides": _key(r), **row}
        _write(table, paths, [results[_key(r)] for r in runs if _key(r) in results])
        if progress is not None:
            progress(sum(_key(r) in results for r in runs), len(runs))

    if ray and chunks:
        for chunk, rows in _ray_map(scene, chunks, frames, traj_dir, address, force):
            keep(chunk, rows)
    else:
        for chunk in chunks:
            keep(chunk, run_chunk(scene, chunk, frames, traj_dir, force))
    if not chunks:
        _write(table, paths, [results[_key(r)] for r in runs])
    return [results[_key(r)] for r in runs]


def _ray_map(
    scene: str, chunks: list, frames: int | None, traj_dir: str | None, address: str | None, force: bool
):
    try:
        import ray
    except ImportError:
        from .._extras import pip_install

        raise SweepError(f"--ray needs Ray, an optional extra: {pip_install('ray')}") from None
    started = not ray.is_initialized()
    if started:
        ray.init(address=address, include_dashboard=False, log_to_driver=False, ignore_reinit_error=True)
    try:
        task = ray.remote(run_chunk)
        refs = [task.remote(scene, c, frames, traj_dir, force) for c in chunks]
        for c, ref in zip(chunks, refs, strict=True):
            yield c, ray.get(ref)
    finally:
        if started:
            ray.shutdown()
