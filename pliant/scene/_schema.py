"""The scene-file schema (pydantic v2): value types with their bounds, the shared sections and
:class:`SceneConfig`. Object, collider and handle kinds are registered (``_registry``); their tagged unions
are (re)built into :class:`SceneConfig` when a kind is registered.

Every number is finite (``allow_inf_nan=False``) and bounded: coordinates, velocities and lengths by
``MAX_COORD`` (1e6 m; beyond it float32 loses millimetres and 1e39 overflows), counts of work per frame by
``MAX_SUBSTEPS`` / ``MAX_ITERATIONS``, the run by ``MAX_FRAMES``, so that a typo fails at load time instead
of running for hours or writing non-finite output.
"""

from __future__ import annotations

import warnings
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, Strict, model_validator

#: Bound of |coordinate| [m], |velocity| [m/s], |gravity| [m/s²] and of any length [m] in a scene file.
MAX_COORD = 1.0e6
#: Smallest length [m] (sizes, spacings, radii): below it float32 positions cannot resolve the geometry.
MIN_LENGTH = 1.0e-6
#: Bound of material constants and other positive magnitudes (stiffness, E, density ...), float32-safe.
MAX_VALUE = 1.0e30
MAX_SUBSTEPS = 10_000
MAX_ITERATIONS = 10_000
MAX_FRAMES = 1_000_000
MAX_PIXELS = 8192
#: Frame duration bounds [s]: 1 µs to 10 s.
MIN_FRAME_DT, MAX_FRAME_DT = 1.0e-6, 10.0
MAX_NAME = 100


def vector(n: int, what: str, *, scalar: bool = False):
    """Validator: a list of ``n`` items (or, with ``scalar``, one number repeated ``n`` times)."""

    def check(v: Any) -> Any:
        if scalar and isinstance(v, (int, float)) and not isinstance(v, bool):
            return [v] * n
        if not isinstance(v, (list, tuple)) or len(v) != n:
            raise ValueError(f"expected {what}, got {v!r}")
        return v

    return check


Float = Annotated[float, Strict(), Field(ge=-MAX_VALUE, le=MAX_VALUE)]
Int = Annotated[int, Strict(), Field(ge=-(2**31), le=2**31 - 1)]
Coord = Annotated[float, Strict(), Field(ge=-MAX_COORD, le=MAX_COORD)]
Length = Annotated[float, Strict(), Field(ge=MIN_LENGTH, le=MAX_COORD)]
PosFloat = Annotated[float, Strict(), Field(gt=0, le=MAX_VALUE)]
NonNegFloat = Annotated[float, Strict(), Field(ge=0, le=MAX_VALUE)]
Fraction = Annotated[float, Strict(), Field(ge=0, le=1)]
#: A mass density's log-gradient per normalised axis: exp(2 · 10) end to end is far beyond a real object.
MassSlope = Annotated[float, Strict(), Field(ge=-10, le=10)]
PosInt = Annotated[int, Strict(), Field(ge=1, le=2**31 - 1)]
Vec3 = Annotated[tuple[Coord, Coord, Coord], BeforeValidator(vector(3, "3 numbers [x, y, z]"))]
Size2 = Annotated[
    tuple[Length, Length], BeforeValidator(vector(2, "2 numbers [u, v] or one number", scalar=True))
]
Size3 = Annotated[
    tuple[Length, Length, Length],
    BeforeValidator(vector(3, "3 numbers [x, y, z] or one number", scalar=True)),
]
Scale3 = Annotated[
    tuple[PosFloat, PosFloat, PosFloat],
    BeforeValidator(vector(3, "3 numbers [x, y, z] or one number", scalar=True)),
]
Cells3 = Annotated[
    tuple[PosInt, PosInt, PosInt],
    BeforeValidator(vector(3, "3 integers [nx, ny, nz] or one integer", scalar=True)),
]


