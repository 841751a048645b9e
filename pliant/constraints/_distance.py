"""Distance (stretching) and attachment constraints."""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp
from numpy.typing import ArrayLike

from ..model import Model, Parameter, constraint_array, declares
from ._base import Constraint, ProjectionContext, constraint_delta_lambda
from ._factory import FixedArityConstraint, projection_kernels


@wp.func
def distance_c(x0: Any, x1: Any, rest: Any):
    """C(x0, x1) = |x0 − x1| − rest  [m]."""
    return wp.length(x0 - x1) - rest


@wp.func
def distance_grad(x0: Any, x1: Any):
    """(∇_0 C, ∇_1 C) = (n, −n), n = (x0 − x1)/|x0 − x1|; zero for coincident points."""
    d = x0 - x1
    l = wp.length(d)
    n = d * type(l)(0.0)
    if l > type(l)(0.0):
        n = d / l
    return n, -n


def _as_pairs(indices: ArrayLike) -> np.ndarray:
    idx = np.asarray(indices, np.int64).reshape(-1, 2)
    return idx.astype(np.int32)


@declares
class Distance(FixedArityConstraint):
    """Stretching: C(x_i, x_j) = |x_i − x_j| − l = 0, with compliance α = 1/k [m/N].

    By default the constraint set is the model's springs with α = 1/k from ``model.spring_stiffness``
    (springs with k = 0 are left out). Reference: Müller, Heidelberger, Hennix, Ratcliff, "Position based
    dynamics", VRIPHYS 2006; Macklin, Müller, Chentanez, "XPBD", MIG 2016.

    Args:
        indices: particle pairs [S, 2]; default the model's springs.
        rest_length: [S] or scalar rest lengths [m]; default the current distances (model springs: theirs).
        compliance: α [m/N] (scalar or [S]); default 1/k of the model springs, or 0 for given indices.
        stiffness: PBD stiffness k in [0, 1] (used by :class:`pliant.solvers.PBD`).

    Example::

        solver = pl.solvers.XPBD(model, constraints=[pl.constraints.Distance(compliance=1e-6)])
    """

    kernels = projection_kernels("distance", distance_c, distance_grad, 2, unit_gradient=True)

    @classmethod
    def parameters(cls) -> tuple[Parameter, ...]:
        """XPBD compliance α per constraint."""
        return (
            Parameter(
                "compliance_distance",
                "XPBD compliance of each distance constraint",
                "m/N",
                "constraint",
                ("constraint.compliance_array",),
                (1e-10, 1e-1),
                get=constraint_array("compliance_distance"),
            ),
        )

    def __init__(
        self,
        indices: ArrayLike | None = None,
        *,
        rest_length: ArrayLike | None = None,
        compliance: Any = None,
        stiffness: float = 1.0,
    ) -> None:
        super().__init__(
            compliance=None if compliance is None or np.ndim(compliance) else float(compliance),
            stiffness=stiffness,
        )
        self._indices = None if indices is None else _as_pairs(indices)
        self._rest = rest_length
        self._compliance_arg = compliance

    def bind(self, model: Model, coloring: bool) -> None:
        """Resolve defaults from ``model`` and copy the colour-sorted constraints to its device."""
        self.model = model
        if self._indices is None:
            idx = model.spring_indices.numpy().reshape(-1, 2)
            rest = model.spring_rest_length.numpy().astype(np.float64)
            k = model.spring_stiffness.numpy().astype(np.float64)
            keep = k > 0
            idx, rest = idx[keep], rest[keep]
            comp = 1.0 / k[keep] if self._compliance_arg is None else self._compliance_arg
        else:
            idx = self._indices
            q = model.particle_q_np
            if idx.size and (idx.min() < 0 or idx.max() >= model.particle_count):
                raise ValueError(f"Distance: indices out of range [0, {model.particle_count})")
            rest = np.linalg.norm(q[idx[:, 0]] - q[idx[:, 1]], axis=1) if self._rest is None else self._rest
            comp = 0.0 if self._compliance_arg is None else self._compliance_arg
        n = idx.shape[0]
        rest = np.broadcast_to(np.asarray(rest, np.float64), (n,))
        comp = np.broadcast_to(np.asarray(comp, np.float64), (n,))
        if np.any(comp < 0):
            raise ValueError("Distance: compliance must be >= 0 m/N")
        self._device_arrays(np.asarray(idx).reshape(-1, 2), rest, comp, coloring)

    @property
    def rest_length(self) -> wp.array:
        """Rest lengths [m] in colour order (the factory's ``rest``)."""
        return self.rest


