"""One factory for the kernels of k-particle constraints (any k ≥ 1), generated from C and ∇C ``@wp.func``s.

Every bilateral XPBD/PBD constraint of k particles is projected the same way — gather the k positions
and inverse masses, (Jacobi) split the masses, Δλ = −(C + α̃λ)/(Σ w|∇C|² + α̃) (or PBD's −k'C/Σ w|∇C|²),
then scatter wΔλ∇C — and only C and ∇C differ. :func:`projection_kernels` builds, for one pair of funcs,

- ``jacobi``: reads ``p_in`` and ``lam_in``, writes ``lam_out`` and accumulates the mass-split corrections
  and their counts atomically (the solver averages them); ``lam_in`` and ``lam_out`` may be one array
  (in place) or two (a fresh array per sweep, so a ``wp.Tape`` can replay it);
- ``gauss_seidel``: one colour's constraints update ``p_io`` in place, and λ from ``lam_in`` into ``lam_out``
  (one array but in a step's first sweep, which reads zeros: the reset folded into the sweep);
- ``residual``: Σ (C + α̃λ)² and the count of constraints with a movable particle;
- ``evaluate``: C and ∇C of every constraint (:meth:`FixedArityConstraint.evaluate`, the contract tests).

The kernels are cached per (name, arity) like FEM's material kernels, generic over float32/float64.
Constraints with ``unit_gradient`` (|∇_i C| = 1, e.g. distance) use Σ w for Σ w|∇C|², which is both
cheaper and the arithmetic the hand-written distance kernels used.
"""

from __future__ import annotations

import linecache
from typing import Any, NamedTuple

import numpy as np
import warp as wp
from numpy.typing import ArrayLike

from ..model import Model
from ._base import Constraint, ProjectionContext, constraint_delta_lambda


class ProjectionKernels(NamedTuple):
    """The kernels of one constraint family (see the module docstring for their arguments)."""

    jacobi: Any
    gauss_seidel: Any
    residual: Any
    evaluate: Any


_CACHE: dict[tuple[str, int], ProjectionKernels] = {}


def projection_kernels(
    name: str, c_func: Any, grad_func: Any, arity: int, *, unit_gradient: bool = False
) -> ProjectionKernels:
    """The Jacobi, Gauss–Seidel, residual and evaluation kernels of a constraint family, built once, cached.

    Args:
        name: a unique family name (the cache key and the kernels' module name).
        c_func: ``@wp.func`` C(x0, …, x_{k−1}, rest) → scalar.
        grad_func: ``@wp.func`` ∇C(x0, …, x_{k−1}) → (∇_0 C, …, ∇_{k−1} C); for k = 1 the one vec3 ∇_0 C.
        arity: k ≥ 1, the particles per constraint.
        unit_gradient: |∇_i C| = 1 for every point (Σ w|∇C|² = Σ w).

    Returns:
        The family's :class:`ProjectionKernels`.
    """
    if not isinstance(arity, int) or arity < 1:
        raise ValueError(f"projection_kernels({name!r}): arity must be an integer >= 1, got {arity!r}")
    key = (name, arity)
    if key not in _CACHE:
        _CACHE[key] = _build(name, c_func, grad_func, arity, unit_gradient)
    return _CACHE[key]


# The kernels are written once, below, as templates over the arity k: a line holding ``{j}`` is repeated for
# each point j = 0 … k−1, and ``{x}``, ``{g}``, ``{w}``, ``{wgs}``, ``{m}`` stand for the point lists and
# sums. Warp compiles Python source, so the k-point kernels are this text expanded and compiled; for k = 2
# and 4 it is, expression for expression, what the hand-written kernels were (tests/test_xpbd_factory.py
# checks the positions bit for bit).
_SCALARS = """\
    indices: wp.array2d(dtype=wp.int32),
    rest: wp.array(dtype=Any),
    compliance: wp.array(dtype=Any),
"""

