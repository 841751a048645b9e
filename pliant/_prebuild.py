"""A fast first frame on a fresh kernel cache: compile what a run needs early, on every core, once.

Warp compiles a module the first time one of its kernels is launched, one module after another on the thread
that launches. On the CPU three costs dominate a fresh start (measured on the 2-core CI box, Warp 1.19):

1. Clang builds a precompiled header (PCH) of Warp's native headers before the first module: about 1.6 s.
   Warp keeps one PCH directory *per thread*, so a second compiling thread would build it again.
2. Every further module costs 0.13-0.3 s (1.8 s for the neo-Hookean Hessian); a scene needs 8-18 of them.
3. A module whose generic kernels are launched with new types one after another is compiled again for
   each (the Newton solver's module was compiled five times for the FEM box).

So pliant (a) shares one PCH between threads and lets the first build make it while the others wait
(:func:`share_precompiled_header`); (b) starts that first build on a background thread as soon as the CLI
starts, overlapping the PCH with Python's imports and the scene's build (:func:`warm_up`); and (c) for a
built-in scene, registers every kernel overload the scene will launch (a manifest recorded from a run,
``pliant/scenes/kernels.json``) and compiles all its modules at once on two threads before the first step
(:func:`prebuild`). The manifest only speeds things up: an entry that no longer matches a kernel is skipped,
and a kernel missing from it is compiled on first launch as before.
"""

from __future__ import annotations

import builtins
import functools
import importlib
import inspect
import json
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import warp as wp

if TYPE_CHECKING:
    from ._warp import ParticleModel

#: Built-in scenes' manifests: {scene: {"modules": [...], "overloads": [...]}} (float32, CPU).
MANIFEST = Path(__file__).resolve().parent / "scenes" / "kernels.json"

_lock = threading.Lock()
_pch_ready = threading.Event()
_pch: dict[str, Any] = {"dir": None}
_threads: list[threading.Thread] = []
_queued: set[tuple[str, str]] = set()  # (device, module) handed to a background build already


def share_precompiled_header() -> bool:
    """Make every thread use one Clang PCH directory; the first CPU build creates it, the others wait.

    Returns False (and changes nothing) when this Warp's CPU build has no ``pch_dir`` argument.
    """
    try:
        import warp._src.build as wb
    except ImportError:  # a Warp without this layout: keep its own behaviour
        return False
    orig = wb.build_cpu
    if getattr(orig, "_pliant_shared_pch", False):
        return True
    params = inspect.signature(orig).parameters
    if "pch_dir" not in params and not any(p.kind is p.VAR_KEYWORD for p in params.values()):
        return False

    def build_cpu(*args: Any, **kwargs: Any) -> Any:
        if not (kwargs.get("use_precompiled_headers") and kwargs.get("pch_dir")):
            return orig(*args, **kwargs)
        with _lock:
            first = _pch["dir"] is None
            if first:
                _pch["dir"] = kwargs["pch_dir"]
        if not first:
            _pch_ready.wait()
            kwargs["pch_dir"] = _pch["dir"]
        try:
            return orig(*args, **kwargs)
        finally:
            if first:
                _pch_ready.set()  # also after a failed build: the others then build without waiting

    build_cpu._pliant_shared_pch = True  # type: ignore[attr-defined]
    wb.build_cpu = build_cpu
    _hold_main_thread()
    return True


def _hold_main_thread() -> None:
    """Make the main thread wait for the background builds before it loads a module itself: every launch
    (pliant's or a direct ``wp.launch``) goes through ``Module.load``, so no module is ever built twice."""
    from warp._src import context

    orig = context.Module.load
    if getattr(orig, "_pliant_wait", False):
        return

    def load(self: Any, *args: Any, **kwargs: Any) -> Any:
        if _threads and threading.current_thread() is threading.main_thread():
            wait()
        return orig(self, *args, **kwargs)

    load._pliant_wait = True  # type: ignore[attr-defined]
    context.Module.load = load  # type: ignore[method-assign]  # wrapped on purpose (see above)


def _start(target: Callable[[], object]) -> None:
    t = threading.Thread(target=target, name="pliant-prebuild", daemon=True)
    _threads.append(t)
    t.start()


