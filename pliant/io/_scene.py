"""Scene files (TOML): load, validate (pydantic v2) and build a Model, a Solver and a Simulator.

A scene file has the sections ``[scene]``, ``[[objects]]`` (one per body), ``[ground]``, ``[solver]``,
``[camera]`` and ``[output]``; README.md documents every field. Errors name the file, the line when it can
be found, the field as a dotted path (``objects[1].material.E``) and the allowed values or the fix.
"""

from __future__ import annotations

import importlib.resources
import inspect
import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, Strict, ValidationError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

OBJECT_KINDS = ("cloth", "rope", "soft_box", "mesh", "points", "soft_sphere", "cluster")
COLLIDER_KINDS = ("sphere", "box", "capsule", "mesh")
HANDLE_KINDS = ("box", "points")
MODELS = ("mass_spring", "pbd", "fem")
SOLVER_KINDS = ("force", "xpbd", "pbd")
CLOTH_PINS = (
    "none",
    "top-corners",
    "top-edge",
    "corners",
    "top-left",
    "top-right",
    "bottom-corners",
    "left-corners",
    "right-corners",
    "bottom-edge",
    "left-edge",
    "right-edge",
    "boundary",
)
ROPE_PINS = ("first", "last", "both", "none")
#: Young's modulus given to the tets of a ``model = "pbd"`` volume without ``material.E`` (the builder
#: stores tets with an E; XPBD's volume constraints only use their rest volumes).
PBD_DEFAULT_E = 1.0e5
#: Video colours (RGB in [0, 1]) of simulated bodies and of drawn colliders.
BODY_COLOR = (0.91, 0.42, 0.16)
COLLIDER_COLOR = (0.55, 0.62, 0.72)
#: FEM material laws and the ``pliant.energies`` class each needs.
FEM_LAWS = {"neohookean": "NeoHookean", "stvk": "StVK", "corotated": "Corotated", "linear": "LinearElastic"}


# ---------------------------------------------------------------------------------------------- errors
class SceneError(ValueError):
    """A scene file is unreadable or invalid; ``problems`` holds ``(line, field path, message)`` each."""

    def __init__(self, file: str, problems: list[tuple[int | None, str, str]]) -> None:
        self.file = file
        self.problems = problems
        lines = []
        for line, path, msg in problems:
            where = f"{file}:{line}" if line else file
            lines.append(f"{where}: {path}: {msg}" if path else f"{where}: {msg}")
        super().__init__("\n".join(lines))


# ---------------------------------------------------------------------------------------------- types
def _vector(n: int, what: str, *, scalar: bool = False):
    """Validator: a list of ``n`` items (or, with ``scalar``, one number repeated ``n`` times)."""

    def check(v: Any) -> Any:
        if scalar and isinstance(v, (int, float)) and not isinstance(v, bool):
            return [v] * n
        if not isinstance(v, (list, tuple)) or len(v) != n:
            raise ValueError(f"expected {what}, got {v!r}")
        return v

    return check


Float = Annotated[float, Strict()]
Int = Annotated[int, Strict()]
PosFloat = Annotated[float, Strict(), Field(gt=0)]
NonNegFloat = Annotated[float, Strict(), Field(ge=0)]
PosInt = Annotated[int, Strict(), Field(ge=1)]
Vec3 = Annotated[tuple[Float, Float, Float], BeforeValidator(_vector(3, "3 numbers [x, y, z]"))]
Size2 = Annotated[
    tuple[PosFloat, PosFloat], BeforeValidator(_vector(2, "2 numbers [u, v] or one number", scalar=True))
]
Size3 = Annotated[
    tuple[PosFloat, PosFloat, PosFloat],
    BeforeValidator(_vector(3, "3 numbers [x, y, z] or one number", scalar=True)),
]
Cells3 = Annotated[
    tuple[PosInt, PosInt, PosInt],
    BeforeValidator(_vector(3, "3 integers [nx, ny, nz] or one integer", scalar=True)),
]


def _check_pin(v: Any) -> Any:
    if isinstance(v, str):
        return v
    if isinstance(v, list) and all(isinstance(i, int) and not isinstance(i, bool) and i >= 0 for i in v):
        return v
    raise ValueError(f"expected a pin name or a list of particle indices >= 0, got {v!r}")


Pin = Annotated[Any, BeforeValidator(_check_pin)]


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, validate_default=False)


class Material(_Section):
    """Material parameters; which ones are needed depends on the object's ``model``."""

    stiffness: NonNegFloat | None = None  # spring constant k [N/m] (mass_spring) or PBD stiffness
    shear_stiffness: NonNegFloat | None = None  # cloth shear springs [N/m] (default: stiffness)
    bend_stiffness: NonNegFloat = 0.0  # cloth / rope bend springs [N/m]
    damping: NonNegFloat = 0.0  # dashpot γ along each spring [N s/m]
    Et: PosFloat | None = None  # cloth membrane stiffness E·t [N/m] (instead of stiffness)
    E: PosFloat | None = None  # Young's modulus [Pa] (fem)
    nu: Annotated[float, Strict(), Field(gt=-1.0, lt=0.5)] = 0.3  # Poisson ratio
    law: Literal["neohookean", "stvk", "corotated", "linear"] = "neohookean"  # fem material law
    compliance: NonNegFloat | None = None  # XPBD compliance α [m/N]


class _Object(_Section):
    name: str | None = None
    model: Literal["mass_spring", "pbd", "fem"] = "mass_spring"
    material: Material = Field(default_factory=Material)
    particle_radius: PosFloat | None = None  # contact radius [m]


class ClothObject(_Object):
    """A rectangular cloth of nx × ny cells (structural, shear and bend springs)."""

    kind: Literal["cloth"]
    nx: PosInt = 16
    ny: PosInt = 16
    size: Size2 = (1.0, 1.0)  # [m]
    origin: Vec3 = (-0.5, 1.0, -0.5)  # bottom-left corner [m]
    plane: Literal["xz", "xy", "yz"] = "xz"
    mass: PosFloat = 0.1  # total [kg]
    pin: Pin = "none"


class RopeObject(_Object):
    """A rope (chain of springs) of ``n_segments`` from ``origin`` along ``direction``."""

    kind: Literal["rope"]
    n_segments: PosInt = 20
    length: PosFloat = 1.0  # [m]
    origin: Vec3 = (0.0, 1.0, 0.0)  # first particle [m]
    direction: Vec3 = (1.0, 0.0, 0.0)
    mass: PosFloat = 0.1  # total [kg]
    pin: Pin = "first"


class RenderMesh(_Section):
    """A fine surface drawn instead of a volume's own surface, moved by barycentric interpolation."""

    path: str | None = None  # a surface mesh file (relative to the scene file), or:
    icosphere: Annotated[int, Strict(), Field(ge=0, le=6)] | None = None  # subdivision level
    radius: PosFloat | None = None  # icosphere radius [m] (default: the object's radius or half size)
    scale: Size3 = (1.0, 1.0, 1.0)  # mesh file scale
    center: Vec3 | None = None  # [m] (default: the object's origin)


