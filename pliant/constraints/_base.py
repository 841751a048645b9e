"""The shared XPBD update, greedy graph colouring, and the base class of constraint objects."""

from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from ..model import Model


@wp.func
def xpbd_delta_lambda(c: Any, w_grad_sq: Any, alpha_tilde: Any, lam: Any):
    """Δλ = -(C + α̃λ) / (Σ w_i|∇_i C|² + α̃), α̃ = compliance / dt² (Macklin, Müller, Chentanez 2016)."""
    denom = w_grad_sq + alpha_tilde
    if denom <= type(c)(0.0):
        return type(c)(0.0)
    return -(c + alpha_tilde * lam) / denom


@wp.func
def pbd_delta_lambda(c: Any, w_grad_sq: Any, k: Any):
    """Δλ = -k' C / Σ w_i|∇_i C|² (Müller et al. 2007, with the iteration-corrected stiffness k')."""
    if w_grad_sq <= type(c)(0.0):
        return type(c)(0.0)
    return -k * c / w_grad_sq


@wp.func
def constraint_delta_lambda(c: Any, w_grad_sq: Any, alpha_tilde: Any, lam: Any, pbd_k: Any):
    """XPBD Δλ when ``pbd_k`` < 0, otherwise the PBD update with stiffness ``pbd_k`` (λ then unused)."""
    if pbd_k >= type(c)(0.0):
        return pbd_delta_lambda(c, w_grad_sq, pbd_k)
    return xpbd_delta_lambda(c, w_grad_sq, alpha_tilde, lam)


#: Run a colour-sorted Gauss–Seidel sweep as one launch on the CPU (identical arithmetic, fewer launches).
FUSE_CPU_COLORS = True

#: Use the CUDA schedule on the CPU too: the launch colouring (:func:`color_incidence_first_fit`) with a
#: launch per colour. Private, for tests and launch counts: the CPU's own path keeps the Luby colouring, so
#: its trajectories (tests/test_golden.py) stay bit for bit what they were.
CUDA_SCHEDULE_ON_CPU = False

#: Rounds of :func:`color_incidence_first_fit` in constraint order before the rest get random priorities.
ORDERED_ROUNDS = 1024


def per_colour_launches(device: wp.DeviceLike) -> bool:
    """Whether a colour sweep on ``device`` launches once per colour (CUDA, or the CPU forced to the CUDA
    schedule): there the number of colours is the number of launches, so the colouring minimises it."""
    return bool(wp.get_device(device).is_cuda or CUDA_SCHEDULE_ON_CPU)


def pbd_iteration_stiffness(k: float, iterations: int) -> float:
    """Müller's k' = 1 − (1 − k)^(1/n): after n iterations the constraint error shrinks by (1 − k)."""
    if not 0.0 <= k <= 1.0:
        raise ValueError(f"PBD stiffness k must be in [0, 1], got {k}")
    return 1.0 - (1.0 - k) ** (1.0 / max(int(iterations), 1))


