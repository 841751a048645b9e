"""Warp set-up shared by every layer: initialisation, scalar types, device choice."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator, Sequence
from typing import Any, Protocol, TypeVar

import numpy as np
import warp as wp

_initialised = False


def init() -> None:
    """Initialise Warp once, quietly unless PLIANT_VERBOSE is set."""
    global _initialised
    if _initialised:
        return
    if not os.environ.get("PLIANT_VERBOSE"):
        # Warp's banner and per-module "load ... (compiled)" lines are noise in a CLI; warnings still show.
        if hasattr(wp.config, "log_level") and hasattr(wp, "LOG_WARNING"):
            wp.config.log_level = wp.LOG_WARNING
        else:  # older Warp
            wp.config.quiet = True  # type: ignore[attr-defined]
    if os.environ.get("PLIANT_VERBOSE") or _cuda_driver_present():
        wp.init()
    else:
        with _without_line_on_stderr(_NO_DRIVER):
            wp.init()
    _initialised = True


#: Warp's native library prints this on every start of a machine without the NVIDIA driver: noise on a
#: CPU-only machine, where ``pliant info`` already says "cuda: not available (CPU only)".
_NO_DRIVER = b"Could not find or load the NVIDIA CUDA driver"


def _cuda_driver_present() -> bool:
    """Whether the CUDA driver library that Warp looks for (libcuda / nvcuda.dll) loads."""
    import ctypes
    import sys

    if sys.platform == "darwin":  # Warp has no CUDA there and prints nothing about it
        return True
    names = ("nvcuda.dll",) if sys.platform == "win32" else ("libcuda.so", "libcuda.so.1")
    for name in names:
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


@contextlib.contextmanager
def _without_line_on_stderr(needle: bytes) -> Iterator[None]:
    """Run the body with file descriptor 2 captured (native code writes there, not to ``sys.stderr``) and
    write back every captured line except those containing ``needle``."""
    import sys
    import tempfile

    fd = 2  # C's stderr, whatever sys.stderr has been replaced with (pytest capture, notebooks)
    try:
        sys.stderr.flush()
        saved = os.dup(fd)
    except OSError:
        yield
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), fd)
        try:
            yield
        finally:
            os.dup2(saved, fd)
            os.close(saved)
            tmp.seek(0)
            kept = [line for line in tmp.read().splitlines(keepends=True) if needle not in line]
            if kept:
                os.write(fd, b"".join(kept))


DTYPES = ("float32", "float64")


def scalar_type(dtype: str) -> type:
    """Warp scalar type for ``"float32"`` or ``"float64"``."""
    if dtype not in DTYPES:
        raise ValueError(f"dtype must be one of {DTYPES}, got {dtype!r}")
    return wp.float32 if dtype == "float32" else wp.float64


def vec3_type(dtype: str) -> type:
    """Warp 3-vector type for ``dtype``."""
    return wp.vec3 if scalar_type(dtype) is wp.float32 else wp.vec3d


def mat33_type(dtype: str) -> type:
    """Warp 3x3 matrix type for ``dtype``."""
    return wp.mat33 if scalar_type(dtype) is wp.float32 else wp.mat33d


def np_dtype(dtype: str) -> type:
    """NumPy scalar type for ``dtype``."""
    scalar_type(dtype)
    return np.float32 if dtype == "float32" else np.float64


def default_device() -> str:
    """CUDA when present, else the CPU (DESIGN.md: default device is CUDA when present)."""
    init()
    return "cuda:0" if wp.is_cuda_available() else "cpu"


def resolve_device(device: str | None) -> str:
    """Validate a device name, naming the devices that exist when it is unknown."""
    init()
    if device is None:
        return default_device()
    names = [str(d) for d in wp.get_devices()]
    if device == "cuda" and wp.is_cuda_available():
        return "cuda:0"
    if device not in names:
        raise ValueError(f"unknown device {device!r}; available devices: {names}")
    return device


# ----------------------------------------------------------------------------------------------- launches
#: Recorded launches by argument signature (see :func:`launch`); bounded so that churned arrays drop out.
_LAUNCHES: dict[tuple, tuple[Any, tuple[int, ...]]] = {}
_LAUNCHES_MAX = 2048


def _runtime() -> Any:
    """Warp's runtime object, which holds the recording tape (its module moved between Warp versions)."""
    try:
        from warp._src.context import runtime
    except ImportError:  # an older Warp layout
        from warp.context import runtime  # type: ignore[no-redef, import-not-found]
    return runtime


def active_tape() -> wp.Tape | None:
    """The ``wp.Tape`` now recording, or None. The one place that reads Warp's runtime for it."""
    return getattr(_runtime(), "tape", None)


def capturing(device: wp.DeviceLike) -> bool:
    """Whether launches on ``device`` are being captured into a graph (so a host read would see stale
    data): a CUDA stream capture, or Warp's CPU capture (Warp 1.19+)."""
    d = wp.get_device(device)
    if d.is_cuda:
        return bool(d.is_capturing)
    return getattr(_runtime(), "_apic_capture", None) is not None


_F = TypeVar("_F", bound=Callable[..., Any])


def graph_safe(fn: _F) -> _F:
    """Mark a tape callback (``wp.Tape.record_func``) as replayable in a captured graph: it only launches
    Warp kernels and copies on the tape's device, reads nothing back to the host while a capture is on
    (``capturing``) and takes no Python decision from array values, so its launches captured once replay
    correctly (``pliant.diff``'s rollout
    graphs refuse unmarked callbacks, and still compare the capturing call with a direct run)."""
    fn.graph_safe = True  # type: ignore[attr-defined]
    return fn