class SoftBoxObject(_Object):
    """A box of cells × 6 tetrahedra (tet-edge springs, or FEM with ``model = "fem"``)."""

    kind: Literal["soft_box"]
    cells: Cells3 = (4, 4, 4)
    size: Size3 = (0.2, 0.2, 0.2)  # [m]
    origin: Vec3 = (0.0, 0.5, 0.0)  # centre [m]
    density: PosFloat = 1000.0  # [kg/m³]
    velocity: Vec3 = (0.0, 0.0, 0.0)  # initial [m/s]
    render_mesh: RenderMesh | None = None


class MeshObject(_Object):
    """A mesh file (relative to the scene file): a tet mesh, or a closed surface filled by TetGen."""

    kind: Literal["mesh"]
    path: str
    scale: Size3 = (1.0, 1.0, 1.0)
    origin: Vec3 = (0.0, 0.0, 0.0)  # translation after scaling [m]
    density: PosFloat = 1000.0  # [kg/m³]
    velocity: Vec3 = (0.0, 0.0, 0.0)
    max_volume: PosFloat | None = None  # TetGen bound on tet volume [m³]
    render_mesh: RenderMesh | None = None


class PointsObject(_Object):
    """A point cloud with springs to neighbours within ``radius`` (PhysTwin style).

    Points come from ``path`` (.npy [N, 3] or a mesh file's vertices) or fill a ``shape`` on a jittered grid.
    """

    kind: Literal["points"]
    path: str | None = None
    shape: Literal["sphere", "box"] = "sphere"
    size: Size3 = (0.3, 0.3, 0.3)  # diameter / extents [m]
    spacing: PosFloat = 0.04  # grid spacing [m]
    jitter: Annotated[float, Strict(), Field(ge=0, lt=0.5)] = 0.2  # fraction of spacing
    seed: Int = 0
    origin: Vec3 = (0.0, 0.5, 0.0)  # centre [m]
    mass: PosFloat = 0.5  # total [kg]
    radius: PosFloat | None = None  # spring radius [m] (default 1.8 × spacing)
    max_neighbors: PosInt = 12


class SoftSphereObject(_Object):
    """A solid ball: an icosphere filled with tetrahedra by TetGen (springs, XPBD volume or FEM)."""

    kind: Literal["soft_sphere"]
    radius: PosFloat = 0.15  # [m]
    resolution: Annotated[int, Strict(), Field(ge=0, le=4)] = 2  # icosphere subdivision level
    max_volume: PosFloat | None = None  # TetGen bound on tet volume [m³]
    origin: Vec3 = (0.0, 0.5, 0.0)  # centre [m]
    density: PosFloat = 1000.0  # [kg/m³]
    velocity: Vec3 = (0.0, 0.0, 0.0)  # initial [m/s]
    render_mesh: RenderMesh | None = None


class ClusterObject(_Object):
    """Particles on a grid filling a sphere or box, held together by shape matching (XPBD/PBD only)."""

    kind: Literal["cluster"]
    model: Literal["pbd"] = "pbd"
    shape: Literal["sphere", "box"] = "box"
    size: Size3 = (0.1, 0.1, 0.1)  # diameter / extents [m]
    spacing: PosFloat = 0.025  # grid spacing [m]; particle_radius defaults to half of it
    origin: Vec3 = (0.0, 0.5, 0.0)  # centre [m]
    mass: PosFloat = 0.1  # total [kg]
    velocity: Vec3 = (0.0, 0.0, 0.0)  # initial [m/s]
    rigid: bool = True  # shape-matching stiffness 1
    shape_stiffness: Annotated[float, Strict(), Field(gt=0, le=1)] | None = None  # k_S when not rigid
    oriented: bool = False  # oriented particles (Müller & Chentanez 2011)


ObjectConfig = Annotated[
    ClothObject | RopeObject | SoftBoxObject | SoftSphereObject | MeshObject | PointsObject | ClusterObject,
    Field(discriminator="kind"),
]


class _Collider(_Section):
    friction: NonNegFloat = 0.5  # Coulomb μ
    restitution: Annotated[float, Strict(), Field(ge=0, le=1)] = 0.0
    render: bool = True  # draw it in the video


class SphereCollider(_Collider):
    kind: Literal["sphere"]
    center: Vec3 = (0.0, 0.0, 0.0)  # [m]
    radius: PosFloat  # [m]


class BoxCollider(_Collider):
    kind: Literal["box"]
    center: Vec3 = (0.0, 0.0, 0.0)  # [m]
    half_extents: Size3  # [m]
    rotation: (
        Annotated[tuple[Float, Float, Float, Float], BeforeValidator(_vector(4, "a quaternion [x, y, z, w]"))]
        | None
    ) = None
    rounding: NonNegFloat = 0.0  # [m]


class CapsuleCollider(_Collider):
    kind: Literal["capsule"]
    a: Vec3  # segment end points [m]
    b: Vec3
    radius: PosFloat  # [m]


class MeshCollider(_Collider):
    kind: Literal["mesh"]
    path: str  # closed, outward-wound surface (relative to the scene file)
    scale: Size3 = (1.0, 1.0, 1.0)
    origin: Vec3 = (0.0, 0.0, 0.0)  # translation after scaling [m]


ColliderConfig = Annotated[
    SphereCollider | BoxCollider | CapsuleCollider | MeshCollider, Field(discriminator="kind")
]


def _check_keyframes(v: Any) -> Any:
    if not isinstance(v, list) or not v:
        raise ValueError(f"expected a list of keyframes [[t, x, y, z], ...], got {v!r}")
    for k, row in enumerate(v):
        if (
            not isinstance(row, (list, tuple))
            or len(row) != 4
            or not all(isinstance(a, (int, float)) and not isinstance(a, bool) for a in row)
        ):
            raise ValueError(f"keyframe {k} must be 4 numbers [t, x, y, z] (s, m), got {row!r}")
    ts = [float(r[0]) for r in v]
    if any(b <= a for a, b in zip(ts, ts[1:], strict=False)):
        raise ValueError(f"keyframe times must increase strictly, got {ts}")
    return [tuple(float(a) for a in r) for r in v]


class HandleConfig(_Section):
    """Prescribed motion of some particles: kinematic (they follow exactly) or through springs."""

    kind: Literal["box", "points"]
    center: Vec3 | None = None  # box: the particles inside [m] at t = 0 are grabbed
    half_extents: Size3 | None = None  # box [m]
    points: list[Vec3] | None = None  # points: control points [m], linked to particles within radius
    object: str | Annotated[int, Strict(), Field(ge=0)] | None = None  # grab only this object (name/index)
    mode: Literal["kinematic", "springs"] | None = None  # default: box kinematic, points springs
    stiffness: PosFloat | None = None  # springs: k [N/m] per link
    damping: NonNegFloat = 0.0  # springs: γ [N s/m] per link
    radius: PosFloat | None = None  # points: link particles within this distance [m]
    max_links: PosInt = 16  # points: links per control point
    path: Annotated[list[tuple[float, float, float, float]], BeforeValidator(_check_keyframes)] | None = None
    velocity: Vec3 | None = None  # [m/s], instead of a path
    until: PosFloat | None = None  # velocity: stop moving at this time [s]

    def offset(self, t: float) -> np.ndarray:
        """Displacement [m] of the handle from its start at time ``t`` [s]."""
        if self.path is not None:
            k = np.asarray(self.path)
            return np.array([np.interp(t, k[:, 0], k[:, j]) for j in (1, 2, 3)])
        if self.velocity is not None:
            return np.asarray(self.velocity) * min(t, self.until if self.until is not None else np.inf)
        return np.zeros(3)

    def resolved_mode(self) -> str:
        """``mode``, or the default of the kind."""
        return self.mode or ("kinematic" if self.kind == "box" else "springs")