def color_incidence(
    constraint_ids: np.ndarray, particle_ids: np.ndarray, constraint_count: int, particle_count: int
) -> np.ndarray:
    """Greedy colouring of constraints so that no two of one colour share a particle.

    Vectorised rounds (Luby's algorithm): inside a colour, repeatedly take every still-free constraint whose
    random priority is the smallest at each of its particles — an independent set — until no constraint
    can join; then open the next colour. Each colour is a maximal independent set, as in sequential greedy;
    random (seeded) priorities keep the number of rounds logarithmic instead of following id chains.

    Args:
        constraint_ids: Incidence pairs (constraint, particle): constraint side, int [P].
        particle_ids: Particle side of the incidence pairs, int [P]. Drop pinned particles beforehand:
            they never move, so sharing them is no conflict.
        constraint_count: Number of constraints.
        particle_count: Number of particles.

    Returns:
        Colour per constraint, int32 [constraint_count].
    """
    cid = np.asarray(constraint_ids, np.int64)
    pid = np.asarray(particle_ids, np.int64)
    color = np.full(constraint_count, -1, np.int64)
    prio = np.random.default_rng(0).permutation(constraint_count)
    big = np.iinfo(np.int64).max
    c = 0
    while np.any(color < 0):
        used = np.zeros(particle_count, bool)
        while True:
            free_c = color[cid] < 0
            # A constraint can join colour c only if none of its particles is used in colour c.
            blocked = np.zeros(constraint_count, bool)
            np.logical_or.at(blocked, cid[free_c], used[pid[free_c]])
            cand = (color < 0) & ~blocked
            if not np.any(cand):
                break
            mask = cand[cid]
            owner = np.full(particle_count, big)
            np.minimum.at(owner, pid[mask], prio[cid[mask]])
            # A candidate wins if it has the smallest priority at every one of its particles.
            lose = np.zeros(constraint_count, bool)
            np.logical_or.at(lose, cid[mask], owner[pid[mask]] != prio[cid[mask]])
            win = cand & ~lose
            color[win] = c
            used[pid[win[cid]]] = True
        c += 1
    return color.astype(np.int32)


def color_incidence_first_fit(
    constraint_ids: np.ndarray, particle_ids: np.ndarray, constraint_count: int, particle_count: int
) -> np.ndarray | None:
    """Sequential first-fit colouring in constraint order, computed in vectorised rounds (Jones–Plassmann).

    Each round, every uncoloured constraint whose priority is the smallest among the uncoloured constraints
    at each of its particles takes the lowest colour that none of its particles has yet. With the
    constraint id as priority this is exactly the sequential greedy colouring in id order, which on meshes
    the builder emits in a structured order needs few colours: 8 for a grid cloth's structural + shear
    springs (its maximum degree, the least possible) where :func:`color_incidence`'s random priorities
    give 12. The rounds follow chains of increasing ids (about 2 per grid row); after
    :data:`ORDERED_ROUNDS` the rest get random priorities, which bounds the rounds again.

    Args and return value as :func:`color_incidence`; None when more than 62 colours would be needed
    (the colours at a particle are kept as bits of an int64).
    """
    cid = np.asarray(constraint_ids, np.int64)
    pid = np.asarray(particle_ids, np.int64)
    color = np.full(constraint_count, -1, np.int64)
    used = np.zeros(particle_count, np.int64)  # bit c set: a constraint of colour c moves the particle
    prio = np.arange(constraint_count, dtype=np.int64)
    big = np.iinfo(np.int64).max
    # Scratch arrays, reset after each round only where it wrote: a round costs O(incidences left).
    owner = np.full(particle_count, big)
    lose = np.zeros(constraint_count, bool)
    taken = np.zeros(constraint_count, np.int64)
    rounds = 0
    while cid.size:
        if rounds == ORDERED_ROUNDS:
            prio = np.random.default_rng(0).permutation(constraint_count).astype(np.int64)
        rounds += 1
        np.minimum.at(owner, pid, prio[cid])
        np.logical_or.at(lose, cid, owner[pid] != prio[cid])
        won = ~lose[cid]  # incidences of this round's winners (an independent set)
        np.bitwise_or.at(taken, cid[won], used[pid[won]])
        win = np.unique(cid[won])
        bits = taken[win]
        if np.any(bits >= (1 << 62)):
            return None
        # The lowest clear bit of each winner's taken colours: ~b & (b + 1) isolates it.
        color[win] = np.log2((~bits & (bits + 1)).astype(np.float64)).astype(np.int64)
        np.bitwise_or.at(used, pid[won], np.left_shift(np.int64(1), color[cid[won]]))
        owner[pid], lose[cid], taken[win] = big, False, 0
        cid, pid = cid[~won], pid[~won]
    color[color < 0] = 0  # constraints with no movable particle conflict with nothing
    return color.astype(np.int32)


