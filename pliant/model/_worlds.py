"""Worlds: W independent copies of everything a builder holds, stepped together by the same kernels.

``ModelBuilder.replicate(W)`` turns what was added so far into world 0 and appends W − 1 copies, each block
contiguous: world w owns particles [w·P, (w+1)·P), springs [w·S, (w+1)·S), and likewise triangles, tets and
bending elements. Nothing couples two worlds (no element spans them), so every kernel, explicit or
implicit, treats them as one larger model whose matrices are block-diagonal; the ground is shared, as every
world sees the same plane. Per-world parameters are slices of the model's per-element arrays
(:meth:`pliant.model.Model.set_world_parameter`).

Why copies in one model rather than a world axis in every kernel: pliant's kernels are per element and
already index through topology arrays, so a block of copies costs them nothing, keeps one launch for all
worlds on the CPU and on CUDA, and leaves every solver (mass-spring, FEM, XPBD, the implicit ones)
unchanged. The price is that solver-level settings (damping rate, time step, ground friction) are shared.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from ._parameters import RegistryView, parameter

if TYPE_CHECKING:
    import warp as wp

    from ._builder import ModelBuilder
    from ._model import Model, State

#: Element kinds with a per-world block: name → the builder's list of per-call element tuples.
KINDS = ("particle", "spring", "tri", "tet", "bending")


def _count(builder: ModelBuilder, kind: str) -> int:
    if kind == "particle":
        return builder._count
    per_kind: dict[str, Sequence[np.ndarray | tuple[np.ndarray, ...]]] = {
        "spring": builder._springs,
        "tri": builder._tris,
        "tet": builder._tets,
        "bending": builder._bending,
    }
    return int(sum((e[0] if isinstance(e, tuple) else e).shape[0] for e in per_kind[kind]))


def replicate(builder: ModelBuilder, n: int, spacing: Sequence[float] = (0.0, 0.0, 0.0)) -> None:
    """Make ``n`` worlds of what ``builder`` holds (see :meth:`pliant.ModelBuilder.replicate`)."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"replicate: n must be a positive number of worlds, got {n!r}")
    if getattr(builder, "_worlds", None) is not None:
        raise ValueError(
            "replicate: this builder is replicated already; call replicate(n) once, after adding world 0"
        )
    if builder._count == 0:
        raise ValueError("replicate: nothing to copy; add the objects of one world first, then replicate(n)")
    if getattr(builder, "_tets10", None):
        raise ValueError(
            "replicate: quadratic (order = 2) tetrahedra cannot be replicated into worlds yet; use order = 1"
        )
    shift = np.asarray(spacing, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(shift)):
        raise ValueError(f"replicate: spacing must be 3 finite lengths [m], got {spacing!r}")
    n = int(n)
    per = {k: _count(builder, k) for k in KINDS}
    p = per["particle"]
    q0, qd0 = np.concatenate(builder._q), np.concatenate(builder._qd)
    m0, r0 = np.concatenate(builder._mass), np.concatenate(builder._radius)
    builder._q = [q0 + w * shift for w in range(n)]
    builder._qd = [qd0] * n
    builder._mass = [m0] * n
    builder._radius = [r0] * n
    builder._count = n * p
    pinned = np.fromiter(builder._pinned, dtype=np.int64, count=len(builder._pinned))
    builder._pinned = {int(i) + w * p for w in range(n) for i in pinned}
    builder._kinematic = [i + w * p for w in range(n) for i in builder._kinematic]

    def tile(blocks: list, with_params: bool) -> list:
        out = []
        for w in range(n):
            for b in blocks:
                out.append((b[0] + w * p, *b[1:]) if with_params else b + w * p)
        return out

    builder._springs = tile(builder._springs, True)
    builder._tets = tile(builder._tets, True)
    builder._bending = tile(builder._bending, True)
    builder._tris = tile(builder._tris, False)
    builder._render_faces = tile(builder._render_faces, False)
    builder._tet_host = tile(builder._tet_host, False)
    objects = []
    for w in range(n):
        for o in builder.objects:
            objects.append({**o, "start": o["start"] + w * p, "world": w})
    builder.objects = objects
    builder._worlds = {"count": n, "per_world": per}


def offsets(builder: ModelBuilder) -> dict[str, np.ndarray] | None:
    """Per-kind world offsets [W + 1] of a replicated builder, checked; None when not replicated.

    Raises:
        ValueError: elements were added after ``replicate`` (world blocks would no longer be copies).
    """
    worlds = getattr(builder, "_worlds", None)
    if worlds is None:
        return None
    n, per = worlds["count"], worlds["per_world"]
    out = {}
    for k in KINDS:
        if _count(builder, k) != n * per[k]:
            raise ValueError(
                f"replicate: {_count(builder, k)} {k}s for {n} worlds of {per[k]}: something was added after "
                "replicate(n); add every object to world 0 first and call replicate(n) last"
            )
        out[k] = np.arange(n + 1, dtype=np.int64) * per[k]
    return out


#: Per-element parameters a world may set: Model array name → (element kind, unit): every registry
#: parameter (:mod:`pliant.model._parameters`) held in a per-element Model array of a world-blocked kind.
PARAMETERS: Mapping[str, tuple[str, str]] = RegistryView(
    lambda p: p.model_array == p.name and p.per in KINDS, lambda p: (p.per, p.unit)
)