_JACOBI = """\
def jacobi(
{scalars}\
    split: wp.array(dtype=wp.int32),
    inv_mass: wp.array(dtype=Any),
    inv_dt2: Any,
    pbd_k: Any,
    offset: int,
    omega: Any,
    p_in: wp.array(dtype=Any),
    lam_in: wp.array(dtype=Any),
    lam_out: wp.array(dtype=Any),
    delta_out: wp.array(dtype=Any),
    count_out: wp.array(dtype=wp.int32),
):
    s = offset + wp.tid()
    i{j} = indices[s, {j}]
    x{j} = p_in[i{j}]
    # Mass splitting: each of the n_i constraints at particle i sees the mass m_i/n_i.
    w{j} = inv_mass[i{j}] * type(omega)(split[i{j}])
    c = c_func({x}, rest[s])
    {g} = grad_func({x})
    wgs = {wgs}
    lam = lam_in[s]
    dl = constraint_delta_lambda(c, wgs, compliance[s] * inv_dt2, lam, pbd_k) * omega
    lam_out[s] = lam + dl
    # Scatter written out (not a wp.func taking the arrays): ~15% faster on the CPU, measured.
    wp.atomic_add(delta_out, i{j}, (w{j} * dl) * g{j})
    wp.atomic_add(count_out, i{j}, 1)
"""

_GAUSS_SEIDEL = """\
def gauss_seidel(
{scalars}\
    inv_mass: wp.array(dtype=Any),
    inv_dt2: Any,
    pbd_k: Any,
    offset: int,
    omega: Any,
    lam_in: wp.array(dtype=Any),
    p_io: wp.array(dtype=Any),
    lam_out: wp.array(dtype=Any),
):
    s = offset + wp.tid()
    i{j} = indices[s, {j}]
    x{j} = p_io[i{j}]
    w{j} = inv_mass[i{j}]
    c = c_func({x}, rest[s])
    {g} = grad_func({x})
    wgs = {wgs}
    lam = lam_in[s]
    dl = constraint_delta_lambda(c, wgs, compliance[s] * inv_dt2, lam, pbd_k) * omega
    lam_out[s] = lam + dl
    p_io[i{j}] = x{j} + (w{j} * dl) * g{j}
"""

_RESIDUAL = """\
def residual(
{scalars}\
    inv_mass: wp.array(dtype=Any),
    inv_dt2: Any,
    p_in: wp.array(dtype=Any),
    lam_in: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    s = wp.tid()
    i{j} = indices[s, {j}]
    if {m} == type(inv_dt2)(0.0):
        return
    x{j} = p_in[i{j}]
    r = c_func({x}, rest[s]) + compliance[s] * inv_dt2 * lam_in[s]
    wp.atomic_add(out, 0, r * r)
    wp.atomic_add(out, 1, type(r)(1.0))
"""

_EVALUATE = """\
def evaluate(
    indices: wp.array2d(dtype=wp.int32),
    rest: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    c_out: wp.array(dtype=Any),
    grad_out: wp.array2d(dtype=Any),
):
    s = wp.tid()
    i{j} = indices[s, {j}]
    x{j} = p_in[i{j}]
    c_out[s] = c_func({x}, rest[s])
    {g} = grad_func({x})
    grad_out[s, {j}] = g{j}
"""


def _expand(template: str, arity: int, unit: bool) -> str:
    """The template's source for k = ``arity`` points (see the comment above the templates)."""
    pts = range(arity)
    sums = {
        "scalars": _SCALARS,
        "x": ", ".join(f"x{j}" for j in pts),
        "g": ", ".join(f"g{j}" for j in pts),
        "m": " + ".join(f"inv_mass[i{j}]" for j in pts),
        "wgs": " + ".join(f"w{j}" if unit else f"w{j} * wp.dot(g{j}, g{j})" for j in pts),
    }
    out = []
    for line in template.splitlines(keepends=True):
        if "{j}" in line:
            out += [line.replace("{j}", str(j)) for j in pts]
        else:
            out.append(line.format(**sums) if "{" in line else line)
    return "".join(out)