@wp.kernel
def _first(out: wp.array(dtype=wp.float32)):
    # The smallest kernel: its build exists to make Clang's precompiled header (the first build's cost).
    out[wp.tid()] = 0.0


def warm_up(device: str | None = None) -> None:
    """Start a first CPU build on a background thread, which makes the shared precompiled header while the
    caller imports and builds its scene.

    Nothing happens for a CUDA device, or when the tiny module is cached already (a cache that is not
    fresh: then most modules are cached too).

    Args:
        device: the device the run will use (None: Warp's default).
    """
    from ._warp import init

    init()
    dev = wp.get_device(device)
    if not dev.is_cpu or not share_precompiled_header():
        return

    def work() -> None:
        try:
            wp.force_load(device=dev, modules=[_first.module], max_workers=0)
        except Exception:  # a speed-up only: the next build makes the header instead
            pass

    _start(work)


def wait() -> None:
    """Block until background compilation has finished (called before a launch that could compile)."""
    while _threads:  # empty after the first call: one list check per launch
        t = _threads[0]
        if t.is_alive() and t is not threading.current_thread():
            t.join()
        if _threads and _threads[0] is t:
            _threads.pop(0)


# ---------------------------------------------------------------------------------------------- manifests
def _type_json(t: Any) -> str | dict[str, Any] | None:  # any Warp type: read by duck typing
    """A kernel argument type as JSON, or None when it cannot be written (structs, indexed arrays)."""
    if type(t) is wp.array or type(t).__name__ == "_ArrayAnnotation":  # not indexed or fabric arrays
        dtype = _type_json(t.dtype)
        return None if dtype is None else {"array": int(t.ndim), "dtype": dtype}
    if wp.types.type_is_vector(t) or wp.types.type_is_matrix(t):  # also those made by wp.types.vector(...)
        shape = list(getattr(t, "_shape_", (t._length_,)))
        scalar = _type_json(t._wp_scalar_type_)
        return None if scalar is None else {"shape": shape, "dtype": scalar}
    name = getattr(t, "__name__", None)
    if name in ("int", "float", "bool") and getattr(builtins, name) is t:
        return name
    if name is not None and getattr(wp, name, None) is t:
        return name
    return None


def _type_from_json(d: Any) -> Any:
    if isinstance(d, dict) and "shape" in d:
        shape, scalar = d["shape"], _type_from_json(d["dtype"])
        return wp.types.vector(shape[0], scalar) if len(shape) == 1 else wp.types.matrix(tuple(shape), scalar)
    if isinstance(d, dict):
        return wp.array(dtype=_type_from_json(d["dtype"]), ndim=int(d["array"]))
    if d in ("int", "float", "bool"):
        return getattr(builtins, d)
    t = getattr(wp, d, None)
    if t is None:
        raise KeyError(d)
    return t


def _user_modules() -> dict[str, Any]:
    from warp._src import context

    return dict(context.user_modules)


_compile_ms: dict[str, float] = {}


def module_of_object(path: str) -> str:
    """The Warp module a CPU object file belongs to: Warp names it wp_<module>_<hash>.cpu<arch>.o."""
    return Path(path).name.removeprefix("wp_").rsplit(".cpu", 1)[0].rsplit("_", 1)[0]


def time_compiles() -> None:
    """From now on, note each CPU module build's seconds (for :func:`record`'s ``compile_ms``)."""
    import time

    import warp._src.build as wb

    orig = wb.build_cpu

    def build_cpu(obj_path: str, *args: Any, **kwargs: Any) -> Any:
        t = time.perf_counter()
        try:
            return orig(obj_path, *args, **kwargs)
        finally:
            name = module_of_object(obj_path)
            _compile_ms[name] = _compile_ms.get(name, 0.0) + 1e3 * (time.perf_counter() - t)

    wb.build_cpu = build_cpu


def record(prefix: str = "pliant.") -> dict:
    """The modules loaded so far whose name starts with ``prefix`` and their generic kernels' overloads."""
    modules, overloads = [], []
    for name, m in sorted(_user_modules().items()):
        if not name.startswith(prefix) or not m.execs:
            continue
        modules.append(name)
        for key, k in sorted(m.kernels.items()):
            for ov in getattr(k, "overloads", {}).values():
                args = [_type_json(a.type) for a in ov.adj.args]
                if all(a is not None for a in args):
                    overloads.append({"module": name, "kernel": key, "args": args})
    ms = {name: round(_compile_ms[name]) for name in modules if name in _compile_ms}
    return {"modules": modules, "overloads": overloads, "compile_ms": ms}