def _check_pin(v: Any) -> Any:
    if isinstance(v, str):
        return v
    if isinstance(v, list) and all(
        isinstance(i, int) and not isinstance(i, bool) and 0 <= i < 2**31 for i in v
    ):
        return v
    raise ValueError(f"expected a pin name or a list of particle indices >= 0, got {v!r}")


Pin = Annotated[Any, BeforeValidator(_check_pin)]


def _check_name(v: Any) -> Any:
    """``[scene] name`` names the output files: one safe file-name component (outputs stay in --out)."""
    if not isinstance(v, str):
        return v  # the str type reports it
    bad = (
        "is empty"
        if not v.strip()
        else f"is {len(v)} characters long (at most {MAX_NAME})"
        if len(v) > MAX_NAME
        else "contains a path separator"
        if ("/" in v or "\\" in v)
        else "contains a NUL or control character"
        if any(ord(c) < 32 or ord(c) == 127 for c in v)
        else "starts with '.'"
        if v.startswith(".")
        else "contains ':'"
        if ":" in v
        else None
    )
    if bad is not None:
        raise ValueError(
            f"the name {v[:40]!r} {bad}; it names the output files inside --out, so give one plain "
            'file name such as "my_scene" (letters, digits, "_", "-")'
        )
    return v


SafeName = Annotated[str, BeforeValidator(_check_name)]


class Section(BaseModel):
    """Base of every table: unknown keys are errors, numbers must be finite."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, validate_default=False)


class Material(Section):
    """Material parameters; which ones are needed depends on the object's ``model``. Those that a fit,
    worlds or the live view change are knobs, declared once in ``_knobs.py`` (``KNOBS``)."""

    stiffness: NonNegFloat | None = None  # spring constant k [N/m] (mass_spring) or PBD stiffness
    shear_stiffness: NonNegFloat | None = None  # cloth shear springs [N/m] (default: stiffness)
    bend_stiffness: NonNegFloat = 0.0  # cloth / rope bend springs [N/m]
    damping: NonNegFloat = 0.0  # dashpot γ along each spring [N s/m]
    Et: PosFloat | None = None  # cloth membrane stiffness E·t [N/m] (instead of stiffness)
    E: PosFloat | None = None  # Young's modulus [Pa] (fem)
    nu: Annotated[float, Strict(), Field(gt=-1.0, lt=0.5)] = 0.3  # Poisson ratio
    law: Literal["neohookean", "stvk", "corotated", "linear"] = "neohookean"  # fem material law
    compliance: NonNegFloat | None = None  # XPBD compliance α [m/N]


class ObjectBase(Section):
    """Fields every ``[[objects]]`` kind has; a kind subclasses it with ``kind: Literal["<name>"]``."""

    name: str | None = None
    model: Literal["mass_spring", "pbd", "fem"] = "mass_spring"
    material: Material = Field(default_factory=Material)
    particle_radius: Length | None = None  # contact radius [m]
    # How the object's total mass is spread over its particles (pliant.model.distribute_mass): "lumped"
    # weights each by its share of length, area or volume; "uniform" gives each M / N (MuJoCo's flexcomp,
    # PhysTwin). mass_uniformity α, when set, blends them instead, (1 − α) lumped + α uniform (a fit
    # searches it); the mass_slope_* multiply by a density exp(a · x̂) over the rest box's normalised
    # coordinates x̂ ∈ [−1, 1]. The total mass is kept in every case.
    mass_distribution: Literal["lumped", "uniform"] = "lumped"
    mass_uniformity: Fraction | None = None  # α ∈ [0, 1], overrides mass_distribution
    mass_slope_x: MassSlope = 0.0  # a_x: density ratio exp(2 a_x) from the box's −x to +x end
    mass_slope_y: MassSlope = 0.0  # a_y, along y
    mass_slope_z: MassSlope = 0.0  # a_z, along z

    def mass_blend(self) -> float:
        """α of :func:`pliant.model.distribute_mass`: ``mass_uniformity``, else 1 for ``uniform``, 0 for
        ``lumped``."""
        if self.mass_uniformity is not None:
            return float(self.mass_uniformity)
        return 1.0 if self.mass_distribution == "uniform" else 0.0

    def mass_slope(self) -> tuple[float, float, float]:
        """The density field's log-gradient (a_x, a_y, a_z) over normalised coordinates."""
        return (float(self.mass_slope_x), float(self.mass_slope_y), float(self.mass_slope_z))


