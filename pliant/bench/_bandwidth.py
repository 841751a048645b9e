"""Memory traffic of the drape's explicit step: bytes a substep must move, and the fraction of the device's
peak bandwidth a row reached.

``bytes_per_substep`` is the compulsory traffic of one :class:`~pliant.solvers.FastMassSpring` symplectic
step, counted from the sizes and dtypes of the arrays its kernels read and write, each element once: a
particle's neighbours' positions are re-reads of the same ``x`` array, assumed to hit the cache, so they are
counted once with ``x``; what no cache can save (every array touched at least once) is the floor. On CUDA the
step is one gather kernel over particles; on the CPU a per-spring scatter plus an update kernel (the solver's
module docstring says why), whose scratch force array is read and written twice. The drape has no ground,
no dashpots (the dashpot reads are skipped by the kernels) and no contact handlers, so nothing else runs.

``peak_bandwidth`` is the device's theoretical DRAM bandwidth. Warp does not expose it (its ``Device`` has
name, arch, SM count, memory size); it is read from the CUDA driver instead (``cuDeviceGetAttribute``: memory
clock [kHz] and bus width [bits], double data rate), or None where the driver cannot be asked (the CPU).
"""

from __future__ import annotations

import ctypes
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..solvers import FastMassSpring

#: cuDeviceGetAttribute's CU_DEVICE_ATTRIBUTE_MEMORY_CLOCK_RATE [kHz] and ..._GLOBAL_MEMORY_BUS_WIDTH [bits].
_MEMORY_CLOCK_RATE, _BUS_WIDTH = 36, 37


def bytes_per_substep(solver: FastMassSpring) -> int:
    """Bytes one symplectic step of ``solver`` must read and write [B] (each array element once), from the
    arrays' lengths and dtypes; the kernel is ``solver.kernel`` ("gather" on CUDA, "scatter" on the CPU).

    gather: per particle x, v, f_ext read, x', v' written (vec3 each), 1/m read, the CSR row offset; per
    adjacency entry (two per spring) the neighbour index and the packed (rest, k, γ). scatter: per spring the
    index pair, rest length and k; per particle x read by the springs, the scratch force read and written by
    their atomic adds, then 1/m, f_ext, x, v, the scratch force read and cleared, x', v' written; v and γ
    are read in the scatter only with dashpots.
    """
    import warp as wp

    if solver.method != "symplectic":
        raise ValueError(f"bytes_per_substep counts the symplectic step; this solver is {solver.method!r}")
    m = solver.model
    s = wp.types.type_size_in_bytes(m.particle_q.dtype) // 3  # the scalar: 4 (float32) or 8 (float64)
    n, springs = m.particle_count, m.spring_count
    vec = 3 * s
    damped = bool(springs) and bool((m.spring_damping.numpy() > 0).any())
    if solver.kernel == "gather":
        entries = solver.adj_neighbor.shape[0]
        index = wp.types.type_size_in_bytes(solver.adj_neighbor.dtype)
        offsets = solver.adj_offsets.shape[0] * wp.types.type_size_in_bytes(solver.adj_offsets.dtype)
        particles = n * (5 * vec + s)  # x, v, f_ext read; x', v' written; 1/m
        return offsets + entries * (index + vec) + particles
    pair = 2 * wp.types.type_size_in_bytes(m.spring_indices.dtype)
    # springs: pair, rest, k (+ γ with dashpots); particles: x (+ v with dashpots), f read + written
    scatter = springs * (pair + (3 if damped else 2) * s) + n * (3 * vec + (vec if damped else 0))
    update = n * (s + 7 * vec)  # 1/m; f_ext, x, v, f read; f cleared; x', v' written
    return scatter + update


def peak_bandwidth(device: str) -> float | None:
    """Theoretical DRAM bandwidth of CUDA ``device`` [B/s]: 2 × memory clock × bus width / 8, from the CUDA
    driver (Warp does not expose it); None on the CPU or where the driver cannot be asked."""
    import warp as wp

    dev = wp.get_device(device)
    if not dev.is_cuda:
        return None
    try:
        cuda = ctypes.CDLL("libcuda.so.1")
        handle, clock, width = ctypes.c_int(), ctypes.c_int(), ctypes.c_int()
        if cuda.cuDeviceGet(ctypes.byref(handle), dev.ordinal) != 0:
            return None
        if cuda.cuDeviceGetAttribute(ctypes.byref(clock), _MEMORY_CLOCK_RATE, handle) != 0:
            return None
        if cuda.cuDeviceGetAttribute(ctypes.byref(width), _BUS_WIDTH, handle) != 0:
            return None
    except (OSError, AttributeError):
        return None
    return dram_bandwidth(clock.value, width.value)


def dram_bandwidth(clock_khz: int, bus_bits: int) -> float | None:
    """Peak bandwidth [B/s] of DRAM at ``clock_khz`` [kHz] on a ``bus_bits``-bit bus, two transfers per clock
    (what CUDA's memory clock attribute counts for GDDR and HBM alike); None if either is not positive."""
    if clock_khz <= 0 or bus_bits <= 0:
        return None
    return 2.0 * clock_khz * 1e3 * bus_bits / 8.0


def bandwidth_fields(solver: FastMassSpring, substeps_done: int, wall: float, device: str) -> dict:
    """The traffic columns of a symplectic drape row: ``bytes_per_substep`` [B], ``achieved_bandwidth_gbs``
    (bytes × ``substeps_done`` / ``wall`` [GB/s]), ``peak_bandwidth_gbs`` and ``bandwidth_fraction`` (None
    without a peak: the CPU, or a driver that cannot be asked)."""
    moved = bytes_per_substep(solver)
    achieved = moved * substeps_done / wall if wall > 0 else float("nan")
    peak = peak_bandwidth(device)
    return {
        "bytes_per_substep": moved,
        "achieved_bandwidth_gbs": round(achieved / 1e9, 3),
        "peak_bandwidth_gbs": None if peak is None else round(peak / 1e9, 1),
        "bandwidth_fraction": None if peak is None else round(achieved / peak, 4),
    }
