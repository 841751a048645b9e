"""Triangle area constraints: C = A(x) − A0 per triangle (made by the k-particle factory, like Distance and
Volume)."""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp
from numpy.typing import ArrayLike

from ..model import Model
from ._factory import FixedArityConstraint, projection_kernels


@wp.func
def triangle_area(x0: Any, x1: Any, x2: Any):
    """A = ½ |(x1 − x0) × (x2 − x0)|  [m²]."""
    return wp.length(wp.cross(x1 - x0, x2 - x0)) * type(x0[0])(0.5)


@wp.func
def triangle_area_c(x0: Any, x1: Any, x2: Any, rest: Any):
    """C = A(x) − A0  [m²]."""
    return triangle_area(x0, x1, x2) - rest


@wp.func
def triangle_area_grad(x0: Any, x1: Any, x2: Any):
    """∇_1 A = ½ (x2 − x0) × n̂, ∇_2 A = ½ n̂ × (x1 − x0), ∇_0 = −∇_1 − ∇_2 (n̂ the unit normal).

    From dA = ½ n̂ · d((x1 − x0) × (x2 − x0)); zero for a degenerate (zero-area) triangle, whose normal is
    undefined.
    """
    n = wp.cross(x1 - x0, x2 - x0)
    ln = wp.length(n)
    half = type(ln)(0.5)
    g1 = n * type(ln)(0.0)
    g2 = g1
    if ln > type(ln)(0.0):
        nh = n / ln
        g1 = wp.cross(x2 - x0, nh) * half
        g2 = wp.cross(nh, x1 - x0) * half
    return -(g1 + g2), g1, g2


def triangle_areas_np(q: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Areas [m²] of triangles [T, 3] at positions q [N, 3] (NumPy)."""
    return 0.5 * np.linalg.norm(np.cross(q[idx[:, 1]] - q[idx[:, 0]], q[idx[:, 2]] - q[idx[:, 0]]), axis=1)


class TriangleArea(FixedArityConstraint):
    """Area preservation: C(x_i, x_j, x_k) = A(x) − A0 = 0 per triangle, compliance α [m³/N].

    Three particles per constraint, projected by the kernels :func:`projection_kernels` generates for
    k = 3 (Müller et al., "Position based dynamics", 2006, lists it beside the volume constraint). Cloth
    keeps its area under shear and compression this way without springs along the diagonals.

    Args:
        indices: triangles [T, 3]; default the model's triangles (``model.tri_indices``).
        rest_area: A0 [m²], scalar or [T]; default the current areas.
        compliance: α [m³/N] (½ C²/α is an energy in J), scalar or [T] (default 0: rigid).
        stiffness: PBD stiffness k in [0, 1].

    Example::

        area = pl.constraints.TriangleArea(compliance=1e-8)
        solver = pl.solvers.XPBD(model, constraints=[pl.constraints.Distance(), area])
    """

    kernels = projection_kernels("triangle_area", triangle_area_c, triangle_area_grad, 3)

    def __init__(
        self,
        indices: ArrayLike | None = None,
        *,
        rest_area: ArrayLike | None = None,
        compliance: Any = 0.0,
        stiffness: float = 1.0,
    ) -> None:
        super().__init__(compliance=None if np.ndim(compliance) else float(compliance), stiffness=stiffness)
        self._indices = None if indices is None else np.asarray(indices, np.int64).reshape(-1, 3)
        self._rest = rest_area
        self._compliance_arg = compliance

    def bind(self, model: Model, coloring: bool) -> None:
        """Resolve the defaults from ``model`` and copy the colour-sorted triangles to its device."""
        self.model = model
        idx = model.tri_indices.numpy().reshape(-1, 3) if self._indices is None else self._indices
        if idx.size and (idx.min() < 0 or idx.max() >= model.particle_count):
            raise ValueError(f"TriangleArea: indices out of range [0, {model.particle_count})")
        n = idx.shape[0]
        rest = triangle_areas_np(model.particle_q_np, idx) if self._rest is None else self._rest
        rest = np.broadcast_to(np.asarray(rest, np.float64), (n,))
        comp = np.broadcast_to(np.asarray(self._compliance_arg, np.float64), (n,))
        if np.any(comp < 0) or np.any(rest < 0):
            raise ValueError("TriangleArea: compliance and rest_area must be >= 0")
        self._device_arrays(np.asarray(idx).reshape(-1, 3), rest, comp, coloring)