class SelfCollisionConfig(_Section):
    thickness: PosFloat  # minimum distance between particles / particle and triangle [m]
    friction: NonNegFloat = 0.0  # force solver
    iterations: PosInt = 2  # force solver: passes per step
    particles: bool = True  # particle–particle contacts
    triangles: bool = True  # particle–triangle contacts


class SceneSection(_Section):
    name: str = "scene"
    dt: PosFloat = 1.0 / 60.0  # frame duration [s]
    substeps: PosInt = 16
    frames: Annotated[int, Strict(), Field(ge=0)] = 120
    gravity: Vec3 = (0.0, -9.81, 0.0)  # [m/s²]
    device: str | None = None
    dtype: Literal["float32", "float64"] = "float32"
    max_speed: PosFloat = 1.0e3  # divergence bound [m/s]


class GroundSection(_Section):
    enabled: bool = True
    height: Float = 0.0  # [m]
    friction: NonNegFloat = 0.5
    restitution: Annotated[float, Strict(), Field(ge=0, le=1)] = 0.0
    stiffness: PosFloat | None = None  # κ [1/s²] of the implicit integrators' ground penalty (default 1e6)


class SolverSection(_Section):
    kind: Literal["force", "xpbd", "pbd"] | None = None  # default: from the objects' models
    integrator: str = "SymplecticEuler"
    integrator_options: dict[str, Any] = Field(default_factory=dict)
    iterations: PosInt = 10
    velocity_damping: Annotated[float, Strict(), Field(gt=0, le=1)] = 1.0
    damping_rate: NonNegFloat | None = None  # [1/s]
    compliance: NonNegFloat | None = None  # XPBD default compliance [m/N]
    stiffness: Annotated[float, Strict(), Field(ge=0, le=1)] | None = None  # PBD constraint stiffness k
    options: dict[str, Any] = Field(default_factory=dict)  # extra solver keyword arguments
    self_collision: SelfCollisionConfig | None = None


class CameraSection(_Section):
    eye: Vec3 | None = None
    target: Vec3 | None = None
    up: Vec3 = (0.0, 1.0, 0.0)
    fov: Annotated[float, Strict(), Field(gt=0, lt=180)] = 40.0  # vertical [deg]
    width: PosInt = 640
    height: PosInt = 480


class OutputSection(_Section):
    video: bool = True
    fps: PosFloat | None = None  # default 1 / dt
    trajectory: bool = True
    checkpoint_every: Annotated[int, Strict(), Field(ge=0)] = 50
    record_velocity: bool = False


class SceneConfig(_Section):
    """A validated scene file. ``source`` is the file it came from (for messages and relative paths)."""

    scene: SceneSection = Field(default_factory=SceneSection)
    objects: Annotated[list[ObjectConfig], Field(min_length=1)]
    colliders: list[ColliderConfig] = Field(default_factory=list)
    handles: list[HandleConfig] = Field(default_factory=list)
    ground: GroundSection | None = None
    solver: SolverSection = Field(default_factory=SolverSection)
    camera: CameraSection = Field(default_factory=CameraSection)
    output: OutputSection = Field(default_factory=OutputSection)
    source: str = Field(default="<scene>", exclude=True)
    base_dir: str = Field(default=".", exclude=True)
    text: str = Field(default="", exclude=True, repr=False)

    @property
    def name(self) -> str:
        """The scene's name (``[scene] name``)."""
        return self.scene.name

    def solver_kind(self) -> str:
        """``[solver] kind``, or the one the objects' models imply."""
        if self.solver.kind is not None:
            return self.solver.kind
        return "xpbd" if any(o.model == "pbd" for o in self.objects) else "force"


# ---------------------------------------------------------------------------------------------- messages
#: Tagged lists: section -> (allowed kinds, model of each kind), filled in below the models.
_UNIONS: dict[str, tuple[tuple[str, ...], dict[str, Any]]] = {
    "objects": (
        OBJECT_KINDS,
        {
            "cloth": ClothObject,
            "rope": RopeObject,
            "soft_box": SoftBoxObject,
            "soft_sphere": SoftSphereObject,
            "mesh": MeshObject,
            "points": PointsObject,
            "cluster": ClusterObject,
        },
    ),
    "colliders": (
        COLLIDER_KINDS,
        {"sphere": SphereCollider, "box": BoxCollider, "capsule": CapsuleCollider, "mesh": MeshCollider},
    ),
}


def _fmt_path(loc: tuple) -> str:
    out = ""
    skip_tag = False
    for part in loc:
        if skip_tag:
            skip_tag = False
            if part in _UNIONS[str(loc[0])][0]:
                continue
        if isinstance(part, int):
            out += f"[{part}]"
            skip_tag = str(loc[0]) in _UNIONS and out.startswith(str(loc[0])) and out.count("[") == 1
        else:
            out += ("." if out else "") + str(part)
    return out


def _allowed_fields(loc: tuple) -> list[str]:
    """Field names allowed next to the unknown one at ``loc`` (for "unknown field" messages)."""
    model: Any = SceneConfig
    parts = list(loc[:-1])
    i = 0
    while i < len(parts):
        p = parts[i]
        if p in _UNIONS and i == 0:
            i += 2  # index
            kind = parts[i] if i < len(parts) else None
            kinds, models = _UNIONS[p]
            model = models.get(kind, models[kinds[0]])
            i += 1
            continue
        if p == "handles" and i == 0:
            model = HandleConfig
            i += 2
            continue
        f = model.model_fields.get(p) if hasattr(model, "model_fields") else None
        if f is None:
            return []
        ann = f.annotation
        for cand in (ann, *getattr(ann, "__args__", ())):
            if isinstance(cand, type) and issubclass(cand, BaseModel):
                model = cand
                break
        else:
            return []
        i += 1
    excluded = {"source", "base_dir", "text"}
    return [k for k in model.model_fields if k not in excluded]


