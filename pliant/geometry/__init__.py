"""NumPy-only geometry: procedural ropes, cloths and tet volumes, mesh loading, topology, measures, and
geometry from calibrated pictures (projection, space carving, depth back-projection, point-cloud clean-up).

Nothing here imports Warp; arrays are float64 positions [N, 3] (m) and int32 index
arrays. Tetrahedra returned by this package are positively oriented
(``det[x1-x0, x2-x0, x3-x0] > 0``).
"""

from ._barycentric import barycentric_coordinates, interpolate, locate_points, shape_functions
from ._clouds import Plane, fit_plane, frame_clouds, remove_outliers
from ._io import SUPPORTED_EXTENSIONS, load_mesh
from ._measures import (
    degenerate_tets,
    degenerate_triangles,
    orient_tets,
    signed_tet_volumes,
    triangle_areas,
    triangle_normals,
)
from ._meshes import TetMesh, TriMesh
from ._p2 import (
    P2_EDGES,
    interpolate_p2,
    locate_points_p2,
    p2_consistent_mass,
    p2_lumped_masses,
    p2_shape_functions,
    p2_shape_gradients,
    p2_subtets,
    promote_tets_p2,
    tet_quadrature,
)
from ._pictures import Voxels, backproject, carve, hull_bounds, project, view_agreement
from ._shapes import ClothGrid, Rope, cloth_grid, rope
from ._springs import springs_from_points
from ._tets import (
    box_tets,
    coarsen_voxels,
    cylinder_tets,
    largest_piece,
    sphere_tets,
    tetrahedralize,
    voxel_tets,
)
from ._topology import bending_pairs, edges_from_tets, edges_from_triangles, surface_from_tets

__all__ = [
    "P2_EDGES",
    "interpolate_p2",
    "locate_points_p2",
    "p2_consistent_mass",
    "p2_lumped_masses",
    "p2_shape_functions",
    "p2_shape_gradients",
    "p2_subtets",
    "promote_tets_p2",
    "tet_quadrature",
    "barycentric_coordinates",
    "interpolate",
    "locate_points",
    "shape_functions",
    "SUPPORTED_EXTENSIONS",
    "Plane",
    "Voxels",
    "backproject",
    "carve",
    "fit_plane",
    "frame_clouds",
    "hull_bounds",
    "project",
    "remove_outliers",
    "view_agreement",
    "ClothGrid",
    "Rope",
    "TetMesh",
    "TriMesh",
    "bending_pairs",
    "box_tets",
    "coarsen_voxels",
    "cloth_grid",
    "cylinder_tets",
    "degenerate_tets",
    "degenerate_triangles",
    "edges_from_tets",
    "edges_from_triangles",
    "largest_piece",
    "load_mesh",
    "orient_tets",
    "rope",
    "signed_tet_volumes",
    "sphere_tets",
    "springs_from_points",
    "surface_from_tets",
    "tetrahedralize",
    "voxel_tets",
    "triangle_areas",
    "triangle_normals",
]