def color_constraints(
    indices: np.ndarray, inv_mass: np.ndarray, worlds: int = 1, *, fewest: bool = False
) -> np.ndarray:
    """Colours for constraints with fixed arity, indices [n, k]; pinned particles (w = 0) never conflict.

    ``fewest``: the colouring for a launch per colour (CUDA): the one of :func:`color_incidence_first_fit`
    and :func:`color_incidence` with fewer colours (the first on a tie). Otherwise :func:`color_incidence`.

    With ``worlds`` > 1 and constraints that are ``worlds`` shifted copies of the first block (what
    ``ModelBuilder.replicate`` makes), the first block is coloured and its colours repeated: each world is
    then swept in the order it has alone, so worlds equal runs alone bit for bit.
    """
    idx = np.asarray(indices, np.int64)
    n, k = idx.shape
    if n == 0:
        return np.zeros(0, np.int32)
    inv_mass = np.asarray(inv_mass)
    if worlds > 1 and n % worlds == 0 and len(inv_mass) % worlds == 0:
        n0, p = n // worlds, len(inv_mass) // worlds
        shift = (np.arange(worlds, dtype=np.int64) * p)[:, None, None]
        blocks = idx.reshape(worlds, n0, k) - shift
        same_pins = np.array_equal(
            (inv_mass.reshape(worlds, p) > 0), np.broadcast_to(inv_mass[:p] > 0, (worlds, p))
        )
        if same_pins and np.array_equal(blocks, np.broadcast_to(blocks[0], blocks.shape)):
            return np.tile(color_constraints(idx[:n0], inv_mass[:p], fewest=fewest), worlds)
    cid = np.repeat(np.arange(n), k)
    pid = idx.reshape(-1)
    keep = np.asarray(inv_mass)[pid] > 0.0
    luby = color_incidence(cid[keep], pid[keep], n, len(inv_mass))
    if not fewest:
        return luby
    first_fit = color_incidence_first_fit(cid[keep], pid[keep], n, len(inv_mass))
    if first_fit is None or first_fit.max() > luby.max():
        return luby
    return first_fit