def _build(name: str, c_func: Any, grad_func: Any, arity: int, unit: bool) -> ProjectionKernels:
    """Compile the four templates for ``arity`` points into module ``pliant.constraints._factory.<name>``."""
    module = wp.get_module(f"pliant.constraints._factory.{name}")
    scope = {
        "wp": wp,
        "Any": Any,
        "c_func": c_func,
        "grad_func": grad_func,
        "constraint_delta_lambda": constraint_delta_lambda,
    }
    kernels = []
    # None: the module's default (backward on), as the hand-written kernels had it.
    for template, backward in (
        (_JACOBI, None),
        (_GAUSS_SEIDEL, None),
        (_RESIDUAL, False),
        (_EVALUATE, False),
    ):
        source = _expand(template, arity, unit)
        fn_name = source[4 : source.index("(")]
        # Registered with linecache so that Warp (and tracebacks) read the generated text like a file's.
        filename = f"<pliant.constraints._factory {name} {fn_name} k={arity}>"
        linecache.cache[filename] = (len(source), None, source.splitlines(keepends=True), filename)
        exec(compile(source, filename, "exec"), scope)  # noqa: S102 - our own template, no user text
        kernels.append(wp.kernel(scope[fn_name], module=module, enable_backward=backward))
    return ProjectionKernels(*kernels)


class FixedArityConstraint(Constraint):
    """A set of k-particle constraints projected by the kernels :func:`projection_kernels` generates.

    Subclasses set :attr:`kernels` and, in ``bind``, the device arrays ``indices`` [n, k], ``rest`` [n],
    ``compliance_array`` [n], ``split`` [N] (Jacobi mass-splitting counts) and ``lam`` [n], and their
    colour offsets. Differentiable: under a gradient-tracking step each Jacobi sweep writes a fresh λ.
    """

    relaxes_itself = True
    differentiable = True
    sums_jacobi = True
    kernels: ProjectionKernels
    #: λ's reset is pending: the step's first sweep reads λ = 0 from ``zero_lam`` instead of a memset of λ
    #: (one launch less per set and step; the same zeros, so the same arithmetic).
    _reset_pending = False

    def begin_step(self, ctx: ProjectionContext, x: wp.array, p: wp.array, dt: float) -> None:
        """Reset λ: a tape step allocates fresh multipliers; otherwise the first sweep reads zeros."""
        if ctx.requires_grad:
            super().begin_step(ctx, x, p, dt)
        else:
            self._reset_pending = True

    def project(self, ctx: ProjectionContext, p: wp.array, dt: float) -> None:
        """One sweep: Gauss–Seidel per colour, or Jacobi into ``ctx.delta``."""
        m = self.model
        k = m.s(self.pbd_k(ctx))
        inv_dt2 = m.s(1.0 / (dt * dt))
        omega = m.s(ctx.relaxation)
        common = [self.indices, self.rest, self.compliance_array]
        lam_in = self.zero_lam if self._reset_pending else self._multipliers()
        self._reset_pending = False
        for off, size in self.color_ranges(ctx.coloring):
            if ctx.coloring:
                args = [*common, m.particle_inv_mass, inv_dt2, k, off, omega, lam_in, p, self.lam]
                ctx.launch(self.kernels.gauss_seidel, size, args)
                continue
            lam_out = ctx.fresh(self._multipliers()) if ctx.requires_grad else self._multipliers()
            # jacobi="sum": a split of 1 everywhere, i.e. the full masses (inv_mass · 1 is inv_mass exactly).
            split = self.unit_split if ctx.jacobi_sum else self.split
            args = [*common, split, m.particle_inv_mass, inv_dt2, k, off, omega, p, lam_in, lam_out]
            ctx.launch(self.kernels.jacobi, size, [*args, ctx.delta, ctx.delta_count])
            self.lam = lam_in = lam_out

    def residual(self, ctx: ProjectionContext, p: wp.array, dt: float, out: wp.array) -> None:
        """Σ (C + α̃λ)² into out[0], count into out[1] (constraints with a movable particle)."""
        m = self.model
        if self.count:
            args = [self.indices, self.rest, self.compliance_array, m.particle_inv_mass]
            wp.launch(
                self.kernels.residual,
                self.count,
                [*args, m.s(1.0 / (dt * dt)), p, self.lam, out],
                device=m.device,
            )

    def evaluate(self, x: wp.array) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """C [n], indices [n, k] and ∇C [n, k, 3] of the bound set at positions ``x`` (colour order)."""
        m = self.model
        c = wp.zeros(self.count, dtype=m.scalar, device=m.device)
        k = self.indices.shape[1]
        g = wp.zeros((self.count, k), dtype=m.vec3, device=m.device)
        if self.count:
            wp.launch(self.kernels.evaluate, self.count, [self.indices, self.rest, x, c, g], device=m.device)
        return c.numpy(), self.indices.numpy(), g.numpy()

    def _device_arrays(self, idx: np.ndarray, rest: np.ndarray, comp: np.ndarray, coloring: bool) -> None:
        """Colour-sort and copy indices, rest values, compliances, λ and split counts to the device."""
        m = self.model
        n, k = idx.shape
        order, self.color_offsets = self._colors(idx, coloring)
        rg = m.requires_grad
        d, f = m.device, m.scalar
        self.count = n
        self.indices: wp.array = wp.array(
            idx[order].astype(np.int32).reshape(-1, k), dtype=wp.int32, device=d
        )
        self.rest: wp.array = wp.array(rest[order], dtype=f, device=d, requires_grad=rg)
        self.compliance_array: wp.array = wp.array(comp[order], dtype=f, device=d, requires_grad=rg)
        self.lam = wp.zeros(n, dtype=f, device=d, requires_grad=rg)
        #: Never written: what a step's first sweep reads as λ (:meth:`begin_step`).
        self.zero_lam: wp.array = wp.zeros(n, dtype=f, device=d)
        # An instance attribute from bind on: a graph fingerprint (pliant.sim._graph) must not see it appear.
        self._reset_pending = False
        self.split: wp.array = wp.array(self._split_counts(idx), dtype=wp.int32, device=d)
        self.unit_split: wp.array = wp.ones(m.particle_count, dtype=wp.int32, device=d)
        self.order = order