def _message(err: dict) -> tuple[tuple, str]:
    loc, typ, msg = tuple(err["loc"]), err["type"], err["msg"]
    ctx = err.get("ctx") or {}
    got = err.get("input")
    kinds = _UNIONS.get(str(loc[0]) if loc else "", (OBJECT_KINDS, {}))[0]
    if typ == "union_tag_invalid":
        return loc + ("kind",), f"unknown kind {ctx.get('tag')!r}; allowed: {', '.join(kinds)}"
    if typ == "union_tag_not_found":
        return loc + ("kind",), f"missing required field 'kind'; allowed: {', '.join(kinds)}"
    if typ == "missing":
        if len(loc) >= 3 and str(loc[0]) in _UNIONS and isinstance(loc[2], str):
            return loc, f"missing required field {loc[-1]!r} (a {loc[2]} in {loc[0]} needs it)"
        return loc, f"missing required field {loc[-1]!r}" if loc else "missing required field"
    if typ == "extra_forbidden":
        allowed = _allowed_fields(loc)
        hint = f"; allowed: {', '.join(allowed)}" if allowed else ""
        return loc[:-1] + (loc[-1],), f"unknown field {loc[-1]!r}{hint}"
    if typ == "literal_error":
        allowed = re.findall(r"'([^']*)'", ctx.get("expected", ""))
        return loc, f"got {got!r}; allowed: {', '.join(allowed)}"
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
    elif got is not None:
        msg = f"{msg[0].lower()}{msg[1:]}, got {got!r}"
    return loc, msg


def _line_of(text: str, path: str) -> int | None:
    """Best-effort line number of the field at dotted ``path`` in TOML ``text`` (1-based)."""
    parts = re.findall(r"([A-Za-z_][\w-]*)|\[(\d+)\]", path)
    keys: list[str | int] = [int(i) if i else k for k, i in parts]
    if not keys or not text:
        return None
    lines = text.splitlines()
    header = re.compile(r"^\s*\[\[?\s*([^\]]+?)\s*\]\]?")
    section = str(keys[0])
    rest = keys[1:]
    index = None
    if rest and isinstance(rest[0], int):
        index, rest = rest[0], rest[1:]
    # Find the block [section] or the index-th [[section]].
    count, start = -1, None
    for n, ln in enumerate(lines):
        m = header.match(ln)
        if m and m.group(1) == section:
            count += 1
            if index is None or count == index:
                start = n
                break
    if start is None:
        for n, ln in enumerate(lines):  # inline form: section = ... at top level
            if re.match(rf"^\s*{re.escape(section)}\s*=", ln):
                return n + 1
        return None
    end = next((n for n in range(start + 1, len(lines)) if header.match(lines[n])), len(lines))
    best = start
    sub = [k for k in rest if isinstance(k, str)]
    if sub:
        # A sub-table [section.material] after the block, or the key inside the block.
        for n in range(start + 1, len(lines)):
            m = header.match(lines[n])
            if m and m.group(1) == f"{section}.{sub[0]}" and len(sub) > 1:
                stop = next((k for k in range(n + 1, len(lines)) if header.match(lines[k])), len(lines))
                for k in range(n + 1, stop):
                    if re.match(rf"^\s*{re.escape(sub[1])}\s*=", lines[k]):
                        return k + 1
                return n + 1
            if m and not m.group(1).startswith(section + "."):
                break
        for n in range(start + 1, end):
            if re.match(rf"^\s*{re.escape(sub[0])}\s*=", lines[n]):
                return n + 1
    return best + 1


def _problems_from(exc: ValidationError, text: str) -> list[tuple[int | None, str, str]]:
    out = []
    for err in exc.errors():
        loc, msg = _message(err)
        path = _fmt_path(loc)
        out.append((_line_of(text, path), path, msg))
    return sorted(out, key=lambda p: p[0] or 0)


# ---------------------------------------------------------------------------------------------- loading
def builtin_scenes() -> list[str]:
    """Names of the scenes shipped with pliant (``pliant run <name>``)."""
    root = importlib.resources.files("pliant") / "scenes"
    return sorted(p.name[: -len(".toml")] for p in root.iterdir() if p.name.endswith(".toml"))


def _resolve(path_or_name: str | os.PathLike) -> tuple[str, str, str]:
    """(display name, text, base directory) of a scene file or a built-in scene name."""
    p = Path(path_or_name)
    if p.is_file():
        try:
            return str(p), p.read_text(encoding="utf-8"), str(p.resolve().parent)
        except (OSError, UnicodeDecodeError) as exc:
            raise SceneError(str(p), [(None, "", f"cannot read the scene file ({exc})")]) from exc
    name = str(path_or_name)
    names = builtin_scenes()
    if name in names:
        res = importlib.resources.files("pliant") / "scenes" / f"{name}.toml"
        return f"{name}.toml", res.read_text(encoding="utf-8"), str(Path(str(res)).parent)
    raise SceneError(
        name,
        [(None, "", f"no such scene file, and not a built-in scene; built-in scenes: {', '.join(names)}")],
    )


