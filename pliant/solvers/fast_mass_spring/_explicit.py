"""FastMassSpring's explicit step (symplectic Euler): the per-particle gather kernel (one fused launch, CUDA's
choice) and the per-spring scatter with its update kernel (two launches, the CPU's choice); see
:mod:`pliant.solvers.fast_mass_spring._solver` for why each device gets which.

The gather comes in three variants (``FastMassSpring(gather=...)``), because on CUDA a small cloth's step is
latency-bound: a thread runs its 8-12 springs one after another, each a chain of dependent loads (CSR
offset -> neighbour index -> neighbour position), with too few threads to hide it.

* ``"loop"``: one spring per iteration (the reference);
* ``"unrolled"``: the row in chunks of 4 springs, a chunk's loads issued before any of its arithmetic
  (indices past the row's end are clamped to its last entry and their terms dropped), summed in the loop's
  order: bit for bit the loop's step;
* ``"ell"``: the rows in ELL layout, column-major (slot k of every particle contiguous: a warp's loads of
  a slot are one coalesced read, where CSR rows are 48 B apart), with the slot loop unrolled at build time
  (:func:`ell_gather_kernel`: one kernel per slot count, a multiple of 4 up to :data:`ELL_MAX_SLOTS`) so
  that the whole row's loads can be issued before its arithmetic; slots past a row's end repeat its last
  entry and are not added (a select, no branch): bit for bit the loop's step;
* ``"tiled"`` / ``"tiled16"``: a block of 32 / 16 lanes per particle (``wp.launch_tiled``;
  :data:`TILE_LANES`), one spring per lane, reduced with ``wp.tile_sum``; lane 0 writes the update. Another
  summation order: equal to round-off. On the CPU a block is one lane (Warp runs tiles there with
  ``block_dim`` 1), which sums the springs in the loop's order and adds the external force last.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import warp as wp

from ...energies import dashpot_force_axis, spring_gradient_axis
from ...integrators import symplectic_particle

#: Lanes per particle of each tiled gather variant on CUDA: a warp (the reduction stays in shuffles), or half
#: of one (fewer idle lanes on rows of 8-12 springs, at most 32 resident blocks per SM).
TILE_LANES = {"tiled": 32, "tiled16": 16}


@wp.func
def _add_spring(f: Any, xi: Any, vi: Any, xj: Any, v_in: wp.array(dtype=Any), j: int, prm: Any, damped: int):
    """f − ∇E_spring (+ the dashpot's force when ``damped``) of one spring of particle i (prm: rest length,
    stiffness, dashpot γ); the energies' own definitions (issue 10: one of each), |d| taken once."""
    d = xi - xj
    l = wp.length(d)
    g = f - spring_gradient_axis(d, l, prm[1], prm[0])
    if damped != 0:
        g += dashpot_force_axis(d, l, vi, v_in[j], prm[2])
    return g


