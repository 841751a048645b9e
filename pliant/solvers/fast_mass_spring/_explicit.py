"""FastMassSpring's explicit step (symplectic Euler): the per-particle gather kernel (one fused launch, CUDA's
choice) and the per-spring scatter with its update kernel (two launches, the CPU's choice); see
:mod:`pliant.solvers.fast_mass_spring._solver` for why each device gets which."""

from __future__ import annotations

from typing import Any

import warp as wp

from ...energies._spring import dashpot_force_axis, spring_gradient_axis
from ...integrators._symplectic import symplectic_particle


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
        prm = adj_param[e]  # (rest length, stiffness, dashpot γ)
        # The energies' own spring force and dashpot (issue 10: one definition of each), |d| taken once.
        d = xi - x_in[j]
        l = wp.length(d)
        f -= spring_gradient_axis(d, l, prm[1], prm[0])
        if damped != 0:
            f += dashpot_force_axis(d, l, vi, v_in[j], prm[2])
    w = particle_inv_mass[i]
    x, v = symplectic_particle(w, xi, vi, gravity + w * f, dt, delta)
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