def parse_scene(text: str, source: str = "<scene>", base_dir: str | os.PathLike = ".") -> SceneConfig:
    """Validate the TOML ``text`` of a scene; ``source`` names it in errors."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        msg = re.sub(r"\s*\(at line \d+, column \d+\)", "", str(exc))
        raise SceneError(
            source, [(int(m.group(1)) if m else None, "", f"TOML syntax error: {msg}")]
        ) from None
    try:
        cfg = SceneConfig.model_validate(data)
    except ValidationError as exc:
        raise SceneError(source, _problems_from(exc, text)) from None
    cfg.source, cfg.base_dir, cfg.text = source, str(base_dir), text
    problems = [(_line_of(text, p), p, m) for p, m in _check(cfg)]
    if problems:
        raise SceneError(source, problems)
    return cfg


def load_scene(path_or_name: str | os.PathLike) -> SceneConfig:
    """Read and validate a scene file, or a built-in scene by name (``"cloth"``, ``"rope"`` ...).

    Raises:
        SceneError: a ``ValueError`` naming the file, line, field and the fix.
    """
    source, text, base = _resolve(path_or_name)
    return parse_scene(text, source, base)


def _check(cfg: SceneConfig) -> list[tuple[str, str]]:
    """Cross-field rules that pydantic's per-field types cannot express: (path, message) each."""
    out: list[tuple[str, str]] = []
    kind = cfg.solver_kind()
    for i, o in enumerate(cfg.objects):
        at = f"objects[{i}]"
        mat = o.material
        volumetric = o.kind in ("soft_box", "soft_sphere", "mesh")
        if o.model == "fem":
            if not volumetric:
                out.append(
                    (
                        f"{at}.model",
                        f"'fem' needs a volume (kind soft_box, soft_sphere or mesh), not {o.kind}; "
                        'use model = "mass_spring" or "pbd"',
                    )
                )
            elif mat.E is None:
                out.append((f"{at}.material.E", "model 'fem' needs Young's modulus E [Pa], e.g. E = 1e5"))
            if kind != "force":
                out.append(("solver.kind", f"objects[{i}] uses model 'fem', which needs kind = \"force\""))
        elif o.model == "mass_spring":
            if o.kind == "cloth" and mat.stiffness is None and mat.Et is None:
                out.append(
                    (
                        f"{at}.material.stiffness",
                        "mass_spring cloth needs stiffness [N/m] or Et (E·t [N/m]), e.g. stiffness = 300",
                    )
                )
            elif o.kind != "cloth" and mat.stiffness is None:
                out.append(
                    (
                        f"{at}.material.stiffness",
                        "model 'mass_spring' needs stiffness [N/m], e.g. stiffness = 500",
                    )
                )
            if kind != "force":
                out.append(
                    ("solver.kind", f"objects[{i}] uses model 'mass_spring', which needs kind = \"force\"")
                )
        elif o.model == "pbd" and kind == "force" and o.kind != "cluster":
            out.append(
                ("solver.kind", f'objects[{i}] uses model \'pbd\', which needs kind = "xpbd" or "pbd"')
            )
        pin = getattr(o, "pin", None)
        if isinstance(pin, str):
            allowed = CLOTH_PINS if o.kind == "cloth" else ROPE_PINS
            if pin not in allowed:
                out.append(
                    (f"{at}.pin", f"unknown pin {pin!r}; allowed: {', '.join(allowed)} or a list of indices")
                )
        if isinstance(o, RopeObject) and not np.any(o.direction):
            out.append((f"{at}.direction", "must be a non-zero vector"))
        if isinstance(o, ClusterObject):
            if o.rigid and o.shape_stiffness is not None:
                out.append(
                    (f"{at}.shape_stiffness", "a rigid cluster has k_S = 1; set rigid = false to use it")
                )
            if kind == "force":
                out.append(
                    ("solver.kind", f'objects[{i}] is a cluster (shape matching): needs kind = "xpbd"')
                )
        rm = getattr(o, "render_mesh", None)
        if rm is not None and (rm.path is None) == (rm.icosphere is None):
            out.append((f"{at}.render_mesh", "give either path (a surface mesh file) or icosphere (a level)"))
    names = [o.name or f"{o.kind}{i}" for i, o in enumerate(cfg.objects)]
    for i, h in enumerate(cfg.handles):
        at = f"handles[{i}]"
        mode = h.resolved_mode()
        if h.kind == "box" and (h.center is None or h.half_extents is None):
            field_ = "center" if h.center is None else "half_extents"
            out.append((f"{at}.{field_}", "a box handle needs center and half_extents [m]"))
        if h.kind == "points":
            if not h.points:
                out.append((f"{at}.points", "a points handle needs points = [[x, y, z], ...] [m]"))
            if h.radius is None:
                out.append(
                    (f"{at}.radius", "a points handle needs radius [m] (particles linked to each point)")
                )
            if mode == "kinematic":
                out.append((f"{at}.mode", 'a points handle acts through springs: use mode = "springs"'))
        if mode == "springs":
            if h.stiffness is None:
                out.append((f"{at}.stiffness", "mode 'springs' needs stiffness [N/m] per link, e.g. 1e3"))
            if kind != "force":
                out.append(
                    (
                        f"{at}.mode",
                        'springs (pl.energies.ControlPoints) need solver kind "force"; '
                        'use mode = "kinematic" with xpbd/pbd',
                    )
                )
        if h.path is not None and h.velocity is not None:
            out.append((f"{at}.velocity", "give path or velocity, not both"))
        if isinstance(h.object, int) and h.object >= len(cfg.objects):
            out.append(
                (f"{at}.object", f"index {h.object} out of range; there are {len(cfg.objects)} objects")
            )
        elif isinstance(h.object, str) and h.object not in names:
            out.append((f"{at}.object", f"no object named {h.object!r}; objects: {', '.join(names)}"))
    laws = {o.material.law for o in cfg.objects if o.model == "fem"}
    if len(laws) > 1:
        i = next(i for i, o in enumerate(cfg.objects) if o.model == "fem" and o.material.law != min(laws))
        out.append((f"objects[{i}].material.law", f"all fem objects must share one law, got {sorted(laws)}"))
    cam = cfg.camera
    if (cam.eye is None) != (cam.target is None):
        out.append(
            (
                "camera.eye" if cam.eye is None else "camera.target",
                "give both eye and target, or neither (the camera then frames the motion)",
            )
        )
    elif cam.eye is not None and np.allclose(cam.eye, cam.target):
        out.append(("camera.target", "must differ from camera.eye"))
    return out


# ---------------------------------------------------------------------------------------------- building
def integrator_names() -> list[str]:
    """Integrators constructible without arguments in this version of ``pliant.integrators``."""
    from .. import integrators

    names = []
    for n in getattr(integrators, "__all__", dir(integrators)):
        obj = getattr(integrators, n, None)
        if isinstance(obj, type) and issubclass(obj, integrators.Integrator) and not inspect.isabstract(obj):
            try:
                inspect.signature(obj).bind()
            except TypeError:
                continue
            names.append(n)
    return sorted(names)


def make_integrator(
    name: str, options: dict[str, Any] | None = None, *, source: str = "", path: str = "", text: str = ""
):
    """``pliant.integrators.<name>(**options)``, found case-insensitively; errors list what exists."""
    from .. import integrators

    path = path or "solver.integrator"

    names = integrator_names()
    match = next((n for n in names if n.lower() == name.lower().replace("-", "").replace("_", "")), None)
    match = match or next((n for n in names if n.lower() == name.lower()), None)
    if match is None:
        msg = f"unknown integrator {name!r}; available: {', '.join(names)}"
        raise SceneError(source or "<scene>", [(_line_of(text, path), path, msg)])
    try:
        return getattr(integrators, match)(**(options or {}))
    except (TypeError, ValueError) as exc:
        opt = "solver.integrator_options"
        raise SceneError(source or "<scene>", [(_line_of(text, opt), opt, f"{match}: {exc}")]) from None


def _not_available(what: str, needs: str) -> NotImplementedError:
    return NotImplementedError(f"{what} needs {needs}, not available in this version of pliant")


def _filtered_kwargs(fn: Any, kwargs: dict[str, Any]) -> dict[str, Any]:
    params = inspect.signature(fn).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return kwargs
    return {k: v for k, v in kwargs.items() if k in params}


def _points_for(o: PointsObject | ClusterObject, base_dir: str) -> np.ndarray:
    if getattr(o, "path", None) is not None:
        p = Path(base_dir) / o.path
        if p.suffix == ".npy":
            pts = np.load(p, allow_pickle=False)
        else:
            from ..geometry import load_mesh

            pts = load_mesh(p).points
        pts = np.asarray(pts, np.float64).reshape(-1, 3)
        return pts - pts.mean(axis=0) + np.asarray(o.origin)
    half = 0.5 * np.asarray(o.size)
    axes = [np.arange(-h, h + 1e-12, o.spacing) for h in half]
    axes = [a - a.mean() for a in axes]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    if o.shape == "sphere":
        grid = grid[np.sum((grid / half) ** 2, axis=1) <= 1.0]
    if getattr(o, "jitter", 0.0):
        rng = np.random.default_rng(o.seed)
        grid = grid + rng.uniform(-o.jitter, o.jitter, grid.shape) * o.spacing
    return grid + np.asarray(o.origin)