class ColliderBase(Section):
    """Fields every ``[[colliders]]`` kind has."""

    friction: NonNegFloat = 0.5  # Coulomb μ
    restitution: Fraction = 0.0
    render: bool = True  # draw it in the video (a moving one where it is at each frame)
    velocity: Vec3 | None = None  # [m/s] of a kinematic collider's centre (None: static)
    angular_velocity: Vec3 | None = None  # [rad/s] about its centre
    stiffness: PosFloat | None = None  # κ [1/s²] of compliant contact (None: hard); rests g/κ deep
    damping_ratio: NonNegFloat = 0.0  # ζ of compliant contact, b = 2ζ√κ

    def contact(self) -> dict[str, Any]:
        """The keywords every ``Colliders.add_*`` takes: μ, e, motion and compliance."""
        return {
            "friction": self.friction,
            "restitution": self.restitution,
            "velocity": self.velocity,
            "angular_velocity": self.angular_velocity,
            "stiffness": self.stiffness,
            "damping_ratio": self.damping_ratio,
        }


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


class HandleConfig(Section):
    """Prescribed motion of some particles: kinematic (they follow exactly) or through springs."""

    kind: str  # a registered handle kind: "box" or "points"
    center: Vec3 | None = None  # box: the particles inside [m] at t = 0 are grabbed
    half_extents: Size3 | None = None  # box [m]
    points: list[Vec3] | None = None  # points: control points [m], linked to particles within radius
    object: str | Annotated[int, Strict(), Field(ge=0)] | None = None  # grab only this object (name/index)
    mode: Literal["kinematic", "springs"] | None = None  # default: box kinematic, points springs
    stiffness: PosFloat | None = None  # springs: k [N/m] per link
    damping: NonNegFloat = 0.0  # springs: γ [N s/m] per link
    radius: Length | None = None  # points: link particles within this distance [m]
    max_links: Annotated[int, Strict(), Field(ge=1, le=1024)] = 16  # points: links per control point
    path: Annotated[list[tuple[Coord, Coord, Coord, Coord]], BeforeValidator(_check_keyframes)] | None = None
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

    def max_speed(self) -> float:
        """Largest speed [m/s] of the prescribed motion (piecewise linear path, or the velocity)."""
        if self.path is not None and len(self.path) > 1:
            k = np.asarray(self.path)
            return float(np.max(np.linalg.norm(np.diff(k[:, 1:], axis=0), axis=1) / np.diff(k[:, 0])))
        return float(np.linalg.norm(self.velocity)) if self.velocity is not None else 0.0


class SelfCollisionConfig(Section):
    thickness: Length  # minimum distance between particles / particle and triangle [m]; barrier: its d̂
    #: "projection": the post-step pass (pl.collision.SelfCollision); "barrier": IPC's log barrier within
    #: d̂ = thickness for point–triangle and edge–edge pairs, intersection-free (implicit ForceSolver only).
    contact: Literal["projection", "barrier"] = "projection"
    kappa: PosFloat | None = None  # barrier stiffness κ [N/m]; None: pl.energies.BarrierContact's default
    #: Coulomb μ between layers: SelfCollision's and the step bound's push (XPBD / PBD: the contact
    #: constraints' and the bound's push); barrier: the lagged friction's μ
    friction: NonNegFloat = 0.0
    iterations: Annotated[int, Strict(), Field(ge=1, le=100)] = 2  # force solver: passes per step
    particles: bool = True  # particle–particle contacts
    triangles: bool = True  # particle–triangle contacts
    #: γ in (0, 0.5): truncate each step's displacements to γ × the distance to the nearest other primitive
    #: (pl.collision.StepBound, reach = thickness): no tunnelling; off by default
    bound: Annotated[float, Strict(), Field(gt=0, lt=0.5)] | None = None