@functools.cache
def _manifests() -> dict:
    """Every stored manifest, read once per process (each run asks for one)."""
    try:
        return json.loads(MANIFEST.read_text())
    except (OSError, ValueError):
        return {}


#: Environment switch: PLIANT_PREBUILD=0 turns the background compilation off.
ENV = "PLIANT_PREBUILD"


def enabled() -> bool:
    """Whether background compilation is on (``PLIANT_PREBUILD`` is not ``0``)."""
    return os.environ.get(ENV, "1") != "0"


def maybe_prebuild(name: str, model: ParticleModel) -> int:
    """Start compiling built-in scene ``name``'s kernels (``Scene.prebuild_kernels`` calls this) when
    ``model`` is float32 on the CPU without gradients (what the manifest was recorded for) and
    :func:`enabled`.

    Args:
        name: the scene's name (``[scene] name``); scenes without a stored manifest queue nothing.
        model: the built :class:`~pliant.model.Model` (its dtype, device and ``requires_grad``).

    Returns the number of modules queued."""
    if (
        not enabled()
        or model.dtype != "float32"
        or model.requires_grad
        or not str(model.device).startswith("cpu")
    ):
        return 0
    manifest = manifest_for(name)
    return 0 if manifest is None else prebuild(manifest, model.device)


def manifest_for(scene: str) -> dict | None:
    """The stored manifest of built-in ``scene`` (None when there is none)."""
    return _manifests().get(scene)


def register_overloads(manifest: dict) -> set[str]:
    """Import ``manifest``'s modules and register its generic kernels' overloads (no compilation).

    Entries that no longer match a kernel are skipped. Returns the names of the modules that gained an
    overload (a module queued before must then be built again). Also used by tests/cuda_compile.py, which
    compiles every registered overload for CUDA without a GPU.
    """
    for name in manifest.get("modules", []):
        if name not in _user_modules():
            try:  # a Python module whose kernels are not imported yet (e.g. the simulator's)
                importlib.import_module(name)
            except ImportError:  # a module a factory names: created by the objects that use it
                pass
    mods = _user_modules()
    grown: set[str] = set()
    for entry in manifest.get("overloads", []):
        m = mods.get(entry["module"])
        k = None if m is None else m.kernels.get(entry["kernel"])
        if k is None or not k.is_generic:
            continue
        before = len(k.overloads)
        try:
            wp.overload(k, [_type_from_json(a) for a in entry["args"]])
        except Exception:  # a changed signature: the launch compiles what it needs
            continue
        if len(k.overloads) > before:
            grown.add(entry["module"])
    return grown


def prebuild(manifest: dict, device: str | None = None, workers: int = 2) -> int:
    """Register ``manifest``'s overloads and compile its modules on ``workers`` background threads.

    Modules not created yet in this process, modules an earlier call queued and this one adds no overload
    to (a sweep or a fit builds the same scene many times) and entries that no longer match a kernel are
    skipped. Call :func:`wait` before launching. Returns the number of modules queued.

    Args:
        manifest: ``{"modules": [...], "overloads": [...]}`` as :func:`record` writes it.
        device: the device to compile for (None: Warp's default).
        workers: threads compiling at once.
    """
    from ._warp import init

    init()
    dev = wp.get_device(device)
    share_precompiled_header()
    grown = register_overloads(manifest)
    mods = _user_modules()
    # Longest compiles first, so that the two threads finish together (costs recorded with the manifest).
    cost = manifest.get("compile_ms", {})
    names = sorted(manifest.get("modules", []), key=lambda n: -cost.get(n, 0.0))
    todo = [mods[n] for n in names if n in mods and (n in grown or (str(dev), n) not in _queued)]
    if not todo:
        return 0
    _queued.update((str(dev), m.name) for m in todo)
    earlier = list(_threads)

    def work() -> None:
        for t in earlier:  # the warm-up may be compiling one of these modules: never build one twice
            t.join()
        try:
            wp.force_load(device=dev, modules=todo, max_workers=workers)
        except Exception:  # a speed-up only: launches compile on demand
            pass

    _start(work)
    return len(todo)