def _add_object(b: Any, o: Any, i: int, cfg: SceneConfig) -> None:
    mat = o.material
    name = o.name or f"{o.kind}{i}"
    # pbd objects without a stiffness: the springs only carry topology (the solver gets compliance 0).
    k = mat.stiffness if mat.stiffness is not None else 1.0
    r = {} if o.particle_radius is None else {"radius": o.particle_radius}
    if o.kind == "cloth":
        kw: dict[str, Any] = {}
        if mat.Et is not None and mat.stiffness is None:
            kw = {"youngs_modulus_thickness": mat.Et, "poisson": mat.nu}
        else:
            kw = {"stiffness": k, "shear_stiffness": mat.shear_stiffness}
        b.add_cloth_grid(
            nx=o.nx,
            ny=o.ny,
            size=o.size,
            mass=o.mass,
            bend_stiffness=mat.bend_stiffness,
            damping=mat.damping,
            origin=o.origin,
            plane=o.plane,
            pin=o.pin,
            name=name,
            **kw,
            **r,
        )
    elif o.kind == "rope":
        b.add_rope(
            n_segments=o.n_segments,
            length=o.length,
            mass=o.mass,
            stiffness=k,
            damping=mat.damping,
            start=o.origin,
            direction=o.direction,
            bend_stiffness=mat.bend_stiffness,
            pin=o.pin,
            name=name,
            **r,
        )
    elif o.kind in ("soft_box", "soft_sphere", "mesh"):
        fem = o.model == "fem"
        # pbd volumes keep their tets (XPBD volume constraints); the builder stores tets with an E.
        E = mat.E if fem else ((mat.E or PBD_DEFAULT_E) if o.model == "pbd" else None)
        kw = {
            "stiffness": None if fem else k,
            "damping": mat.damping,
            "E": E,
            "nu": mat.nu,
            "velocity": o.velocity,
            "name": name,
            "density": o.density,
            **r,
        }
        if o.kind == "soft_box":
            b.add_soft_box(cells=o.cells, size=o.size, origin=o.origin, **kw)
        elif o.kind == "soft_sphere":
            from ..geometry import sphere_tets

            tm = sphere_tets(o.radius, o.resolution, o.origin, max_volume=o.max_volume)
            b.add_tet_mesh(tm.points, tm.tets, **kw)
            b.objects[-1]["kind"] = "soft_sphere"
        else:
            from ..geometry import TetMesh, load_mesh, tetrahedralize

            path = Path(cfg.base_dir) / o.path
            mesh = load_mesh(path)
            pts = mesh.points * np.asarray(o.scale) + np.asarray(o.origin)
            if isinstance(mesh, TetMesh):
                tets = mesh.tets
            else:
                tm = tetrahedralize(pts, mesh.triangles, max_volume=o.max_volume, name=str(path))
                pts, tets = tm.points, tm.tets
            b.add_tet_mesh(pts, tets, **kw)
    elif o.kind == "points":
        pts = _points_for(o, cfg.base_dir)
        b.add_point_cloud(
            pts,
            mass=o.mass,
            stiffness=k,
            radius=o.radius or 1.8 * o.spacing,
            max_neighbors=o.max_neighbors,
            damping=mat.damping,
            name=name,
            **({} if o.particle_radius is None else {"particle_radius": o.particle_radius}),
        )
    elif o.kind == "cluster":
        pts = _points_for(o, cfg.base_dir)
        if pts.shape[0] < 2:
            raise ValueError(f"{name}: {pts.shape[0]} particle(s) fit; make size larger or spacing smaller")
        start = b.particle_count
        b.add_particles(
            pts,
            o.mass / pts.shape[0],
            velocities=np.broadcast_to(np.asarray(o.velocity, float), pts.shape),
            radius=o.particle_radius or 0.5 * o.spacing,
            name=name,
        )
        b.objects.append({"name": name, "kind": "cluster", "start": start, "count": pts.shape[0]})


@dataclass
class Embedding:
    """A fine render surface moved with a coarse tet mesh: x_fine = Σ φ x_tet (barycentric)."""

    start: int  # first particle of the embedding object
    count: int  # its particles
    tets: np.ndarray  # [E, 4] global particle indices of the object's tets
    tet_ids: np.ndarray  # [P] tet of each fine vertex
    bary: np.ndarray  # [P, 4]
    faces: np.ndarray  # [F, 3] fine triangles (indices into the fine vertices)


@dataclass
class Scene:
    """A built scene: the Model, its Solver, and how to run and show it.

    Example::

        scene = pl.io.build_scene(pl.io.load_scene("cloth"), device="cpu")
        traj = scene.simulator().run(frames=scene.frames)
    """

    config: SceneConfig
    model: Any
    solver: Any
    dt: float
    substeps: int
    frames: int
    camera: Any = None  # pliant.render.Camera, or None to frame the motion automatically
    outputs: OutputSection = field(default_factory=OutputSection)
    colliders: Any = None  # pliant.collision.Colliders of [[colliders]], or None
    control_fn: Any = None  # f(t, control) moving the [[handles]], or None
    control_points: list = field(default_factory=list)  # pl.energies.ControlPoints of spring handles
    embeddings: list[Embedding] = field(default_factory=list)
    static_meshes: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)  # drawn colliders

    @property
    def name(self) -> str:
        """The scene's name."""
        return self.config.scene.name

    @property
    def fps(self) -> float:
        """Video frame rate: ``[output] fps`` or 1 / dt."""
        return float(self.outputs.fps or 1.0 / self.dt)

    @property
    def sim_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :class:`pliant.Simulator` for this scene."""
        kw = {"dt": self.dt, "substeps": self.substeps, "max_speed": self.config.scene.max_speed}
        if self.control_fn is not None:
            kw["control_fn"] = self.control_fn
        return kw

    def simulator(self, **overrides: Any) -> Any:
        """A fresh :class:`pliant.Simulator` (``overrides`` replace ``sim_kwargs`` entries)."""
        from ..sim import Simulator

        if self.control_fn is not None:
            self.control_fn(0.0, None)  # handles back to their start
        return Simulator(self.model, self.solver, **{**self.sim_kwargs, **overrides})

    def render_mesh(
        self, x: np.ndarray, faces: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """What to draw for positions ``x`` [T, N, 3] (or [N, 3]): embedded fine surfaces replace their tet
        meshes' surfaces, and colliders with ``render = true`` are added as grey static meshes.

        Returns (x, faces, per-vertex colours [V, 3] or None).
        """
        if not self.embeddings and not self.static_meshes:
            return x, faces, None
        x = np.asarray(x)
        single = x.ndim == 2
        xs = x[None] if single else x
        parts, fparts = [xs], []
        count = xs.shape[1]
        if faces is not None:
            keep = np.ones(len(faces), bool)
            for e in self.embeddings:
                keep &= ~np.all((faces >= e.start) & (faces < e.start + e.count), axis=1)
            fparts.append(np.asarray(faces)[keep])
        for e in self.embeddings:
            w = xs[:, e.tets[e.tet_ids]]  # [T, P, 4, 3]
            parts.append(np.einsum("tpkd,pk->tpd", w, e.bary))
            fparts.append(e.faces + count)
            count += len(e.bary)
        n_body = count
        for v, f in self.static_meshes:
            parts.append(np.broadcast_to(v, (xs.shape[0], *v.shape)))
            fparts.append(f + count)
            count += len(v)
        out = np.concatenate(parts, axis=1)
        out_faces = np.concatenate(fparts).astype(np.int32) if fparts else None
        colors = np.empty((count, 3))
        colors[:n_body] = BODY_COLOR
        colors[n_body:] = COLLIDER_COLOR
        return (out[0] if single else out), out_faces, colors


def _with_post_step(cls: type) -> type:
    """``cls`` (XPBD or PBD) running contact handlers (``apply(model, s_in, s_out, dt)``) after each step."""

    def step(self, state_in, state_out, control, dt):
        cls.step(self, state_in, state_out, control, dt)
        for c in self.post_step:
            c.apply(self.model, state_in, state_out, dt)

    return type(cls.__name__, (cls,), {"step": step, "post_step": (), "__module__": cls.__module__})


def _collider_mesh(c: Any, base_dir: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices [V, 3] and faces [F, 3] of a collider, for drawing (and for mesh colliders, contact)."""
    import trimesh

    if c.kind == "sphere":
        m = trimesh.creation.icosphere(subdivisions=3, radius=c.radius)
        return m.vertices + np.asarray(c.center), m.faces
    if c.kind == "box":
        m = trimesh.creation.box(extents=2.0 * np.asarray(c.half_extents))
        v = m.vertices
        if c.rotation is not None:
            from scipy.spatial.transform import Rotation

            v = Rotation.from_quat(c.rotation).apply(v)
        return v + np.asarray(c.center), m.faces
    if c.kind == "capsule":
        a, b = np.asarray(c.a), np.asarray(c.b)
        d = b - a
        m = trimesh.creation.capsule(height=float(np.linalg.norm(d)), radius=c.radius, count=[16, 16])
        z = np.array([0.0, 0.0, 1.0])
        u = d / np.linalg.norm(d)
        rot = trimesh.geometry.align_vectors(z, u)[:3, :3]
        v = m.vertices - np.array([0.0, 0.0, 0.0])  # trimesh's capsule is centred at the origin
        return v @ rot.T + 0.5 * (a + b), m.faces
    from ..geometry import load_mesh

    mesh = load_mesh(Path(base_dir) / c.path)
    return mesh.points * np.asarray(c.scale) + np.asarray(c.origin), np.asarray(mesh.triangles)