class SceneSection(Section):
    name: SafeName = "scene"
    #: Frame duration [s]: the time between two saved frames (the simulator's ``dt``); ``dt`` is the old key.
    frame_dt: Annotated[float, Strict(), Field(ge=MIN_FRAME_DT, le=MAX_FRAME_DT)] = 1.0 / 60.0
    substeps: Annotated[int, Strict(), Field(ge=1, le=MAX_SUBSTEPS)] = 16
    frames: Annotated[int, Strict(), Field(ge=0, le=MAX_FRAMES)] = 120
    gravity: Vec3 = (0.0, -9.81, 0.0)  # [m/s²]
    device: str | None = None
    dtype: Literal["float32", "float64"] = "float32"
    max_speed: Annotated[float, Strict(), Field(gt=0, le=MAX_COORD)] = 1.0e3  # divergence bound [m/s]
    #: NPZ of per-element values (``pliant fit``) applied after building: ``model.<array>`` and
    #: ``constraints.<i>.<array>`` keys; a path relative to the scene file.
    parameters: str | None = None

    @model_validator(mode="before")
    @classmethod
    def _renamed(cls, data: Any) -> Any:
        return renamed_key(data, "dt", "frame_dt", "scene", "the frame duration [s]")

    @property
    def dt(self) -> float:
        """Deprecated alias of :attr:`frame_dt` (the frame duration [s])."""
        return self.frame_dt

    @dt.setter
    def dt(self, value: float) -> None:
        self.frame_dt = value


def renamed_key(data: Any, old: str, new: str, section: str, what: str) -> Any:
    """Accept the old key ``old`` of ``[section]`` as ``new`` with a one-line DeprecationWarning."""
    if isinstance(data, dict) and old in data:
        if new in data:
            raise ValueError(f"give {new} only ({old} is its deprecated name)")
        warnings.warn(
            f"[{section}] {old} is deprecated; rename it to {new} ({what})", DeprecationWarning, stacklevel=2
        )
        data = {(new if k == old else k): v for k, v in data.items()}
    return data


class GroundSection(Section):
    enabled: bool = True
    height: Coord = 0.0  # [m]
    friction: NonNegFloat = 0.5
    restitution: Fraction = 0.0
    # ε_v [m/s]: below it Coulomb friction is a smooth viscous ramp; pl.model.STICK_VELOCITY (the schema
    # imports nothing of pliant; tests/test_friction_incline.py checks they agree)
    stick_velocity: NonNegFloat = 1.0e-4
    # a law of pl.collision.FRICTION_LAWS ("coulomb": smoothed; "coulomb_exact"), checked at build
    friction_law: str = "coulomb"
    # κ [1/s²] of compliant contact, a normal spring κ d per unit mass (rests g/κ deep; MuJoCo's solref
    # (τ, ζ) is κ = 1/(τ ζ)²), in every solver instead of the hard projection and restitution; unset: hard
    # contact (implicit integrators' Newton still sees a ground penalty, κ = 1e6).
    stiffness: PosFloat | None = None
    # ζ [-] of compliant contact's damper b = 2ζ√κ (MuJoCo's dampratio; 1: critical); unset: 0.
    damping_ratio: NonNegFloat | None = None

    #: "penalty": the hard projection, or compliant contact with stiffness (above); "barrier": IPC's log
    #: barrier within ``dhat`` against the ground and the colliders, with a CCD-bounded Newton step,
    #: intersection-free (implicit ForceSolver only); their friction μ then acts as IPC's lagged friction
    #: with this stick_velocity.
    contact: Literal["penalty", "barrier"] = "penalty"
    dhat: Length = 1.0e-3  # barrier: the distance d̂ [m] below which it acts
    kappa: PosFloat | None = None  # barrier stiffness κ [N/m]; None: pl.energies.BarrierContact's default

    @model_validator(mode="after")
    def _damper_needs_spring(self) -> GroundSection:
        if self.damping_ratio and self.stiffness is None:
            raise ValueError("damping_ratio needs stiffness (compliant contact): give ground.stiffness too")
        if self.contact == "barrier" and self.stiffness is not None:
            raise ValueError(
                'contact = "barrier" and stiffness (compliant contact) are two contact models: give one'
            )
        return self


