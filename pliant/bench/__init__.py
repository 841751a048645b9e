"""Benchmarks run by ``pliant bench``: fixed scenes, one JSON-serialisable dict each.

Every private module ``pliant/bench/_<topic>.py`` defines ``BENCHMARKS: dict[str, Callable[..., dict]]``;
this package discovers them, so adding a benchmark touches one file. A benchmark accepts the keyword
arguments it declares among ``device`` (``None``: the default device) and ``quick`` (smaller problem, for
smoke tests), and returns the figures DESIGN.md lists: scene, solver, integrator, device, particles,
elements, substeps, wall seconds after warm-up, compile seconds, throughput, and a physical sanity figure.

Example::

    from pliant import bench
    print(sorted(bench.discover()))
    result = bench.run("render_cloth", quick=True)
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
from collections.abc import Callable
from typing import Any

Benchmark = Callable[..., dict]


def discover() -> dict[str, Benchmark]:
    """All benchmarks by name, from the ``BENCHMARKS`` dict of every ``pliant.bench._*`` module."""
    found: dict[str, Benchmark] = {}
    where: dict[str, str] = {}
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda i: i.name):
        if not info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{__name__}.{info.name}")
        table = getattr(mod, "BENCHMARKS", None)
        if table is None:
            continue
        if not isinstance(table, dict):
            raise TypeError(f"{mod.__name__}.BENCHMARKS must be a dict of name -> callable")
        for name, fn in table.items():
            if name in found:
                raise ValueError(f"benchmark {name!r} is defined in both {where[name]} and {mod.__name__}")
            found[name], where[name] = fn, mod.__name__
    return found


def run(name: str, **options: Any) -> dict:
    """Run one benchmark, passing only the ``options`` it accepts; adds ``"benchmark": name``."""
    table = discover()
    if name not in table:
        raise KeyError(f"unknown benchmark {name!r}; available: {', '.join(sorted(table))}")
    fn = table[name]
    params = inspect.signature(fn).parameters
    kwargs = {k: v for k, v in options.items() if k in params and v is not None}
    return {"benchmark": name, **fn(**kwargs)}


__all__ = ["Benchmark", "discover", "run"]