def _embedding(o: Any, start: int, count: int, tets: np.ndarray, x0: np.ndarray, base_dir: str) -> Embedding:
    """Locate the fine render mesh of object ``o`` in its tets (global indices)."""
    import trimesh

    from ..geometry import locate_points

    rm = o.render_mesh
    center = np.asarray(rm.center if rm.center is not None else o.origin)
    if rm.icosphere is not None:
        r = rm.radius or getattr(o, "radius", None) or 0.5 * float(min(getattr(o, "size", (1.0,))))
        m = trimesh.creation.icosphere(subdivisions=rm.icosphere, radius=r)
        v, f = np.asarray(m.vertices) + center, np.asarray(m.faces)
    else:
        from ..geometry import load_mesh

        mesh = load_mesh(Path(base_dir) / rm.path)
        v = np.asarray(mesh.points) * np.asarray(rm.scale) + center
        f = np.asarray(mesh.triangles)
    mine = tets[np.all((tets >= start) & (tets < start + count), axis=1)]
    tet_ids, bary = locate_points(v, x0, mine)[:2]
    return Embedding(start, count, mine, np.asarray(tet_ids), np.asarray(bary), f.astype(np.int32))


def _make_control_fn(scene_dt: float, kin: list[tuple[Any, slice, np.ndarray]], springs: list):
    """f(t, control): kinematic targets / control points at the end of the coming frame (t + dt)."""
    state = {"targets": None}

    def control_fn(t: float, control: Any) -> None:
        te = t + scene_dt if control is not None else 0.0
        if kin:
            if state["targets"] is None:
                state["targets"] = np.concatenate([x0 for _, _, x0 in kin])
            tg = state["targets"].copy()
            for h, sl, x0 in kin:
                tg[sl] = x0 + h.offset(te)
            if control is not None:
                control.set_kinematic_targets(tg)
        for h, cp, x0 in springs:
            vel = (h.offset(te + 1e-3) - h.offset(max(te - 1e-3, 0.0))) / (te + 1e-3 - max(te - 1e-3, 0.0))
            cp.set_positions(x0 + h.offset(te), np.broadcast_to(vel, x0.shape))

    return control_fn


