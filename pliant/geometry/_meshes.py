"""Plain mesh containers."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ._topology import edges_from_tets, edges_from_triangles, surface_from_tets


@dataclass
class TriMesh:
    """Triangle surface mesh.

    Attributes:
        points: Vertex positions [N, 3] float64 (m).
        triangles: Vertex indices [T, 3] int32.
    """

    points: NDArray[np.float64]
    triangles: NDArray[np.int32]

    def edges(self) -> NDArray[np.int32]:
        """Unique edges [E, 2] int32, ``i < j``."""
        return edges_from_triangles(self.triangles)


@dataclass
class TetMesh:
    """Tetrahedral volume mesh with every tet positively oriented.

    Attributes:
        points: Vertex positions [N, 3] float64 (m).
        tets: Vertex indices [E, 4] int32 with ``det[x1-x0, x2-x0, x3-x0] > 0``.
    """

    points: NDArray[np.float64]
    tets: NDArray[np.int32]

    def surface(self) -> NDArray[np.int32]:
        """Boundary triangles [F, 3] int32 wound with outward normals (indices into ``points``)."""
        return surface_from_tets(self.tets)

    def edges(self) -> NDArray[np.int32]:
        """Unique edges [S, 2] int32, ``i < j``."""
        return edges_from_tets(self.tets)
