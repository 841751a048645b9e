"""Counting what a step or a captured pass would read back from a GPU, on any device.

On CUDA a device-to-host copy inside a stream capture fails the capture (Warp error 906, "operation would
make the legacy stream depend on a capturing blocking stream"), and outside a capture each one stalls the
host until the device drains its queue. On the CPU the same calls are free (``array.numpy()`` of a CPU array
is a view), so a host read hidden in a step goes unseen until somebody runs it on a GPU. :class:`HostReads`
counts the calls that would be reads or uploads on a GPU, whatever the device, so CPU-only CI catches them.
"""

from __future__ import annotations

import traceback
from collections import Counter
from collections.abc import Callable
from typing import Any

import pytest
import warp as wp

from pliant._warp import capturing


class HostReads:
    """Counts, while active (``with HostReads() as reads``), per kind:

    * ``read``: ``array.numpy()``, ``array.list()``, a ``wp.copy`` between two devices (a download or an
      upload), ``wp.synchronize*``;
    * ``upload``: a ``wp.array`` built from host data (NumPy, lists, scalars) on a device, ``array.assign``
      of host data.

    ``capture_only``: count only calls made while a device is capturing a graph. ``where`` keeps each
    counted call's stack (innermost frames last) for the assertion message.
    """

    def __init__(self, capture_only: bool = False) -> None:
        self._mp = pytest.MonkeyPatch()  # its own: leaving undoes only these patches
        self.capture_only = capture_only
        self.counts: Counter[str] = Counter()
        self.where: list[str] = []
        self.active = False

    def __enter__(self) -> HostReads:
        mp, count = self._mp, self._count
        numpy, lst, init, assign = wp.array.numpy, wp.array.list, wp.array.__init__, wp.array.assign
        copy = wp.copy

        def counted_numpy(self: wp.array) -> Any:
            count("read", self.device)
            return numpy(self)

        def counted_list(self: wp.array) -> Any:
            count("read", self.device)
            return lst(self)

        def counted_init(self: wp.array, data: Any = None, *a: Any, **k: Any) -> None:
            init(self, data, *a, **k)
            if data is not None and not isinstance(data, wp.array):
                count("upload", self.device)

        def counted_assign(self: wp.array, src: Any) -> None:
            if not isinstance(src, wp.array):
                count("upload", self.device)
            assign(self, src)

        def counted_copy(dest: wp.array, src: wp.array, *a: Any, **k: Any) -> None:
            if dest.device != src.device:
                count("read", src.device)
            copy(dest, src, *a, **k)

        mp.setattr(wp.array, "numpy", counted_numpy)
        mp.setattr(wp.array, "list", counted_list)
        mp.setattr(wp.array, "__init__", counted_init)
        mp.setattr(wp.array, "assign", counted_assign)
        mp.setattr(wp, "copy", counted_copy)
        for name in ("synchronize", "synchronize_device", "synchronize_stream"):
            mp.setattr(wp, name, self._sync(getattr(wp, name)))
        self.active = True
        return self

    def _sync(self, real: Callable[..., Any]) -> Callable[..., Any]:
        def counted(*a: Any, **k: Any) -> Any:
            self._count("read", None)
            return real(*a, **k)

        return counted

    def __exit__(self, *exc: object) -> None:
        self.active = False
        self._mp.undo()

    def _count(self, kind: str, device: Any) -> None:
        if not self.active:
            return
        if self.capture_only and not (device is not None and capturing(device)):
            return
        self.counts[kind] += 1
        if len(self.where) < 5:
            frames = traceback.format_stack(limit=9)[:-2]
            self.where.append(f"{kind}:\n" + "".join(f for f in frames if "site-packages" not in f))

    def total(self) -> int:
        """Reads and uploads counted so far."""
        return sum(self.counts.values())

    def report(self) -> str:
        """The counts and the first calls' stacks, for an assertion message."""
        return f"{dict(self.counts)}\n" + "\n".join(self.where)