def build_scene(cfg: SceneConfig, device: str | None = None, dtype: str | None = None) -> Scene:
    """Build the Model and Solver a scene describes, on ``device`` in ``dtype`` (defaults: the file's).

    Raises:
        SceneError: an integrator or option the installed pliant does not know.
        NotImplementedError: a model or solver that is not available in this version (e.g. FEM).
    """
    from .. import energies, solvers
    from ..model import ModelBuilder

    src = cfg.source
    kind = cfg.solver_kind()
    fem_objects = [o for o in cfg.objects if o.model == "fem"]
    fem_energy = None
    if fem_objects:
        law = fem_objects[0].material.law
        cls_name = FEM_LAWS[law]
        fem_energy = getattr(energies, cls_name, None)
        if fem_energy is None:
            raise _not_available(f"model 'fem' (law '{law}')", f"pliant.energies.{cls_name}")
    if kind in ("xpbd", "pbd"):
        solver_cls = getattr(solvers, "PBD", None) if kind == "pbd" else None
        solver_cls = solver_cls or getattr(solvers, "XPBD", None)
        if solver_cls is None:
            raise _not_available(f"solver kind '{kind}'", "pliant.solvers.XPBD")

    def fail(path: str, msg: str) -> SceneError:
        return SceneError(src, [(_line_of(cfg.text, path), path, msg)])

    b = ModelBuilder(gravity=cfg.scene.gravity)
    ranges: list[tuple[int, int]] = []
    for i, o in enumerate(cfg.objects):
        start = b.particle_count
        try:
            _add_object(b, o, i, cfg)
        except (ValueError, FileNotFoundError) as exc:
            raise fail(f"objects[{i}]", str(exc)) from None
        ranges.append((start, b.particle_count))
    names = [o.name or f"{o.kind}{i}" for i, o in enumerate(cfg.objects)]

    # Handles: which particles each grabs (kinematic ones are marked before finalize).
    x_all = b.positions()
    kin: list[tuple[Any, slice, np.ndarray]] = []
    spring_handles: list[tuple[int, Any, np.ndarray]] = []
    n_kin = 0
    for i, h in enumerate(cfg.handles):
        lo, hi = 0, b.particle_count
        if h.object is not None:
            lo, hi = ranges[h.object if isinstance(h.object, int) else names.index(h.object)]
        if h.kind == "box":
            c, he = np.asarray(h.center), np.asarray(h.half_extents)
            inside = np.all(np.abs(x_all[lo:hi] - c) <= he, axis=1)
            idx = np.flatnonzero(inside) + lo
            if idx.size == 0:
                raise fail(f"handles[{i}].center", "the box holds no particle at t = 0; move or enlarge it")
            if h.resolved_mode() == "kinematic":
                b.add_kinematic(idx)
                kin.append((h, slice(n_kin, n_kin + idx.size), x_all[idx]))
                n_kin += idx.size
            else:
                spring_handles.append((i, h, x_all[idx]))
        else:
            spring_handles.append((i, h, np.asarray(h.points, float)))

    g = cfg.ground
    if g is not None and g.enabled:
        b.add_ground(g.height, friction=g.friction, restitution=g.restitution)
    try:
        model = b.finalize(device=device or cfg.scene.device, dtype=dtype or cfg.scene.dtype)
    except ValueError as exc:
        if device is None and cfg.scene.device is not None and "device" in str(exc):
            path = "scene.device"
        elif "device" in str(exc):
            raise
        else:
            path = "objects"
        raise fail(path, str(exc)) from None

    # Render meshes embedded in tet meshes.
    embeddings = []
    for i, o in enumerate(cfg.objects):
        if getattr(o, "render_mesh", None) is not None:
            lo, hi = ranges[i]
            try:
                embeddings.append(_embedding(o, lo, hi - lo, model.tet_indices_np, x_all, cfg.base_dir))
            except (ValueError, FileNotFoundError) as exc:
                raise fail(f"objects[{i}].render_mesh", str(exc)) from None

    # Contact handlers: static colliders, then self-collision.
    from ..collision import Colliders, SelfCollision

    colliders, static_meshes = None, []
    if cfg.colliders:
        colliders = Colliders()
        for i, c in enumerate(cfg.colliders):
            fr = {"friction": c.friction, "restitution": c.restitution}
            try:
                if c.kind == "sphere":
                    colliders.add_sphere(c.center, c.radius, **fr)
                elif c.kind == "box":
                    colliders.add_box(
                        c.center, c.half_extents, rotation=c.rotation, rounding=c.rounding, **fr
                    )
                elif c.kind == "capsule":
                    colliders.add_capsule(c.a, c.b, c.radius, **fr)
                if c.kind == "mesh" or c.render:
                    v, f = _collider_mesh(c, cfg.base_dir)
                    if c.kind == "mesh":
                        colliders.add_mesh(v, f, **fr)
                    if c.render:
                        static_meshes.append((np.asarray(v, float), np.asarray(f, np.int32)))
            except (ValueError, FileNotFoundError) as exc:
                raise fail(f"colliders[{i}]", str(exc)) from None
    s = cfg.solver
    sc = s.self_collision
    handlers: list[Any] = [colliders] if colliders is not None else []

    control_points = []
    if kind == "force":
        if sc is not None:
            try:
                handlers.append(
                    SelfCollision(
                        model,
                        thickness=sc.thickness,
                        friction=sc.friction,
                        iterations=sc.iterations,
                        particles=sc.particles,
                        triangles=sc.triangles,
                    )
                )
            except ValueError as exc:
                raise fail("solver.self_collision", str(exc)) from None
        terms = list(energies.mass_spring())
        if fem_energy is not None:
            try:
                terms.append(fem_energy())
            except TypeError:
                m0 = fem_objects[0].material
                terms.append(fem_energy(E=m0.E, nu=m0.nu))
        springs = []
        for i, h, pts in spring_handles:
            try:
                cp = energies.ControlPoints(
                    model,
                    pts,
                    stiffness=h.stiffness,
                    radius=h.radius if h.radius is not None else 1e-6,
                    max_links=h.max_links if h.kind == "points" else 1,
                    damping=h.damping,
                    zero_rest=h.kind == "box",
                )
            except ValueError as exc:
                raise fail(f"handles[{i}]", str(exc)) from None
            terms.append(cp)
            control_points.append(cp)
            springs.append((h, cp, pts))
        integrator = make_integrator(s.integrator, s.integrator_options, source=src, text=cfg.text)
        g = cfg.ground
        if g is not None and g.enabled and g.stiffness is not None and not integrator.explicit:
            terms.append(energies.GroundPenalty(g.stiffness))
        solver = solvers.ForceSolver(
            model,
            terms,
            integrator,
            velocity_damping=s.velocity_damping,
            damping_rate=s.damping_rate,
            collisions=handlers,
            **s.options,
        )
    else:
        springs = []
        compliance = s.compliance
        if compliance is None:
            compliance = next(
                (o.material.compliance for o in cfg.objects if o.material.compliance is not None), None
            )
        if compliance is None and any(
            o.material.stiffness is None for o in cfg.objects if o.kind != "cluster"
        ):
            compliance = 0.0  # no stiffness given: rigid distance constraints (XPBD would use α = 1/k)
        kw = {
            "iterations": s.iterations,
            "compliance": None if kind == "pbd" else compliance,
            "stiffness": s.stiffness if kind == "pbd" else None,
            "damping": s.damping_rate,
        }
        kw = {k: v for k, v in kw.items() if v is not None}
        cls = _with_post_step(solver_cls) if handlers else solver_cls
        solver = cls(model, **_filtered_kwargs(solver_cls, kw), **s.options)
        extra = _xpbd_extra_constraints(cfg, ranges, model, sc)
        for c in extra:
            c.bind(model, solver.coloring)
            solver.constraints.insert(len(solver.constraints) - (1 if model.ground is not None else 0), c)
        if handlers:
            solver.post_step = handlers

    control_fn = _make_control_fn(cfg.scene.dt, kin, springs) if (kin or springs) else None

    camera = None
    c = cfg.camera
    if c.eye is not None:
        from ..render import Camera

        camera = Camera(eye=c.eye, target=c.target, up=c.up, fov_y=c.fov, width=c.width, height=c.height)
    return Scene(
        config=cfg,
        model=model,
        solver=solver,
        dt=cfg.scene.dt,
        substeps=cfg.scene.substeps,
        frames=cfg.scene.frames,
        camera=camera,
        outputs=cfg.output,
        colliders=colliders,
        control_fn=control_fn,
        control_points=control_points,
        embeddings=embeddings,
        static_meshes=static_meshes,
    )


def _xpbd_extra_constraints(cfg: SceneConfig, ranges: list, model: Any, sc: Any) -> list:
    """Shape matching for cluster objects, and the self-collision constraints, for XPBD / PBD."""
    from .. import constraints as C

    out: list[Any] = []
    by_k: dict[tuple[float, bool], list[np.ndarray]] = {}
    radii = model.particle_radius.numpy() if hasattr(model.particle_radius, "numpy") else None
    for o, (lo, hi) in zip(cfg.objects, ranges, strict=True):
        if isinstance(o, ClusterObject):
            k_s = 1.0 if o.rigid else (o.shape_stiffness if o.shape_stiffness is not None else 0.5)
            by_k.setdefault((k_s, o.oriented), []).append(np.arange(lo, hi))
    for (k_s, oriented), clusters in by_k.items():
        out.append(C.ShapeMatching(clusters, stiffness=k_s, radii=radii if oriented else None))
    if sc is not None:
        if sc.particles:
            out.append(C.ParticleCollision())
        if sc.triangles and model.tri_count:
            out.append(C.PointTriangleCollision(thickness=sc.thickness))
    return out
