"""Issue 41, item 2: every NPZ pliant loads from users (observations, trajectories, checkpoints, a scene's
parameters) has its arrays' headers read from the ZIP entries first, and is refused in one line naming the
file, the array, its shape and size in GiB when loading would not fit in the available memory: before
``np.load`` allocates what the headers declare, in well under a second."""

from __future__ import annotations

import io
import time
import zipfile

import numpy as np
import pytest

from pliant.io import (
    CheckpointError,
    ObservationError,
    Observations,
    Trajectory,
    load_checkpoint,
    npz_headers,
)
from pliant.io._npz import LOAD_FACTOR

GIB = 2.0**30


def _header_only(shape: tuple[int, ...], dtype: str = "<f8") -> bytes:
    """A version-1.0 ``.npy`` header declaring ``shape`` and ``dtype``, with no data after it."""
    text = f"{{'descr': '{dtype}', 'fortran_order': False, 'shape': {shape!r}, }}"
    pad = 64 - (10 + len(text) + 1) % 64
    text = text + " " * pad + "\n"
    return b"\x93NUMPY\x01\x00" + len(text).to_bytes(2, "little") + text.encode("latin1")


def _npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def _npz(path, members: dict[str, bytes], compress: bool = False):
    mode = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(path, "w", mode) as zf:
        for name, data in members.items():
            zf.writestr(f"{name}.npy", data)
    return path


def test_a_224_gib_header_is_refused_before_allocation(tmp_path):
    """images declared as 100000 × 100000 × 3 float64 (223.5 GiB) in a file of a few hundred bytes: an
    ObservationError naming the file, the array, its shape and 224 GiB, in well under a second (np.load
    would first try to allocate it)."""
    path = _npz(
        tmp_path / "obs.npz",
        {"t": _npy(np.linspace(0.0, 1.0, 5)), "images": _header_only((100000, 100000, 3))},
        compress=True,
    )
    assert path.stat().st_size < 1000
    t0 = time.perf_counter()
    with pytest.raises(ObservationError) as info:
        Observations.load(path)
    elapsed = time.perf_counter() - t0
    msg = str(info.value)
    assert elapsed < 1.0 and len(msg.splitlines()) == 1, (elapsed, msg)
    gib = 100000 * 100000 * 3 * 8 / GIB  # 223.5
    assert msg.startswith(f"{path}: images: the header declares shape (100000, 100000, 3) float64, "), msg
    assert f"{gib:.3g} GiB" in msg and "224 GiB" in msg, msg


def test_a_20_gb_header_is_refused_on_a_24_gb_machine(tmp_path, monkeypatch):
    """20 GB of points (2500 × 1000000 × 1 ... declared as [2500, 1000000, 1] float64) on a machine with
    24 GB available: loading it and the copies its checks make (LOAD_FACTOR = 2 × 18.6 GiB = 37.3 GiB) would
    thrash, so it is refused from the header; the same file at 10 MB loads as far as its content check."""
    monkeypatch.setenv("PLIANT_MEMORY_GB", "24")
    shape = (2500, 1000000, 1)
    path = _npz(tmp_path / "obs.npz", {"t": _npy(np.linspace(0.0, 1.0, 2500)), "points": _header_only(shape)})
    t0 = time.perf_counter()
    with pytest.raises(ObservationError) as info:
        Observations.load(path)
    elapsed = time.perf_counter() - t0
    msg = str(info.value)
    declared = 2500 * 1000000 * 8 + 2500 * 8  # points + t [bytes]
    assert elapsed < 1.0, elapsed
    assert f"points: the header declares shape {shape} float64, {2500 * 1e6 * 8 / GIB:.3g} GiB" in msg, msg
    assert f"needs about {LOAD_FACTOR * declared / GIB:.3g} GiB and {24e9 / GIB:.3g} GiB is available" in msg
    print(f"\n20 GB header refused in {1e3 * elapsed:.2f} ms")
    small = _npz(
        tmp_path / "small.npz", {"t": _npy(np.linspace(0.0, 1.0, 5)), "points": _header_only((5, 1, 3))}
    )
    with pytest.raises(ObservationError, match="not a readable observation NPZ"):  # truncated: no data
        Observations.load(small)


def test_headers_are_read_from_compressed_members(tmp_path):
    """npz_headers reads each member's header, deflated or stored, without its data."""
    path = tmp_path / "a.npz"
    np.savez_compressed(path, x=np.zeros((4, 5, 3), np.float32), t=np.arange(4))
    heads = {n: (s, d) for n, s, d in npz_headers(path)}
    assert heads == {"x": ((4, 5, 3), np.dtype(np.float32)), "t": ((4,), np.dtype(np.arange(4).dtype))}
    assert npz_headers(tmp_path / "missing.npz") == []


def test_trajectories_and_checkpoints_are_bounded_from_their_headers(tmp_path, monkeypatch):
    """A trajectory and a checkpoint whose x declares 1e6 × 1e6 × 3 float64 (22 TiB) are refused naming x."""
    monkeypatch.setenv("PLIANT_MEMORY_GB", "24")
    members = {"x": _header_only((1000000, 1000000, 3)), "t": _npy(np.arange(3.0))}
    traj = _npz(tmp_path / "traj.npz", members)
    with pytest.raises(ValueError, match=r"traj.npz: x: the header declares shape \(1000000, 1000000, 3\)"):
        Trajectory.load(traj)
    ck = _npz(tmp_path / "ck.npz", members)
    with pytest.raises(CheckpointError, match=r"ck.npz: x: the header declares .* GiB is available"):
        load_checkpoint(ck)


def test_files_that_are_not_zips_or_that_zipfile_cannot_read_are_refused_in_one_line(tmp_path):
    """Found by tests/test_fuzz_observations.py: a file that is not a ZIP was said to hold pickled data (NumPy
    tries it as a pickle), a ZIP whose version zipfile does not implement escaped the header check as
    NotImplementedError without the file's name, and a truncated ZIP left np.load's file handle open."""
    import gc
    import sys
    import warnings

    good = io.BytesIO()
    np.savez(good, t=np.linspace(0.0, 1.0, 5), points=np.zeros((5, 1, 3)))
    blob = good.getvalue()
    unsupported = bytearray(blob)
    at = blob.rfind(b"PK\x01\x02")  # the last member's central directory entry: needs version 99.9
    unsupported[at + 6 : at + 8] = (999).to_bytes(2, "little")
    cases = {
        "text.npz": (b'{"t": [0, 1]}', "it is not a ZIP archive of .npy arrays"),
        "empty.npz": (b"", "it is not a ZIP archive of .npy arrays"),
        "version.npz": (bytes(unsupported), "not a readable observation NPZ"),
        "truncated.npz": (blob[: len(blob) // 2], "not a readable observation NPZ"),
    }
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name, (content, words) in cases.items():
            path = tmp_path / name
            path.write_bytes(content)
            with pytest.raises(ObservationError) as info:
                Observations.load(path)
            msg = str(info.value)
            assert msg.startswith(f"{path}: ") and words in msg and "pickle" not in msg, msg
            assert len(msg.splitlines()) == 1
        unraisable = []
        hook, sys.unraisablehook = sys.unraisablehook, unraisable.append
        try:
            gc.collect()  # an open handle left behind is reported here, as a ResourceWarning
        finally:
            sys.unraisablehook = hook
    assert not unraisable, [str(u.exc_value) for u in unraisable]
