"""The class registries (``pl.integrators.ALL_INTEGRATORS``, ``pl.energies.ALL_ENERGIES``,
``pl.constraints.ALL_CONSTRAINTS``): found by walking a base class's subclasses, not written as lists."""

from __future__ import annotations

import inspect
from collections.abc import Callable


def registered_subclasses(base: type, keep: Callable[[type], bool] | None = None) -> tuple[type, ...]:
    """Every concrete, public subclass of ``base`` that exists now (at any depth), sorted by name.

    A class is left out when its name starts with ``_`` (private helpers, tests' throw-away classes), when
    it is abstract (:func:`inspect.isabstract`: an ``abc`` method is still missing) or when ``keep(cls)``
    is False. A class defined anywhere — a user's module, a test — is found once its class statement has
    run, and forgotten once it is garbage-collected (``__subclasses__`` holds weak references).

    Args:
        base: the root class (not itself returned unless a subclass of itself, which cannot happen).
        keep: an extra test (e.g. "can be made without arguments"); default: keep all.

    Returns:
        The classes, sorted by ``__name__`` then module, each once.
    """
    found: set[type] = set()
    todo: list[type] = list(base.__subclasses__())
    while todo:
        cls = todo.pop()
        todo.extend(cls.__subclasses__())
        if cls.__name__.startswith("_") or inspect.isabstract(cls):
            continue
        if keep is None or keep(cls):
            found.add(cls)
    return tuple(sorted(found, key=lambda c: (c.__name__, c.__module__)))