class _FourPoint(FixedArityConstraint):
    """A set of four-particle constraints (dihedral bending, tet volume): indices [N, 4], a rest value and a
    compliance per constraint; a subclass gives ``_defaults`` (the model's own set) and ``_rest_of``. Private:
    the constraint registry lists the concrete subclasses only."""

    _name = ""

    def __init__(
        self, indices: ArrayLike | None, rest: ArrayLike | None, compliance: Any, stiffness: float
    ) -> None:
        super().__init__(
            compliance=None if compliance is None or np.ndim(compliance) else float(compliance),
            stiffness=stiffness,
        )
        self._indices = None if indices is None else np.asarray(indices, np.int64).reshape(-1, 4)
        self._rest = rest
        self._compliance_arg = compliance

    def _defaults(self, model: Model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _rest_of(self, q: np.ndarray, idx: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def bind(self, model: Model, coloring: bool) -> None:
        """Resolve defaults from ``model`` and copy the colour-sorted constraints to its device."""
        self.model = model
        rest: ArrayLike  # per constraint, or one value broadcast below
        comp: ArrayLike
        if self._indices is None:
            idx, rest, comp = self._defaults(model)
        else:
            idx = self._indices
            if idx.size and (idx.min() < 0 or idx.max() >= model.particle_count):
                raise ValueError(f"{self._name}: indices out of range [0, {model.particle_count})")
            rest = self._rest_of(model.particle_q_np, idx) if self._rest is None else self._rest
            comp = 0.0 if self._compliance_arg is None else self._compliance_arg
        n = idx.shape[0]
        rest = np.broadcast_to(np.asarray(rest, np.float64), (n,))
        comp = np.broadcast_to(np.asarray(comp, np.float64), (n,))
        if np.any(comp < 0):
            raise ValueError(f"{self._name}: compliance must be >= 0")
        self._device_arrays(np.asarray(idx).reshape(-1, 4), rest, comp, coloring)
