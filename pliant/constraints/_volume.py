"""Tetrahedral volume constraints: C = V(x) − V0 per tet, the volume's maths and the constraint set."""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp
from numpy.typing import ArrayLike

from ..model import Model, Parameter, constraint_array, declares
from ._factory import _FourPoint, projection_kernels


# ---------------------------------------------------------------------- tetrahedral volume
@wp.func
def tet_volume(x0: Any, x1: Any, x2: Any, x3: Any):
    """V = (1/6) ((x1 − x0) × (x2 − x0)) · (x3 − x0)  [m³], positive for a positively oriented tet."""
    return wp.dot(wp.cross(x1 - x0, x2 - x0), x3 - x0) / type(x0[0])(6.0)


@wp.func
def volume_c(x0: Any, x1: Any, x2: Any, x3: Any, rest: Any):
    """C = V(x) − V0  [m³]."""
    return tet_volume(x0, x1, x2, x3) - rest


@wp.func
def volume_grad(x0: Any, x1: Any, x2: Any, x3: Any):
    """∇_1 = (x2 − x0)×(x3 − x0)/6, ∇_2 = (x3 − x0)×(x1 − x0)/6, ∇_3 = (x1 − x0)×(x2 − x0)/6, ∇_0 = −Σ."""
    sixth = type(x0[0])(1.0) / type(x0[0])(6.0)
    g1 = wp.cross(x2 - x0, x3 - x0) * sixth
    g2 = wp.cross(x3 - x0, x1 - x0) * sixth
    g3 = wp.cross(x1 - x0, x2 - x0) * sixth
    return -(g1 + g2 + g3), g1, g2, g3


@declares
class Volume(_FourPoint):
    """Tetrahedral volume: C = V(x) − V0 with V = (1/6)(x1 − x0)×(x2 − x0)·(x3 − x0).

    By default the set is the model's tetrahedra with compliance α = V0/κ [m³/Pa] from the bulk modulus
    κ = λ + 2μ/3 of each tet (so that ½ α⁻¹ C² = ½ κ (ΔV)²/V0), unless ``compliance`` is given.

    Args:
        indices: [E, 4] positively oriented tets; default the model's tetrahedra.
        rest_volume: V0 [m³]; default the current volumes.
        compliance: α [m³/Pa], scalar or [E] (0: incompressible).
        stiffness: PBD stiffness k in [0, 1].
    """

    _name = "Volume"
    kernels = projection_kernels("volume", volume_c, volume_grad, 4)

    @classmethod
    def parameters(cls) -> tuple[Parameter, ...]:
        """XPBD compliance α per constraint."""
        return (
            Parameter(
                "compliance_volume",
                "XPBD compliance of each tet volume constraint",
                "m^3/Pa",
                "constraint",
                ("constraint.compliance_array",),
                (1e-10, 1e-1),
                get=constraint_array("compliance_volume"),
            ),
        )

    def __init__(
        self,
        indices: ArrayLike | None = None,
        *,
        rest_volume: ArrayLike | None = None,
        compliance: Any = None,
        stiffness: float = 1.0,
    ) -> None:
        super().__init__(indices, rest_volume, compliance, stiffness)

    def _defaults(self, model: Model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        idx = model.tet_indices.numpy().reshape(-1, 4)
        rest = model.tet_rest_volume.numpy().astype(np.float64)
        if self._compliance_arg is not None:
            return idx, rest, self._compliance_arg
        kappa = model.tet_lam.numpy().astype(np.float64) + 2.0 / 3.0 * model.tet_mu.numpy()
        return idx, rest, np.abs(rest) / np.maximum(kappa, 1e-300)

    def _rest_of(self, q: np.ndarray, idx: np.ndarray) -> np.ndarray:
        x0, x1, x2, x3 = (q[idx[:, k]] for k in range(4))
        return np.einsum("ij,ij->i", np.cross(x1 - x0, x2 - x0), x3 - x0) / 6.0