@wp.kernel
def _project_attachment(
    indices: wp.array(dtype=wp.int32),
    targets: wp.array(dtype=Any),
    rest: wp.array(dtype=Any),
    compliance: wp.array(dtype=Any),
    inv_mass: wp.array(dtype=Any),
    inv_dt2: Any,
    pbd_k: Any,
    p_io: wp.array(dtype=Any),
    lam_io: wp.array(dtype=Any),
):
    s = wp.tid()
    i = indices[s]
    w = inv_mass[i]
    if w == type(w)(0.0):
        return
    x = p_io[i]
    c = distance_c(x, targets[s], rest[s])
    g, _g = distance_grad(x, targets[s])
    lam = lam_io[s]
    dl = constraint_delta_lambda(c, w, compliance[s] * inv_dt2, lam, pbd_k)
    lam_io[s] = lam + dl
    p_io[i] = x + (w * dl) * g


@wp.kernel(enable_backward=False)
def _attachment_values(
    indices: wp.array(dtype=wp.int32),
    targets: wp.array(dtype=Any),
    rest: wp.array(dtype=Any),
    p_in: wp.array(dtype=Any),
    c_out: wp.array(dtype=Any),
    grad_out: wp.array2d(dtype=Any),
):
    s = wp.tid()
    x = p_in[indices[s]]
    c_out[s] = distance_c(x, targets[s], rest[s])
    g, _g = distance_grad(x, targets[s])
    grad_out[s, 0] = g


class Attachment(Constraint):
    """Attach particles to world points: C(x_i) = |x_i − t_i| − l (l = 0: a zero-length tether).

    Unlike a pin (inverse mass 0) an attachment has compliance α [m/N], so it can be soft and the
    particle keeps its mass. Each particle may appear once, so the sweep has no conflicts.

    Args:
        indices: particles [K].
        targets: world points [m], shape [K, 3]; default the particles' initial positions.
        rest_length: [K] or scalar tether length [m] (default 0).
        compliance: α [m/N] (default 0: rigid).
    """

    uses_deltas = False

    def __init__(
        self,
        indices: ArrayLike,
        targets: ArrayLike | None = None,
        *,
        rest_length: ArrayLike = 0.0,
        compliance: float = 0.0,
        stiffness: float = 1.0,
    ) -> None:
        super().__init__(compliance=compliance, stiffness=stiffness)
        self._indices = np.asarray(indices, np.int64).reshape(-1)
        if np.unique(self._indices).size != self._indices.size:
            raise ValueError("Attachment: each particle may be attached once; merge duplicate indices")
        self._targets = targets
        self._rest = rest_length

    def bind(self, model: Model, coloring: bool) -> None:
        """Copy indices and targets to the model's device."""
        self.model = model
        idx = self._indices
        if idx.size and (idx.min() < 0 or idx.max() >= model.particle_count):
            raise ValueError(f"Attachment: indices out of range [0, {model.particle_count})")
        n = idx.size
        t = model.particle_q_np[idx] if self._targets is None else np.asarray(self._targets, float)
        t = t.reshape(n, 3)
        d, f = model.device, model.scalar
        self.count = n
        self.indices: wp.array = wp.array(idx.astype(np.int32), dtype=wp.int32, device=d)
        self.targets: wp.array = wp.array(t, dtype=model.vec3, device=d)
        self.rest_length: wp.array = wp.array(
            np.broadcast_to(np.asarray(self._rest, float), (n,)), dtype=f, device=d
        )
        self.compliance_array: wp.array = wp.array(
            np.full(n, float(self.compliance or 0.0)), dtype=f, device=d
        )
        self.lam = wp.zeros(n, dtype=f, device=d)

    def evaluate(self, x: wp.array) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """C [K], indices [K, 1] and ∇C [K, 1, 3] of the attachments at positions ``x``."""
        m = self.model
        c = wp.zeros(self.count, dtype=m.scalar, device=m.device)
        g = wp.zeros((self.count, 1), dtype=m.vec3, device=m.device)
        if self.count:
            args = [self.indices, self.targets, self.rest_length, x, c, g]
            wp.launch(_attachment_values, self.count, args, device=m.device)
        return c.numpy(), self.indices.numpy()[:, None], g.numpy()

    def set_targets(self, targets: ArrayLike) -> None:
        """Move the attachment points [m], shape [K, 3] (between steps)."""
        self.targets.assign(np.asarray(targets, float).reshape(self.count, 3))

    def project(self, ctx: ProjectionContext, p: wp.array, dt: float) -> None:
        """Each particle is touched by one attachment: a direct (conflict-free) update."""
        m = self.model
        if self.count:
            ctx.launch(
                _project_attachment,
                self.count,
                [
                    self.indices,
                    self.targets,
                    self.rest_length,
                    self.compliance_array,
                    m.particle_inv_mass,
                    m.s(1.0 / (dt * dt)),
                    m.s(self.pbd_k(ctx)),
                    p,
                    self.lam,
                ],
            )
