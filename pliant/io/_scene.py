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

OBJECT_KINDS = ("cloth", "rope", "soft_box", "mesh", "points")
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


class SoftBoxObject(_Object):
    """A box of cells × 6 tetrahedra (tet-edge springs, or FEM with ``model = "fem"``)."""

    kind: Literal["soft_box"]
    cells: Cells3 = (4, 4, 4)
    size: Size3 = (0.2, 0.2, 0.2)  # [m]
    origin: Vec3 = (0.0, 0.5, 0.0)  # centre [m]
    density: PosFloat = 1000.0  # [kg/m³]
    velocity: Vec3 = (0.0, 0.0, 0.0)  # initial [m/s]


class MeshObject(_Object):
    """A mesh file (relative to the scene file): a tet mesh, or a closed surface filled by TetGen."""

    kind: Literal["mesh"]
    path: str
    scale: Size3 = (1.0, 1.0, 1.0)
    origin: Vec3 = (0.0, 0.0, 0.0)  # translation after scaling [m]
    density: PosFloat = 1000.0  # [kg/m³]
    velocity: Vec3 = (0.0, 0.0, 0.0)
    max_volume: PosFloat | None = None  # TetGen bound on tet volume [m³]


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


ObjectConfig = Annotated[
    ClothObject | RopeObject | SoftBoxObject | MeshObject | PointsObject, Field(discriminator="kind")
]


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
def _fmt_path(loc: tuple) -> str:
    out = ""
    skip_tag = False
    for part in loc:
        if skip_tag:
            skip_tag = False
            if part in OBJECT_KINDS:
                continue
        if isinstance(part, int):
            out += f"[{part}]"
            skip_tag = out.startswith("objects") and out.count("[") == 1
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
        if p == "objects":
            i += 2  # index
            kind = parts[i] if i < len(parts) else None
            model = {
                "cloth": ClothObject,
                "rope": RopeObject,
                "soft_box": SoftBoxObject,
                "mesh": MeshObject,
                "points": PointsObject,
            }.get(kind, ClothObject)
            i += 1
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
    if typ == "union_tag_invalid":
        return loc + ("kind",), f"unknown kind {ctx.get('tag')!r}; allowed: {', '.join(OBJECT_KINDS)}"
    if typ == "union_tag_not_found":
        return loc + ("kind",), f"missing required field 'kind'; allowed: {', '.join(OBJECT_KINDS)}"
    if typ == "missing":
        return loc, "missing required field"
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
        volumetric = o.kind in ("soft_box", "mesh")
        if o.model == "fem":
            if not volumetric:
                out.append(
                    (
                        f"{at}.model",
                        f"'fem' needs a volume (kind soft_box or mesh), not {o.kind}; "
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
        elif o.model == "pbd" and kind == "force":
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


def _points_for(o: PointsObject, base_dir: str) -> np.ndarray:
    if o.path is not None:
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
    elif o.kind in ("soft_box", "mesh"):
        fem = o.model == "fem"
        kw = {
            "stiffness": None if fem else k,
            "damping": mat.damping,
            "E": mat.E if fem else None,
            "nu": mat.nu,
            "velocity": o.velocity,
            "name": name,
            "density": o.density,
            **r,
        }
        if o.kind == "soft_box":
            b.add_soft_box(cells=o.cells, size=o.size, origin=o.origin, **kw)
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
        return {"dt": self.dt, "substeps": self.substeps, "max_speed": self.config.scene.max_speed}

    def simulator(self, **overrides: Any) -> Any:
        """A fresh :class:`pliant.Simulator` (``overrides`` replace ``sim_kwargs`` entries)."""
        from ..sim import Simulator

        return Simulator(self.model, self.solver, **{**self.sim_kwargs, **overrides})


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

    b = ModelBuilder(gravity=cfg.scene.gravity)
    for i, o in enumerate(cfg.objects):
        try:
            _add_object(b, o, i, cfg)
        except (ValueError, FileNotFoundError) as exc:
            path = f"objects[{i}]"
            raise SceneError(src, [(_line_of(cfg.text, path), path, str(exc))]) from None
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
        raise SceneError(src, [(_line_of(cfg.text, path), path, str(exc))]) from None

    s = cfg.solver
    if kind == "force":
        terms = list(energies.mass_spring())
        if fem_energy is not None:
            try:
                terms.append(fem_energy())
            except TypeError:
                m0 = fem_objects[0].material
                terms.append(fem_energy(E=m0.E, nu=m0.nu))
        integrator = make_integrator(s.integrator, s.integrator_options, source=src, text=cfg.text)
        solver = solvers.ForceSolver(
            model,
            terms,
            integrator,
            velocity_damping=s.velocity_damping,
            damping_rate=s.damping_rate,
            **s.options,
        )
    else:
        compliance = s.compliance
        if compliance is None:
            compliance = next(
                (o.material.compliance for o in cfg.objects if o.material.compliance is not None), None
            )
        if compliance is None and any(o.material.stiffness is None for o in cfg.objects):
            compliance = 0.0  # no stiffness given: rigid distance constraints (XPBD would use α = 1/k)
        kw = {
            "iterations": s.iterations,
            "compliance": None if kind == "pbd" else compliance,
            "stiffness": s.stiffness if kind == "pbd" else None,
            "damping": s.damping_rate,
        }
        kw = {k: v for k, v in kw.items() if v is not None}
        solver = solver_cls(model, **_filtered_kwargs(solver_cls, kw), **s.options)

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
    )
