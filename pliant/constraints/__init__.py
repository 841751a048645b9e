"""PBD/XPBD constraints: pure C(x) and ∇C ``@wp.func`` maths, and objects owning indices, rest data and λ.

Every constraint object is a set of one kind (``Distance``, ``DihedralBending``, ``Volume``, ``Ground``,
``ParticleCollision``, ``PointTriangleCollision``, ``Attachment``, ``ShapeMatching``, ``TriangleArea``, …;
:data:`ALL_CONSTRAINTS` lists them) and is passed to :class:`pliant.solvers.XPBD` or
:class:`pliant.solvers.PBD` through ``constraints=[...]``.
"""

from .._subclasses import registered_subclasses
from ._area import TriangleArea, triangle_area, triangle_area_c, triangle_area_grad
from ._base import (
    Constraint,
    ProjectionContext,
    color_constraints,
    color_incidence,
    color_incidence_first_fit,
    pbd_delta_lambda,
    pbd_iteration_stiffness,
    xpbd_delta_lambda,
)
from ._bending import (
    DihedralBending,
    IsometricBending,
    dihedral_angle,
    dihedral_c,
    dihedral_grad,
    isometric_bending_c,
    isometric_bending_grad,
    isometric_bending_weights,
)
from ._contact import Ground, ParticleCollision, PointTriangleCollision
from ._contact_math import ground_c, ground_grad, particle_collision_c, point_triangle_c, point_triangle_grad
from ._distance import Attachment, Distance, distance_c, distance_grad
from ._factory import FixedArityConstraint, ProjectionKernels, projection_kernels
from ._generic import GenericConstraint
from ._shape import ShapeMatching, oriented_moment, polar_rotation, shape_matching_goal
from ._volume import Volume, tet_volume, volume_c, volume_grad


def registered_constraints() -> tuple[type[Constraint], ...]:
    """Every concrete, public :class:`Constraint` class that exists now, sorted by name.

    Found by walking :class:`Constraint`'s subclasses (so a user's or a test's constraint is found once its
    class is created); abstract ones (no ``bind`` or ``project`` yet, e.g. :class:`FixedArityConstraint`)
    and private ones (leading ``_``) are left out. ``tests/test_constraint_contracts.py`` checks each one's
    ∇C against finite differences of C on its example model.
    """
    return registered_subclasses(Constraint)


#: pliant's own constraints (:func:`registered_constraints` at import), one class each.
ALL_CONSTRAINTS: tuple[type[Constraint], ...] = registered_constraints()

__all__ = [
    "ALL_CONSTRAINTS",
    "Attachment",
    "Constraint",
    "DihedralBending",
    "Distance",
    "FixedArityConstraint",
    "GenericConstraint",
    "Ground",
    "IsometricBending",
    "ParticleCollision",
    "PointTriangleCollision",
    "ProjectionContext",
    "ProjectionKernels",
    "ShapeMatching",
    "TriangleArea",
    "Volume",
    "color_constraints",
    "color_incidence",
    "color_incidence_first_fit",
    "dihedral_angle",
    "dihedral_c",
    "dihedral_grad",
    "distance_c",
    "distance_grad",
    "ground_c",
    "ground_grad",
    "isometric_bending_c",
    "isometric_bending_grad",
    "isometric_bending_weights",
    "oriented_moment",
    "particle_collision_c",
    "pbd_delta_lambda",
    "pbd_iteration_stiffness",
    "point_triangle_c",
    "point_triangle_grad",
    "polar_rotation",
    "projection_kernels",
    "registered_constraints",
    "shape_matching_goal",
    "tet_volume",
    "triangle_area",
    "triangle_area_c",
    "triangle_area_grad",
    "volume_c",
    "volume_grad",
    "xpbd_delta_lambda",
]