def _tape_active() -> bool:
    try:
        return active_tape() is not None
    except ImportError:  # another Warp layout: be safe, never replay
        return True


@contextlib.contextmanager
def tape_paused() -> Iterator[wp.Tape | None]:
    """Run the block with no active ``wp.Tape`` (yields the tape that was active, or None)."""
    runtime = _runtime()
    tape = getattr(runtime, "tape", None)
    runtime.tape = None
    try:
        yield tape
    finally:
        runtime.tape = tape


@contextlib.contextmanager
def untaped_in_place() -> Iterator[None]:
    """Run in-place kernels outside any tape: the tape is paused and Warp's read-then-write check
    (``wp.config.verify_autograd_array_access``, applied when a module is built) is off, because these
    launches are never replayed (e.g. the CG iterations a hand-written adjoint stands in for)."""
    old = wp.config.verify_autograd_array_access
    wp.config.verify_autograd_array_access = False
    try:
        with tape_paused():
            yield
    finally:
        wp.config.verify_autograd_array_access = old


def launch(
    kernel: wp.Kernel,
    dim: int | Sequence[int],
    inputs: list,
    device: wp.DeviceLike = None,
    block_dim: int | None = None,
) -> None:
    """``wp.launch(kernel, dim, inputs, device=device, block_dim=block_dim)``, replaying a recorded
    ``wp.Launch`` when it can (``block_dim``: threads per block, None: Warp's default).

    A plain launch of a generic kernel spends 10-60 µs in Python (overload resolution, argument packing),
    more than many of our kernels take to run on the CPU for a thousand particles. The first launch with a
    given signature — kernel, dim, device, block_dim, and for every array its pointer, shape, strides,
    dtype and device — is recorded; later ones replay it after setting the non-array arguments (scalars,
    vectors, ids), which costs 3-6 µs. A replay is exactly the same launch: the key holds everything the
    recorded parameters hold, so an array freed and reallocated at the same address with the same layout
    is launched correctly, and the cache holds no references to arrays. While a ``wp.Tape`` records,
    launches go through ``wp.launch`` so that autodiff sees them, and so do launches on arrays that require
    gradients: recorded steps write into fresh arrays each time, so their signatures never repeat and
    recording them would only evict the replayable launches of the gradient-free path.
    """
    if _tape_active():
        wp.launch(kernel, dim, inputs, device=device, block_dim=block_dim)
        return
    parts: list = [kernel, dim, str(device), block_dim]
    scalars = []
    for k, a in enumerate(inputs):
        if isinstance(a, wp.array):
            if a.requires_grad:
                wp.launch(kernel, dim, inputs, device=device, block_dim=block_dim)
                return
            parts.append((a.ptr, a.shape, a.strides, a.dtype, a.device.alias))  # type: ignore[union-attr]
        elif isinstance(a, (int, float, bool)) or type(a).__module__.startswith("warp"):
            parts.append(type(a))
            scalars.append(k)
        else:  # indexed/fabric arrays, structs: no replay
            wp.launch(kernel, dim, inputs, device=device, block_dim=block_dim)
            return
    key = tuple(parts)
    hit = _LAUNCHES.get(key)
    if hit is None:
        cmd = wp.launch(kernel, dim, inputs, device=device, record_cmd=True, block_dim=block_dim)
        # The recorded parameters hold raw pointers; the argument list is only needed by Warp's launch
        # capture (APIC). Dropping it lets the arrays of a deleted model be freed: the cache would otherwise
        # keep them alive.
        if hasattr(cmd, "fwd_args"):
            cmd.fwd_args = None
        if len(_LAUNCHES) >= _LAUNCHES_MAX:
            _LAUNCHES.clear()
        _LAUNCHES[key] = (cmd, tuple(scalars))
    else:
        cmd, idx = hit
        for k in idx:
            cmd.set_param_at_index(k, inputs[k])
    try:
        cmd.launch()
    except RuntimeError:  # a launch capture that needs the argument list: launch the ordinary way
        wp.launch(kernel, dim, inputs, device=device, block_dim=block_dim)


# ----------------------------------------------------------------------------------------------- gradients
class ParticleModel(Protocol):
    """What this bottom layer reads of a :class:`pliant.model.Model` (a higher layer it may not name)."""

    @property
    def particle_count(self) -> int: ...
    @property
    def dtype(self) -> str: ...
    @property
    def requires_grad(self) -> bool: ...
    @property
    def device(self) -> str: ...
    @property
    def vec3(self) -> type: ...


class GradientError(NotImplementedError):
    """A gradient was requested (a ``requires_grad`` model, or ``pl.diff``) from a solver, option or
    parameter that cannot give a correct one; the message says what to use instead."""


def grad_enabled(model: object) -> bool:
    """True when steps on ``model`` must be replayable by ``wp.Tape`` (the model was finalised with
    ``requires_grad=True``): solvers then write every intermediate into a fresh array allocated with
    ``requires_grad`` instead of reusing scratch buffers in place."""
    return bool(getattr(model, "requires_grad", False))


def fresh(model: ParticleModel, count: int | None = None, dtype: type | None = None) -> wp.array:
    """A new zeroed array of ``count`` (default: particle_count) ``dtype`` (default: the model's vec3) with
    ``requires_grad=True``, for one use inside a recorded step."""
    n = model.particle_count if count is None else count
    return wp.zeros(n, dtype=model.vec3 if dtype is None else dtype, device=model.device, requires_grad=True)


# Importing any layer initialises Warp once, quietly (pliant/__init__.py no longer does: it loads lazily).
init()
