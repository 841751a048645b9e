"""Bounds on NPZ files before loading: the shape and dtype each member's ``.npy`` header declares, read from
the ZIP entry without its data, against the memory the machine has available (issue 41).

``np.load`` of an NPZ allocates each array at the size its header declares before reading a byte of data, so a
crafted or foreign file (a header that claims 100000 × 100000 × 3 float64 in a 200-byte file) is otherwise
refused only when the allocation fails, or, below the physical memory, thrashes the machine first. Reading
the headers takes milliseconds whatever they declare.
"""

from __future__ import annotations

import math
import os
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

_GB = 1e9
_GIB = float(1 << 30)
#: Loading an NPZ holds its arrays and, while they are checked and converted (``astype(float)``,
#: ``np.where``), about one copy more: the memory a file needs is this factor times its declared bytes.
LOAD_FACTOR = 2.0


def available_memory() -> float | None:
    """The memory pliant may use [bytes]: ``PLIANT_MEMORY_GB`` if set, else the machine's available memory
    (``MemAvailable`` of /proc/meminfo, else the free physical pages); None when it cannot be told."""
    raw = os.environ.get("PLIANT_MEMORY_GB", "").strip()
    if raw:
        try:
            v = float(raw)
            if v > 0 and math.isfinite(v):
                return v * _GB
        except ValueError:
            pass
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except (OSError, ValueError, IndexError):
        pass
    try:
        return float(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def npz_headers(path: str | os.PathLike) -> list[tuple[str, tuple[int, ...], np.dtype]]:
    """``(array name, shape, dtype)`` of every ``.npy`` member of the NPZ ``path``, from the headers alone.

    Args:
        path: the NPZ file.

    Returns:
        One entry per member whose header could be read; [] when ``path`` is not a ZIP (``np.load`` then says
        what it is). A member with an unreadable header is left out: loading it reports the fault.
    """
    out: list[tuple[str, tuple[int, ...], np.dtype]] = []
    try:
        zf = zipfile.ZipFile(path)
    except Exception:  # noqa: BLE001 - not a ZIP, or one zipfile cannot read: np.load then says what
        return out
    with zf:
        for info in zf.infolist():
            if not info.filename.endswith(".npy"):
                continue
            try:
                with zf.open(info) as f:  # streams: a compressed member is inflated only up to its header
                    major, _ = np.lib.format.read_magic(f)
                    read = (
                        np.lib.format.read_array_header_1_0
                        if major == 1
                        else np.lib.format.read_array_header_2_0
                    )
                    shape, _fortran, dtype = read(f)
            except Exception:  # noqa: BLE001 - any fault here is reported by np.load, with its own words
                continue
            if all(isinstance(n, int) and n >= 0 for n in shape):
                out.append((info.filename[: -len(".npy")], tuple(shape), dtype))
    return out


def npz_memory_problem(path: str | os.PathLike, what: str) -> str | None:
    """Why the NPZ ``path`` cannot be loaded in the memory available, or None when it fits.

    Args:
        path: the NPZ file (an observation, trajectory, checkpoint or parameter file).
        what: what the file is, for the message ("observation", "checkpoint").

    Returns:
        One line naming the file, its largest array, that array's shape, dtype and size [GiB], and the
        memory loading needs and has; None when :data:`LOAD_FACTOR` × the declared bytes fit in
        :func:`available_memory` (or it cannot be told).
    """
    heads = npz_headers(path)
    if not heads:
        return None
    # In floats: a header may declare dimensions whose product no double holds (then inf, refused).
    sizes = [
        (math.prod(map(float, shape)) * dtype.itemsize, name, shape, dtype) for name, shape, dtype in heads
    ]
    total = float(sum(s[0] for s in sizes))
    have = available_memory()
    if have is None or LOAD_FACTOR * total <= have:
        return None
    nbytes, name, shape, dtype = max(sizes, key=lambda s: s[0])
    together = f"; its {len(sizes)} arrays {total / _GIB:.3g} GiB" if len(sizes) > 1 else ""
    return (
        f"{Path(path)}: {name}: the header declares shape {shape} {dtype}, {nbytes / _GIB:.3g} GiB"
        f"{together}; "
        f"loading and checking it needs about {LOAD_FACTOR * total / _GIB:.3g} GiB and "
        f"{have / _GIB:.3g} GiB is available; this {what} file cannot be loaded here (use fewer frames, "
        "points or a lower image resolution)"
    )


def read_npz(
    path: str | os.PathLike, what: str, fail: Callable[[str], Exception] = ValueError
) -> dict[str, np.ndarray]:
    """Every array of a user's NPZ, refused before anything is allocated when the arrays' headers declare
    more than the memory available (:func:`npz_memory_problem`), and refused in one line when NumPy cannot
    read it (truncated, pickled or not an NPZ).

    Args:
        path: The file.
        what: What the file is, for messages ("observation", "camera", "trajectory").
        fail: Builds the exception from a one-line message (the caller's error type).

    Returns:
        Name → array, loaded with ``allow_pickle=False``.
    """
    too_big = npz_memory_problem(path, what)
    if too_big:  # the headers' declared shapes, before np.load allocates them
        raise fail(too_big)
    try:
        # Opened here, not by np.load, which leaves its own handle open when the ZIP is truncated.
        with open(path, "rb") as f:
            if f.read(2) != b"PK":  # np.load would try it as a pickle and say that it holds pickled data
                raise ValueError("it is not a ZIP archive of .npy arrays")
            f.seek(0)
            with np.load(f, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
    except Exception as exc:  # a truncated or foreign file: say which and why
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if "pickle" in why:  # NumPy's own text would suggest allow_pickle=True: never for an untrusted file
            why = "it holds Python objects (pickled data), which pliant never writes or loads"
        raise fail(f"{path}: not a readable {what} NPZ ({why})") from None


__all__ = ["LOAD_FACTOR", "available_memory", "npz_headers", "npz_memory_problem", "read_npz"]