@wp.kernel
def _symplectic_gather(
    # Model (packed):
    adj_offsets: wp.array(dtype=wp.int32),
    adj_neighbor: wp.array(dtype=wp.int32),
    adj_param: wp.array(dtype=Any),
    particle_inv_mass: wp.array(dtype=Any),
    gravity: Any,
    damped: int,
    # Control:
    f_ext: wp.array(dtype=Any),
    # State in:
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    dt: Any,
    delta: Any,
    # Out:
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    i = wp.tid()
    xi = x_in[i]
    vi = v_in[i]
    f = f_ext[i]
    for e in range(adj_offsets[i], adj_offsets[i + 1]):
        j = adj_neighbor[e]
        f = _add_spring(f, xi, vi, x_in[j], v_in, j, adj_param[e], damped)
    w = particle_inv_mass[i]
    x, v = symplectic_particle(w, xi, vi, gravity + w * f, dt, delta)
    x_out[i] = x
    v_out[i] = v


@wp.kernel
def _symplectic_gather_unrolled(
    # Model (packed):
    adj_offsets: wp.array(dtype=wp.int32),
    adj_neighbor: wp.array(dtype=wp.int32),
    adj_param: wp.array(dtype=Any),
    particle_inv_mass: wp.array(dtype=Any),
    gravity: Any,
    damped: int,
    # Control:
    f_ext: wp.array(dtype=Any),
    # State in:
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    dt: Any,
    delta: Any,
    # Out:
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    """:func:`_symplectic_gather` with the row read 4 springs at a time: the four index
    loads, then the four positions and parameters, none waiting on the previous spring's arithmetic. Entries
    past the row's end read its last entry again (valid memory, no branch before the loads) and are not
    added; the terms are added in the loop's order, so the step is the loop's bit for bit."""
    i = wp.tid()
    xi = x_in[i]
    vi = v_in[i]
    f = f_ext[i]
    start = adj_offsets[i]
    end = adj_offsets[i + 1]
    last = end - 1
    for e in range(start, end, 4):
        e1 = wp.min(e + 1, last)
        e2 = wp.min(e + 2, last)
        e3 = wp.min(e + 3, last)
        j0 = adj_neighbor[e]
        j1 = adj_neighbor[e1]
        j2 = adj_neighbor[e2]
        j3 = adj_neighbor[e3]
        x0 = x_in[j0]
        x1 = x_in[j1]
        x2 = x_in[j2]
        x3 = x_in[j3]
        p0 = adj_param[e]
        p1 = adj_param[e1]
        p2 = adj_param[e2]
        p3 = adj_param[e3]
        f = _add_spring(f, xi, vi, x0, v_in, j0, p0, damped)
        if e + 1 < end:
            f = _add_spring(f, xi, vi, x1, v_in, j1, p1, damped)
        if e + 2 < end:
            f = _add_spring(f, xi, vi, x2, v_in, j2, p2, damped)
        if e + 3 < end:
            f = _add_spring(f, xi, vi, x3, v_in, j3, p3, damped)
    w = particle_inv_mass[i]
    x, v = symplectic_particle(w, xi, vi, gravity + w * f, dt, delta)
    x_out[i] = x
    v_out[i] = v


#: Most springs per particle the "ell" gather takes (its slot loop is unrolled when the kernel is built).
ELL_MAX_SLOTS = 16


def ell_layout(offsets: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """The ELL form of CSR rows ``offsets`` [N + 1]: (slots, count [N], entry [slots · N]) with ``entry[k · N
    + i]`` the CSR entry of particle i's k-th spring (k < count[i]), else its last one (0 for a particle
    without springs); ``slots`` is the longest row rounded up to a multiple of 4 (at least 4).

    Raises:
        ValueError: a row longer than :data:`ELL_MAX_SLOTS` (use ``gather="unrolled"``).
    """
    offsets = np.asarray(offsets, np.int64)
    n = offsets.shape[0] - 1
    count = np.diff(offsets)
    longest = int(count.max(initial=0))
    if longest > ELL_MAX_SLOTS:
        raise ValueError(
            f'gather="ell" holds at most {ELL_MAX_SLOTS} springs per particle; this model has a particle '
            f'with {longest}: use gather="unrolled" (or "loop")'
        )
    slots = max(4, -(-longest // 4) * 4)
    k = np.arange(slots)[:, None]
    entry = offsets[None, :-1] + np.minimum(k, np.maximum(count - 1, 0)[None, :])
    entry[:, count == 0] = 0  # any valid entry (its term is not selected); off[i] may be past the end
    return slots, count.astype(np.int32), entry.reshape(slots * n)


class EllRows(NamedTuple):
    """FastMassSpring's spring rows in the "ell" gather's layout (:func:`ell_layout`), on the device."""

    slots: int  # the unrolled slot count of the kernel that reads them
    lengths: wp.array  # springs per particle [N] (int32)
    neighbor: wp.array  # the other end of slot k of particle i, at k·N + i (int32)
    param: wp.array  # (rest length, k, γ) of that slot (vec3), packed by ``pack``
    entry: np.ndarray  # the CSR entry each slot repeats (host; packs the parameters)

    @classmethod
    def build(cls, offsets: np.ndarray, neighbor: np.ndarray, vec3: type, device: str) -> EllRows:
        """The ELL rows of CSR ``offsets`` [N + 1] and ``neighbor`` [entries] (see :func:`ell_layout`)."""
        slots, count, entry = ell_layout(offsets)
        nb = neighbor[entry] if neighbor.shape[0] else np.zeros(entry.shape, np.int32)
        return cls(
            slots,
            wp.array(count, dtype=wp.int32, device=device),
            wp.array(nb, dtype=wp.int32, device=device),
            wp.zeros(entry.shape[0], dtype=vec3, device=device),
            entry,
        )

    def pack(self, per_entry: np.ndarray) -> None:
        """Write the CSR entries' parameters [entries, 3] into the slots, in place (graphs keep ``param``)."""
        self.param.assign(per_entry[self.entry])


_ELL_KERNELS: dict[int, wp.Kernel] = {}


def ell_gather_kernel(slots: int) -> wp.Kernel:
    """The "ell" gather kernel for rows of at most ``slots`` springs (built once per slot count)."""
    kernel = _ELL_KERNELS.get(slots)
    if kernel is None:
        kernel = _ELL_KERNELS[slots] = _make_ell_gather(slots)
    return kernel


def _make_ell_gather(slots: int) -> wp.Kernel:
    @wp.kernel(module="unique")
    def _symplectic_gather_ell(
        # Model (packed, ELL: slot k of particle i at k·N + i):
        ell_count: wp.array(dtype=wp.int32),
        ell_neighbor: wp.array(dtype=wp.int32),
        ell_param: wp.array(dtype=Any),
        particle_inv_mass: wp.array(dtype=Any),
        gravity: Any,
        damped: int,
        # Control:
        f_ext: wp.array(dtype=Any),
        # State in:
        x_in: wp.array(dtype=Any),
        v_in: wp.array(dtype=Any),
        dt: Any,
        delta: Any,
        # Out:
        x_out: wp.array(dtype=Any),
        v_out: wp.array(dtype=Any),
    ):
        # :func:`_symplectic_gather` over ELL slots, unrolled (wp.static): no load waits on a previous
        # slot's arithmetic; a slot past the row's end (its last entry again) is computed and not selected.
        i = wp.tid()
        n = x_in.shape[0]
        xi = x_in[i]
        vi = v_in[i]
        f = f_ext[i]
        count = ell_count[i]
        for k in range(wp.static(slots)):
            e = k * n + i
            j = ell_neighbor[e]
            g = _add_spring(f, xi, vi, x_in[j], v_in, j, ell_param[e], damped)
            f = wp.where(k < count, g, f)
        w = particle_inv_mass[i]
        x, v = symplectic_particle(w, xi, vi, gravity + w * f, dt, delta)
        x_out[i] = x
        v_out[i] = v

    return _symplectic_gather_ell


@wp.kernel
def _symplectic_gather_tiled(
    # Model (packed):
    adj_offsets: wp.array(dtype=wp.int32),
    adj_neighbor: wp.array(dtype=wp.int32),
    adj_param: wp.array(dtype=Any),
    particle_inv_mass: wp.array(dtype=Any),
    gravity: Any,
    damped: int,
    # Control:
    f_ext: wp.array(dtype=Any),
    # State in:
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    dt: Any,
    delta: Any,
    # Out:
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    """:func:`_symplectic_gather` with a block of lanes per particle (``wp.launch_tiled``, dim [N] + the
    block): lane k sums springs k, k + block, … of the row, ``wp.tile_sum`` adds the lanes' sums, lane 0
    adds the external force and writes the update."""
    i, lane = wp.tid()
    xi = x_in[i]
    vi = v_in[i]
    f = xi * type(dt)(0.0)
    for e in range(adj_offsets[i] + lane, adj_offsets[i + 1], wp.block_dim()):
        j = adj_neighbor[e]
        f = _add_spring(f, xi, vi, x_in[j], v_in, j, adj_param[e], damped)
    total = wp.tile_sum(wp.tile(f, preserve_type=True))
    if lane == 0:
        w = particle_inv_mass[i]
        x, v = symplectic_particle(w, xi, vi, gravity + w * (f_ext[i] + total[0]), dt, delta)
        x_out[i] = x
        v_out[i] = v


@wp.kernel
def _springs_scatter(
    spring_pairs: wp.array(dtype=wp.vec2i),
    spring_rest_length: wp.array(dtype=Any),
    spring_stiffness: wp.array(dtype=Any),
    spring_damping: wp.array(dtype=Any),
    damped: int,
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    f_out: wp.array(dtype=Any),
):
    """Spring ``s``'s force and dashpot, added to its two ends (the CPU's symplectic step: each spring
    evaluated once; CPU launches are sequential, so the atomic adds are plain adds and the sum order is
    fixed — the run is deterministic)."""
    s = wp.tid()
    ij = spring_pairs[s]  # one 8-byte load: 15 % faster than two reads of an [S, 2] array
    i = ij[0]
    j = ij[1]
    d = x_in[i] - x_in[j]
    l = wp.length(d)
    fi = -spring_gradient_axis(d, l, spring_stiffness[s], spring_rest_length[s])
    if damped != 0:
        fi += dashpot_force_axis(d, l, v_in[i], v_in[j], spring_damping[s])
    wp.atomic_add(f_out, i, fi)
    wp.atomic_sub(f_out, j, fi)


@wp.kernel
def _symplectic_update(
    particle_inv_mass: wp.array(dtype=Any),
    gravity: Any,
    f_ext: wp.array(dtype=Any),
    x_in: wp.array(dtype=Any),
    v_in: wp.array(dtype=Any),
    dt: Any,
    delta: Any,
    f_springs_io: wp.array(dtype=Any),
    x_out: wp.array(dtype=Any),
    v_out: wp.array(dtype=Any),
):
    """v¹ = δ(v + Δt(g + w f)), x¹ = x + Δt v¹ from the scattered spring forces, which it clears for the
    next step."""
    i = wp.tid()
    f = f_springs_io[i] + f_ext[i]
    f_springs_io[i] = f * type(dt)(0.0)
    w = particle_inv_mass[i]
    x, v = symplectic_particle(w, x_in[i], v_in[i], gravity + w * f, dt, delta)
    x_out[i] = x
    v_out[i] = v