def sort_by_color(colors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Permutation grouping constraints by colour, and colour offsets [colour_count + 1]."""
    order = np.argsort(colors, kind="stable")
    counts = np.bincount(colors, minlength=int(colors.max()) + 1 if colors.size else 0)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return order, offsets


@dataclass
class ProjectionContext:
    """What a constraint set may use from the solver projecting it (XPBD/PBD build one per step).

    Attributes:
        model: the Model (device, dtype, inverse masses, radii).
        iterations: projection sweeps per step (PBD's k' = 1 − (1 − k)^(1/n) needs it).
        coloring: True for the Gauss–Seidel colour schedule, False for Jacobi.
        relaxation: ω of the bilateral Jacobi corrections.
        pbd: PBD (stiffness k) instead of XPBD (compliance α).
        requires_grad: tape-differentiable step: write fresh arrays (:meth:`fresh`), never in place.
        launch: ``launch(kernel, dim, inputs)`` on the model's device (recorded for replay).
        call: ``call(fn, *args)`` runs a non-kernel operation of the step (recorded for replay).
        delta: Jacobi correction accumulator [N] (vec3) of the current sweep.
        delta_count: Jacobi correction counts [N] (int32) of the current sweep.
        v_pred: the predicted velocity ṽ of this step [m/s] (restitution reads it).
        jacobi_sum: Jacobi sets with :attr:`Constraint.sums_jacobi` project with full masses (no mass
            splitting) and the solver sums their corrections instead of averaging them.
    """

    model: Model
    iterations: int
    coloring: bool
    relaxation: float
    pbd: bool
    requires_grad: bool
    launch: Callable[..., None]
    call: Callable[..., None]
    delta: wp.array
    delta_count: wp.array
    v_pred: wp.array
    jacobi_sum: bool = False

    def fresh(self, like: wp.array) -> wp.array:
        """A zeroed array shaped like ``like``, tracking gradients when the step is differentiable."""
        return wp.zeros_like(like, requires_grad=self.requires_grad and like.dtype != wp.int32)


class Constraint(abc.ABC):
    """A set of constraints of one kind: indices, rest data, compliance α and multipliers λ.

    Subclasses implement :meth:`bind` (host set-up against a Model) and :meth:`project` (one
    Gauss–Seidel or Jacobi sweep, launching kernels only). The solver calls, per step,
    :meth:`begin_step` (reset λ, generate contacts) and, per iteration, :meth:`project`.

    Attributes:
        compliance: XPBD compliance α (inverse stiffness) per constraint set, or None for the default.
        stiffness: PBD stiffness k in [0, 1] (used only by :class:`pliant.solvers.PBD`).
        count: number of constraints once bound.
    """

    #: Whether the set can conflict between threads (False: each thread owns its particle, e.g. ground).
    uses_deltas = True
    #: Whether the set averages its corrections (Jacobi) under every schedule (contacts).
    always_jacobi = False
    #: Unilateral contact (C ≥ 0): also projected in the solver's final contact-only sweeps.
    is_contact = False
    #: Whether the set's Jacobi kernels apply the relaxation ω themselves (to Δλ and Δx together).
    relaxes_itself = False
    #: Whether the set's Jacobi kernel can project with full masses, summed (XPBD jacobi="sum").
    sums_jacobi = False
    #: Whether the set supports a tape-differentiable step (fresh arrays per sweep; see XPBD).
    differentiable = False

    def __init__(self, *, compliance: float | None = None, stiffness: float = 1.0) -> None:
        if compliance is not None and compliance < 0:
            raise ValueError(f"compliance must be >= 0, got {compliance}")
        if not 0.0 <= stiffness <= 1.0:
            raise ValueError(f"PBD stiffness must be in [0, 1], got {stiffness}")
        self.compliance = compliance
        self.stiffness = float(stiffness)
        self.count = 0
        self._model: Model | None = None
        self.lam: wp.array | None = None
        self.color_offsets = np.zeros(1, np.int64)
        #: Whether :meth:`bind` coloured for a launch per colour (:func:`per_colour_launches`).
        self.per_colour = False

    @property
    def model(self) -> Model:
        """The Model this set was bound to (:meth:`bind`, which the XPBD solver calls)."""
        if self._model is None:
            raise RuntimeError(
                f"{type(self).__name__} is not bound to a model: call bind(model, coloring) first"
            )
        return self._model

    @model.setter
    def model(self, model: Model) -> None:
        self._model = model

    def _multipliers(self) -> wp.array:
        """λ, the multipliers :meth:`bind` allocated (the set must be bound)."""
        if self.lam is None:
            raise RuntimeError(f"{type(self).__name__} has no multipliers: call bind(model, coloring) first")
        return self.lam

    # ------------------------------------------------------------------ host set-up
    @abc.abstractmethod
    def bind(self, model: Model, coloring: bool) -> None:
        """Copy indices and rest data to ``model.device``; colour them when ``coloring``."""

    def rebind(self, model: Model, coloring: bool) -> str | None:
        """:meth:`bind` again (after the model's parameter arrays changed in place), keeping every Warp array
        this set holds: the new values are copied into the old arrays, so that captured graphs and recorded
        launches holding them stay valid. Returns None, or why it could not (an array changed shape or
        type: the solver must be rebuilt)."""
        old = {k: v for k, v in vars(self).items() if isinstance(v, wp.array)}
        self.bind(model, coloring)
        for k, v in list(vars(self).items()):
            a = old.get(k)
            if isinstance(v, wp.array) and v is not a:
                if a is None or a.shape != v.shape or a.dtype != v.dtype:
                    return f"{type(self).__name__}.{k} changed shape when bound again"
                wp.copy(a, v)
                setattr(self, k, a)
        return None

    def _colors(self, indices: np.ndarray, coloring: bool) -> tuple[np.ndarray, np.ndarray]:
        """(permutation, offsets) grouping ``indices`` [n, k] by colour; identity when not colouring."""
        n = indices.shape[0]
        self.per_colour = per_colour_launches(self.model.device)
        if not coloring or n == 0:
            return np.arange(n), np.array([0, n], np.int64)
        w = self.model.particle_inv_mass.numpy()
        colors = color_constraints(indices, w, self.model.world_count, fewest=self.per_colour)
        return sort_by_color(colors)

    def _split_counts(self, indices: np.ndarray) -> np.ndarray:
        """n_i: how many constraints of this set can move particle i (those with a movable particle)."""
        w = self.model.particle_inv_mass.numpy()
        idx = np.asarray(indices, np.int64)
        live = np.any(w[idx] > 0, axis=1) if idx.size else np.zeros(0, bool)
        return np.bincount(idx[live].ravel(), minlength=self.model.particle_count).astype(np.int32)

    def color_ranges(self, coloring: bool) -> list[tuple[int, int]]:
        """(offset, size) launches of one sweep.

        On the CPU Warp runs a launch's threads one after another in thread order, so the whole
        colour-sorted list in one launch is exactly the colour-by-colour Gauss–Seidel sweep (the same
        arithmetic in the same order); on CUDA (:attr:`per_colour`) each colour gets its own launch.
        """
        off = self.color_offsets
        per_colour = self.per_colour or per_colour_launches(self.model.device)
        if not coloring or (FUSE_CPU_COLORS and not per_colour):
            return [(0, self.count)] if self.count else []
        return [(int(off[c]), int(off[c + 1] - off[c])) for c in range(len(off) - 1) if off[c + 1] > off[c]]

    # ------------------------------------------------------------------ per step
    def begin_step(self, ctx: ProjectionContext, x: wp.array, p: wp.array, dt: float) -> None:
        """Reset λ (XPBD multipliers start at 0 every step); contacts are generated here."""
        if self.lam is not None:
            if ctx.requires_grad:
                self.lam = ctx.fresh(self.lam)  # the tape keeps every step's multipliers
            else:
                ctx.call(self.lam.zero_)

    @abc.abstractmethod
    def project(self, ctx: ProjectionContext, p: wp.array, dt: float) -> wp.array | None:
        """One sweep over the constraints, writing ``p`` (Gauss–Seidel) or ``ctx`` deltas (Jacobi).

        Returns None, or (sets that move particles directly) the positions they wrote: ``p`` itself, or in a
        differentiable step the fresh array that replaces it.
        """

    def residual(self, ctx: ProjectionContext, p: wp.array, dt: float, out: wp.array) -> None:  # noqa: B027
        """Add Σ (C + α̃λ)² over the constraints into ``out[0]`` and their number into ``out[1]``."""

    def end_step(  # noqa: B027
        self, ctx: ProjectionContext, x: wp.array, p: wp.array, v: wp.array, dt: float
    ) -> wp.array | tuple[wp.array, wp.array] | None:
        """Velocity pass (friction, restitution) after v = (p − x)/dt; returns the velocities written (``v``
        itself in place, a fresh array in a differentiable step), the pair (positions, velocities) written
        where the pass moves positions too (friction acting inside the step), or None (nothing written)."""

    def evaluate(self, x: wp.array) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """C [n], particle indices [n, k] and ∇C [n, k, 3] of every bound constraint at positions ``x``.

        Scalar constraints implement it with the same C and ∇C funcs their projection uses, so that the
        contract test (tests/test_constraint_contracts.py) checks ∇C against finite differences of C.
        """
        raise NotImplementedError(f"{type(self).__name__} has no evaluate(x): it has no scalar C(x)")

    def writes_deltas(self, coloring: bool) -> bool:
        """Whether a sweep accumulates into the solver's deltas (which the solver then averages)."""
        return self.uses_deltas and (self.always_jacobi or not coloring)

    def pbd_k(self, ctx: ProjectionContext) -> float:
        """The per-iteration PBD stiffness k', or −1 for XPBD (the kernels branch on the sign)."""
        if ctx.pbd:
            return pbd_iteration_stiffness(self.stiffness, ctx.iterations)
        return -1.0

    def describe(self) -> dict:
        """Name, count and compliance for metadata."""
        return {"constraint": type(self).__name__, "count": self.count, "compliance": self.compliance}
