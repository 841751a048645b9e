"""What one contact kind is: its signed distance as a Warp function and its Python-side parameters.

A kind (:class:`ContactKind`) is a closed surface or a half space described by four device values per
collider, ``pos`` (a point), ``aux`` (a point, a direction or half extents), ``rot`` (world from local) and
``radius`` (an outward offset), plus a ``wp.Mesh`` id for meshes. Its ``sdf`` is a ``wp.func`` with the
signature ``sdf(pos, aux, rot, radius, mesh, p) -> (φ [m], n = ∇φ, ∇²φ [1/m])``: every response (the
projection after a step, compliant contact, the penalty and barrier energies, XPBD's post-step pass) calls
it through :func:`pliant.collision.collider_sdf`, which the registry unrolls at code generation. Its
``pack`` turns keyword parameters (validated, one-line errors) into those values. Its ``scene`` declares the
keys a scene file's ``[[colliders]]`` entry of the kind takes (:class:`SceneParam`) and its ``draw`` the
triangles a video or an export draws for it: ``pliant.scene`` builds the schema from them, so a kind's one
file is its whole definition.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
import warp as wp

#: How a rigid motion moves a kind's ``aux``: not at all (half extents, unused), as a point, as a direction.
AUX_FIXED, AUX_POINT, AUX_DIRECTION = 0, 1, 2

#: The value types a scene parameter may declare, each a validated scene-file type (``pliant.scene``):
#: ``vec3`` 3 numbers [m], ``length`` a number > 0 [m], ``nonneg`` a number >= 0, ``size3`` 3 numbers > 0
#: (or one, for all three) [m], ``scale3`` 3 factors > 0 (or one), ``quaternion`` [x, y, z, w] or absent,
#: ``surface`` a closed surface file's path (relative to the scene file), read into (vertices, faces).
SCENE_TYPES = ("vec3", "length", "nonneg", "size3", "scale3", "quaternion", "surface")


#: The default of a scene parameter that has none (the key is required).
class _Required:
    """The type of :data:`REQUIRED` (a marker: no default)."""

    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED = _Required()


@dataclass(frozen=True)
class SceneParam:
    """One key of a ``[[colliders]]`` entry of a kind (besides the keys every collider has).

    Attributes:
        name: the key (and, unless ``draw_only`` or the kind has a ``from_scene``, ``pack``'s keyword).
        type: one of :data:`SCENE_TYPES`.
        default: its value when absent, or :data:`REQUIRED`.
        unit: its unit ("m", "-").
        doc: one line saying what it is.
        draw_only: it shapes the drawing only (``draw`` gets it; ``pack`` does not).
    """

    name: str
    type: str
    default: object = REQUIRED
    unit: str = "m"
    doc: str = ""
    draw_only: bool = False


@dataclass(frozen=True)
class Packed:
    """One collider's device values (see the module docstring)."""

    pos: np.ndarray
    aux: np.ndarray
    rot: np.ndarray
    radius: float
    centre: np.ndarray  # the point it rotates about when it moves [m]


@dataclass(frozen=True)
class ContactKind:
    """One entry of :data:`pliant.collision.kinds.CONTACT_KINDS`.

    Attributes:
        name: the kind's name (``Colliders.add(name, ...)``, the scene's ``kind = "name"``).
        code: its integer code in the device arrays (unique, stable: recorded in nothing but memory).
        sdf: ``wp.func`` (pos, aux, rot, radius, mesh, p) → (φ [m], ∇φ, ∇²φ [1/m]).
        pack: ``pack(**params) -> Packed``: validates the parameters [m] and returns the device values.
        floor: ``floor()`` → parameters of a sample collider whose surface is the plane y = 0, normal +y,
            over x, z in [−5, 5] m (within 0.1 mm): the contract test's incline
            (``tests/test_contact_registry.py``) rests and slides a particle on it under tilted gravity.
        aux_motion: how a rigid motion moves ``aux`` (``AUX_FIXED``, ``AUX_POINT``, ``AUX_DIRECTION``).
        params: the parameter names ``pack`` takes (documentation and the contract test).
        bounded: whether the surface encloses a finite volume (a plane does not).
        scene: its ``[[colliders]]`` keys (:class:`SceneParam`); the scene schema is built from them.
        draw: ``draw(**add_keywords, **draw_only_values) -> (vertices [V, 3] m, faces [F, 3])``: the
            triangles drawn for it where it was added; None: not drawn.
        from_scene: ``from_scene(**values) -> add_keywords``: the scene values (a ``surface`` read as
            (vertices, faces)) as ``Colliders.add`` keywords; None: the values themselves.
    """

    name: str
    code: int
    sdf: Callable[..., object]
    pack: Callable[..., Packed]
    floor: Callable[[], dict[str, Any]]
    aux_motion: int = AUX_FIXED
    params: tuple[str, ...] = field(default_factory=tuple)
    bounded: bool = True
    scene: tuple[SceneParam, ...] = field(default_factory=tuple)
    draw: Callable[..., tuple[np.ndarray, np.ndarray]] | None = None
    from_scene: Callable[..., dict[str, Any]] | None = None


def vec3(v: npt.ArrayLike, what: str) -> np.ndarray:
    """``v`` as 3 finite float64 numbers, or a ValueError naming ``what``."""
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be 3 finite numbers [m], got {v!r}")
    return a


def rotation_matrix(rotation: npt.ArrayLike | None, what: str = "box rotation") -> np.ndarray:
    """A proper 3×3 rotation from a matrix, an (x, y, z, w) quaternion or None (identity)."""
    if rotation is None:
        return np.eye(3)
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape == (3, 3):
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
            raise ValueError(f"{what} must be a proper rotation matrix (orthonormal, det +1)")
        return r
    if r.shape == (4,):  # quaternion (x, y, z, w)
        if not (np.all(np.isfinite(r)) and np.linalg.norm(r) > 1e-12):
            raise ValueError(f"{what} is a zero quaternion; give [x, y, z, w] with a non-zero norm")
        x, y, z, w = r / np.linalg.norm(r)
        return np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
    raise ValueError(f"{what} must be a 3x3 matrix or an (x, y, z, w) quaternion, got shape {r.shape}")


@wp.func
def curved_hessian(P: Any, n: Any, rho: Any):
    """(P − nnᵀ)/ρ: the Hessian of the distance to a point (P = I) or a line (P = I − ûûᵀ)."""
    return (P - wp.outer(n, n)) / wp.max(rho, type(rho)(1.0e-12))