def world_slice(model: Model, kind: str, w: int) -> slice:
    """Element range of world ``w`` for ``kind`` ("particle", "spring", "tri", "tet", "bending")."""
    if kind not in KINDS:
        raise ValueError(f"world_slice: kind must be one of {KINDS}, got {kind!r}")
    n = model.world_count
    if isinstance(w, bool) or not isinstance(w, (int, np.integer)) or not 0 <= w < n:
        raise ValueError(f"world index {w!r} out of range [0, {n}) (the model has {n} worlds)")
    if model.world_offsets is None:  # one world: everything
        total = {
            "particle": model.particle_count,
            "spring": model.spring_count,
            "tri": model.tri_count,
            "tet": model.tet_count,
            "bending": model.bending_count,
        }[kind]
        return slice(0, total)
    off = model.world_offsets[kind]
    return slice(int(off[w]), int(off[w + 1]))


def set_world_parameter(model: Model, name: str, w: int, value: npt.ArrayLike) -> None:
    """Set parameter ``name`` of world ``w`` (see :meth:`pliant.model.Model.set_world_parameter`)."""
    import warp as wp

    if name not in PARAMETERS:
        raise ValueError(
            f"set_world_parameter: unknown parameter {name!r}; one of {sorted(PARAMETERS)} (for E and ν use "
            "set_world_material)"
        )
    kind, unit = PARAMETERS[name]
    sign = parameter(name).sign
    sl = world_slice(model, kind, w)
    count = sl.stop - sl.start
    v = np.asarray(value, dtype=np.float64)
    if v.ndim > 1 or (v.ndim == 1 and v.shape[0] != count):
        raise ValueError(
            f"set_world_parameter({name!r}, {w}): expected a scalar or {count} values [{unit}] (one per "
            f"{kind} of the world), got shape {v.shape}"
        )
    v = np.broadcast_to(v, (count,))
    if not np.all(np.isfinite(v)):
        raise ValueError(f"set_world_parameter({name!r}, {w}): values must be finite [{unit}]")
    positive = sign == "positive"  # the declared sign (λ < 0 is valid: ν < 0)
    bad = np.any(v <= 0) if positive else (sign == "nonnegative" and np.any(v < 0))
    if bad:
        raise ValueError(
            f"set_world_parameter({name!r}, {w}): values must be {'> 0' if positive else '>= 0'} {unit}"
        )
    write_range(getattr(model, name), sl, v, model.dtype)
    if name == "particle_mass":
        inv_w = model.particle_inv_mass.numpy()[sl].astype(np.float64)
        free = inv_w > 0  # pinned and kinematic particles keep inverse mass 0
        inv_w[free] = 1.0 / v[free]  # in float64, then rounded, as the builder does
        write_range(model.particle_inv_mass, sl, inv_w, model.dtype)
        model.particle_mass_np[sl] = v
    wp.synchronize_device(model.device)


def write_range(arr: wp.array, sl: slice, values: np.ndarray, dtype: str) -> None:
    """``arr[sl] = values`` on ``arr``'s device: one small upload and a device copy, so setting every
    world's values costs O(elements), not O(worlds × elements)."""
    import warp as wp

    if sl.stop <= sl.start:
        return
    from .._warp import np_dtype

    src: wp.array = wp.array(
        np.ascontiguousarray(values, dtype=np_dtype(dtype)), dtype=arr.dtype, device=arr.device
    )
    wp.copy(arr, src, dest_offset=sl.start, src_offset=0, count=sl.stop - sl.start)


def set_world_material(model: Model, w: int, E: npt.ArrayLike, nu: npt.ArrayLike) -> None:
    """Young's modulus ``E`` [Pa] and Poisson ratio ``nu`` of world ``w``'s tets (scalars or per tet)."""
    from ._materials import lame_parameters

    sl = world_slice(model, "tet", w)
    count = sl.stop - sl.start
    if count == 0:
        raise ValueError(f"set_world_material: world {w} has no tetrahedra")
    e_arr = np.broadcast_to(np.asarray(E, dtype=np.float64), (count,))
    nu_arr = np.broadcast_to(np.asarray(nu, dtype=np.float64), (count,))
    if np.any(e_arr <= 0) or np.any(nu_arr <= -1) or np.any(nu_arr >= 0.5):
        raise ValueError(f"set_world_material: need E > 0 Pa and -1 < nu < 0.5, got E={E!r}, nu={nu!r}")
    mu, lam = lame_parameters(e_arr, nu_arr)
    set_world_parameter(model, "tet_mu", w, np.broadcast_to(mu, (count,)))
    set_world_parameter(model, "tet_lam", w, np.broadcast_to(lam, (count,)))


def set_world_state(
    model: Model,
    w: int,
    x: npt.ArrayLike | None = None,
    v: npt.ArrayLike | None = None,
) -> None:
    """Replace world ``w``'s initial positions ``x`` [m] and/or velocities ``v`` [m/s] ([P, 3] each)."""
    sl = world_slice(model, "particle", w)
    count = sl.stop - sl.start
    for name, value in (("particle_q", x), ("particle_qd", v)):
        if value is None:
            continue
        a = np.asarray(value, dtype=np.float64)
        if a.shape != (count, 3) or not np.all(np.isfinite(a)):
            raise ValueError(
                f"set_world_state: {name} of world {w} must be finite [{count}, 3], got {a.shape}"
            )
        if name == "particle_qd":
            a = np.where(model.particle_inv_mass.numpy()[sl, None] > 0, a, 0.0)  # fixed particles stay still
        write_range(getattr(model, name), sl, a, model.dtype)
        if name == "particle_q":
            model.particle_q_np[sl] = a


def reset_world(model: Model, state: State, w: int) -> None:
    """Copy world ``w``'s initial positions and velocities into ``state`` (the others are untouched)."""
    import warp as wp

    sl = world_slice(model, "particle", w)
    n = sl.stop - sl.start
    wp.copy(state.particle_q, model.particle_q, dest_offset=sl.start, src_offset=sl.start, count=n)
    wp.copy(state.particle_qd, model.particle_qd, dest_offset=sl.start, src_offset=sl.start, count=n)