class SolverSection(Section):
    kind: str | None = None  # a registered solver kind; default: from the objects' models
    integrator: str = "SymplecticEuler"
    integrator_options: dict[str, Any] = Field(default_factory=dict)
    iterations: Annotated[int, Strict(), Field(ge=1, le=MAX_ITERATIONS)] = 10
    velocity_damping: Annotated[float, Strict(), Field(gt=0, le=1)] = 1.0
    damping_rate: NonNegFloat | None = None  # [1/s]
    compliance: NonNegFloat | None = None  # XPBD default compliance [m/N]
    #: PBD's dimensionless constraint stiffness k ∈ [0, 1] (``stiffness`` is its old name).
    stiffness_factor: Fraction | None = None
    options: dict[str, Any] = Field(default_factory=dict)  # extra solver keyword arguments
    self_collision: SelfCollisionConfig | None = None

    @model_validator(mode="before")
    @classmethod
    def _renamed(cls, data: Any) -> Any:
        return renamed_key(data, "stiffness", "stiffness_factor", "solver", "PBD's dimensionless k in [0, 1]")


class CameraSection(Section):
    eye: Vec3 | None = None
    target: Vec3 | None = None
    up: Vec3 = (0.0, 1.0, 0.0)
    fov: Annotated[float, Strict(), Field(ge=1.0, le=179.0)] = 40.0  # vertical [deg]
    width: Annotated[int, Strict(), Field(ge=1, le=MAX_PIXELS)] = 640
    height: Annotated[int, Strict(), Field(ge=1, le=MAX_PIXELS)] = 480


class OutputSection(Section):
    video: bool = True
    fps: Annotated[float, Strict(), Field(ge=1.0, le=1000.0)] | None = None  # default 1 / frame_dt
    trajectory: bool = True
    checkpoint_every: Annotated[int, Strict(), Field(ge=0, le=MAX_FRAMES)] = 50
    record_velocity: bool = False


class Entry(Section):
    """One ``[[energies]]`` or ``[[constraints]]`` entry: a registered kind and its keyword options."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)
    kind: str

    def options(self) -> dict[str, Any]:
        """The entry's keyword arguments (every key but ``kind``)."""
        return dict(self.model_extra or {})


class SceneConfig(Section):
    """A validated scene file. ``source`` is the file it came from (for messages and relative paths)."""

    scene: SceneSection = Field(default_factory=SceneSection)
    objects: Annotated[list[Any], Field(min_length=1)]  # replaced by the registered kinds' union
    colliders: list[Any] = Field(default_factory=list)  # idem
    handles: list[HandleConfig] = Field(default_factory=list)
    energies: list[Entry] = Field(default_factory=list)  # extra force-solver energies, by registered kind
    constraints: list[Entry] = Field(default_factory=list)  # extra XPBD constraints, by registered kind
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

    def object_names(self) -> list[str]:
        """Each object's name, ``<kind><index>`` where none is given."""
        return [o.name or f"{o.kind}{i}" for i, o in enumerate(self.objects)]
