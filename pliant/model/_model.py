"""Model (static data on one device), State (x, v) and Control (what the user drives)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NoReturn

import numpy as np
import numpy.typing as npt
import warp as wp

from .._warp import mat33_type, np_dtype, scalar_type, vec3_type
from ._parameters import MODEL_ARRAYS, Parameter, array_home, control_array, declares, solver_array
from ._worlds import reset_world, set_world_material, set_world_parameter, set_world_state, world_slice

#: Default stick velocity ε_v [m/s] of the smoothed Coulomb friction every contact response applies
#: (:mod:`pliant.collision._friction`): below it friction is a viscous ramp that holds a contact loaded
#: inside the friction cone to a creep below ε_v (at most 0.15 mm over 1.5 s, ε_v s/(2b) ≈ 0.04 mm/s on
#: the incline test's μ = 0.6, tan θ = 0.5); 0 is exact, unsmoothed Coulomb.
STICK_VELOCITY = 1.0e-4

_GROUND_GRAD = (
    "with ground contact on a requires_grad model (ForceSolver or FastMassSpring with an explicit step and "
    "model.ground set)"
)


def _set_up_only(m: object, s: object, x: object, c: object) -> NoReturn:
    from .._warp import GradientError

    raise GradientError(
        "the ground's contact stiffness and damping ratio are read at set-up, not differentiated"
    )


#: κ [1/s²] of compliant ground contact: the normal force per unit mass of a particle d below the surface is
#: κ d (plus the damper); the resting depth under gravity g is g/κ. MuJoCo's solref (timeconst τ, dampratio
#: ζ) is κ = 1/(τ ζ)² (its default (0.02, 1): 2500 1/s², 3.9 mm at rest).
GROUND_STIFFNESS = Parameter(
    "ground_stiffness",
    "normal stiffness per unit mass of compliant ground contact (read at set-up)",
    "1/s^2",
    "global",
    ("solver.ground_stiffness",),
    (1.0, 1.0e9),
    differentiable=False,
    get=_set_up_only,
)
#: ζ [-] of compliant ground contact: the damper b = 2ζ√κ [1/s] (MuJoCo's dampratio; 1: critical).
GROUND_DAMPING_RATIO = Parameter(
    "ground_damping_ratio",
    "damping ratio of compliant ground contact, b = 2 zeta sqrt(kappa) (read at set-up)",
    "1",
    "global",
    ("solver.ground_damping_ratio",),
    (1.0e-3, 10.0),
    differentiable=False,
    get=_set_up_only,
)


@declares
@dataclass(frozen=True)
class Ground:
    """A ground plane n·x = height with n = +y, Coulomb friction (stick velocity ε_v [m/s]) and
    restitution; with ``stiffness`` κ [1/s²] set, compliant contact instead of the hard projection.

    Compliant contact is a spring–damper along the normal per unit mass, a = max(κ d − b v_n, 0) for a
    particle d [m] below the surface (b = 2ζ√κ [1/s], ζ = ``damping_ratio``; the damper acts on particles
    already in contact at the start of a step, and the force never pulls): it rests g/κ deep and rebounds
    as a damped oscillator of ω = √κ and damping ratio ζ, so restitution is ignored. Friction is Coulomb
    with that normal force. MuJoCo's soft contact solref = (τ, ζ) is κ = 1/(τ ζ)², the same ζ.
    """

    height: float = 0.0
    friction: float = 0.5
    restitution: float = 0.0
    stick_velocity: float = STICK_VELOCITY
    #: κ [1/s²] of compliant contact; None: hard contact (projection, restitution).
    stiffness: float | None = None
    #: ζ [-] of compliant contact (0: undamped spring).
    damping_ratio: float = 0.0
    #: The friction law's name in :data:`pliant.collision.FRICTION_LAWS` ("coulomb": smoothed Coulomb).
    friction_law: str = "coulomb"

    @property
    def compliant(self) -> bool:
        """Whether contact is the spring–damper (``stiffness`` set) rather than the hard projection."""
        return self.stiffness is not None

    @property
    def damping(self) -> float:
        """b = 2ζ√κ [1/s] of compliant contact (0 for hard contact)."""
        return 2.0 * self.damping_ratio * self.stiffness**0.5 if self.stiffness is not None else 0.0

    @classmethod
    def parameters(cls) -> tuple[Parameter, ...]:
        """Coulomb μ and restitution e (the solver's ``ground_coefficients``; a subgradient at stick/slip
        and contact switches), and compliant contact's κ and ζ (read at set-up: derivative-free fits)."""
        return (
            Parameter(
                "ground_friction",
                "Coulomb friction coefficient of the ground",
                "1",
                "global",
                ("solver.ground_coefficients[0]",),
                (0.0, 2.0),
                log=False,
                get=solver_array("ground_coefficients", _GROUND_GRAD, 0),
            ),
            Parameter(
                "ground_restitution",
                "restitution coefficient of the ground",
                "1",
                "global",
                ("solver.ground_coefficients[1]",),
                (0.0, 1.0),
                log=False,
                get=solver_array("ground_coefficients", _GROUND_GRAD, 1),
            ),
            GROUND_STIFFNESS,
            GROUND_DAMPING_RATIO,
        )


@declares
class State:
    """Particle positions and velocities of one instant.

    Attributes:
        particle_q: Positions [m], shape [particle_count] of vec3.
        particle_qd: Velocities [m/s], shape [particle_count] of vec3.
    """

    def __init__(self, particle_q: wp.array, particle_qd: wp.array) -> None:
        self.particle_q = particle_q
        self.particle_qd = particle_qd

    @property
    def x(self) -> wp.array:
        """Positions [m] (alias of ``particle_q``)."""
        return self.particle_q

    @property
    def v(self) -> wp.array:
        """Velocities [m/s] (alias of ``particle_qd``)."""
        return self.particle_qd

    def assign(self, other: State) -> None:
        """Copy ``other`` into this state (same device and shapes)."""
        wp.copy(self.particle_q, other.particle_q)
        wp.copy(self.particle_qd, other.particle_qd)

    def to_torch(self) -> tuple[Any, Any]:
        """Zero-copy PyTorch views of (positions, velocities)."""
        return wp.to_torch(self.particle_q), wp.to_torch(self.particle_qd)

    @classmethod
    def parameters(cls) -> tuple[Parameter, ...]:
        """The initial positions and velocities (of the rollout's first State)."""
        return (
            Parameter(
                "x0",
                "initial positions",
                "m",
                "particle",
                ("state.particle_q",),
                None,
                log=False,
                sign="any",
                get=lambda m, s, x, c: x.particle_q,
            ),
            Parameter(
                "v0",
                "initial velocities",
                "m/s",
                "particle",
                ("state.particle_qd",),
                None,
                log=False,
                sign="any",
                get=lambda m, s, x, c: x.particle_qd,
            ),
        )


@declares
class Control:
    """Inputs that change over time: external forces, kinematic targets and a drag handle.

    Attributes:
        particle_f: External forces [N] per particle, shape [particle_count] of vec3 (zeros by default).
        kinematic_indices: Particles whose positions are prescribed, int32 [K] (empty by default).
        kinematic_targets: Target positions [m] of those particles at the end of the next step, [K] vec3.
        drag_index: Particle pulled by the drag handle, or -1 when no handle is active.
        drag_target: Where the handle pulls [m].
        drag_stiffness: Stiffness of the handle's zero-length spring [N/m].
        drag_max_force: Cap on the handle's force [N] (inf: none). Beyond ``drag_max_force / drag_stiffness``
            from the target the handle pulls with this force, so a cursor dragged far away cannot make the
            force, and with it the particle's speed, grow without bound.
    """

    @classmethod
    def parameters(cls) -> tuple[Parameter, ...]:
        """External forces and kinematic targets, held over a rollout."""
        return (
            Parameter(
                "particle_f",
                "external force per particle",
                "N",
                "particle",
                ("control.particle_f",),
                None,
                log=False,
                sign="any",
                get=control_array("particle_f"),
            ),
            Parameter(
                "kinematic_targets",
                "target positions of the kinematic particles",
                "m",
                "particle",
                ("control.kinematic_targets",),
                None,
                log=False,
                sign="any",
                get=control_array("kinematic_targets"),
            ),
        )

    def __init__(self, model: Model) -> None:
        self._model = model
        d = model.device
        rg = model.requires_grad  # forces and targets are differentiable inputs of a recorded rollout
        self.particle_f = wp.zeros(model.particle_count, dtype=model.vec3, device=d, requires_grad=rg)
        self.kinematic_indices: wp.array = wp.array(model.kinematic_indices_np, dtype=wp.int32, device=d)
        self.kinematic_targets: wp.array = wp.array(
            model.particle_q_np[model.kinematic_indices_np], dtype=model.vec3, device=d, requires_grad=rg
        )
        self.drag_index = -1
        self.drag_target = np.zeros(3)
        self.drag_stiffness = 0.0
        self.drag_max_force = float("inf")

    def set_kinematic_targets(self, targets: np.ndarray) -> None:
        """Set the target positions [m], shape [K, 3], of the kinematic particles."""
        targets = np.asarray(targets, dtype=np_dtype(self._model.dtype)).reshape(-1, 3)
        if targets.shape[0] != self.kinematic_targets.shape[0]:
            raise ValueError(
                f"expected {self.kinematic_targets.shape[0]} kinematic targets, got {targets.shape[0]}"
            )
        self.kinematic_targets.assign(targets)

    def set_drag(
        self, index: int, target: np.ndarray, stiffness: float, max_force: float = float("inf")
    ) -> None:
        """Pull particle ``index`` toward ``target`` [m] with a spring of ``stiffness`` [N/m] whose force is
        capped at ``max_force`` [N] (default: no cap)."""
        if not 0 <= index < self._model.particle_count:
            raise ValueError(f"drag index {index} out of range [0, {self._model.particle_count})")
        if stiffness < 0:
            raise ValueError(f"drag stiffness must be >= 0 N/m, got {stiffness}")
        if not max_force > 0:
            raise ValueError(f"drag max_force must be > 0 N (inf: no cap), got {max_force}")
        self.drag_index = int(index)
        self.drag_target = np.asarray(target, dtype=float).reshape(3)
        self.drag_stiffness = float(stiffness)
        self.drag_max_force = float(max_force)

    def release_drag(self) -> None:
        """Deactivate the drag handle."""
        self.drag_index = -1


@declares
@array_home("model")
@dataclass
class Model:
    """Static simulation data on one device: topology, rest shapes, materials, masses.

    Built by :class:`pliant.ModelBuilder`; read-only during a step. Array names follow
    ``<entity>_<attribute>``; every physical array is a Warp array on ``device`` in ``dtype``.
    """

    device: str
    dtype: str
    requires_grad: bool
    particle_count: int
    particle_q: wp.array  # initial positions [m]
    particle_qd: wp.array  # initial velocities [m/s]
    particle_mass: wp.array  # [kg]
    particle_inv_mass: wp.array  # [1/kg], 0 for pinned and kinematic particles
    particle_radius: wp.array  # [m]
    spring_count: int
    spring_indices: wp.array  # int32 [S, 2]
    spring_rest_length: wp.array  # [m]
    spring_stiffness: wp.array  # [N/m]
    spring_damping: wp.array  # dashpot coefficient [N s/m]
    tri_count: int
    tri_indices: wp.array  # int32 [T, 3]
    tet_count: int
    tet_indices: wp.array  # int32 [E, 4]
    tet_rest_inv: wp.array  # Dm^-1 per tet [1/m], mat33
    tet_rest_volume: wp.array  # [m^3]
    tet_mu: wp.array  # Lamé mu per tet [Pa]
    tet_lam: wp.array  # Lamé lambda per tet [Pa]
    bending_count: int
    bending_indices: wp.array  # int32 [B, 4]: edge (0, 1), opposite vertices (2, 3)
    bending_rest_angle: wp.array  # [rad]
    bending_stiffness: wp.array  # [N m/rad]
    gravity: tuple[float, float, float]
    ground: Ground | None
    # Host-side copies for builders, validation, rendering and I/O (never used in a step).
    particle_q_np: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 3)))
    particle_mass_np: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    kinematic_indices_np: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, np.int32))
    render_faces: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 3), np.int32))
    tet_indices_np: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 4), np.int32))
    objects: list[dict] = field(default_factory=list)
    material: str | None = None
    #: Worlds (:meth:`pliant.ModelBuilder.replicate`): their count and, when more than one, the offsets
    #: [W + 1] of each element kind ("particle", "spring", "tri", "tet", "bending") per world.
    world_count: int = 1
    world_offsets: dict[str, np.ndarray] | None = field(default=None, repr=False)
    #: Quadratic (10-node) tets (``ModelBuilder.add_quadratic_tetrahedra``; node order in
    #: :mod:`pliant.geometry._p2`): count, int32 [E2, 10] nodes, corner D_m⁻¹ [1/m], volume [m³], Lamé
    #: μ, λ [Pa], and the 8 linear sub-tets per element, int32 [8 E2, 4] (inversion guards).
    tet10_count: int = 0
    tet10_indices: wp.array | None = field(default=None, repr=False)
    tet10_rest_inv: wp.array | None = field(default=None, repr=False)
    tet10_rest_volume: wp.array | None = field(default=None, repr=False)
    tet10_mu: wp.array | None = field(default=None, repr=False)
    tet10_lam: wp.array | None = field(default=None, repr=False)
    tet10_subtets: wp.array | None = field(default=None, repr=False)

    @property
    def scalar(self) -> type:
        """Warp scalar type (wp.float32 or wp.float64)."""
        return scalar_type(self.dtype)

    @property
    def vec3(self) -> type:
        """Warp vec3 type matching ``dtype``."""
        return vec3_type(self.dtype)

    @property
    def mat33(self) -> type:
        """Warp mat33 type matching ``dtype``."""
        return mat33_type(self.dtype)

    def s(self, value: float) -> wp.float32 | wp.float64:
        """``value`` as this model's Warp scalar, for kernel launches."""
        return self.scalar(value)

    def state(self, *, requires_grad: bool | None = None) -> State:
        """A fresh State initialised with the model's initial positions and velocities."""
        rg = self.requires_grad if requires_grad is None else requires_grad
        q = wp.clone(self.particle_q, requires_grad=rg)
        qd = wp.clone(self.particle_qd, requires_grad=rg)
        return State(q, qd)

    def control(self) -> Control:
        """A fresh Control with no external forces, kinematic targets at rest, no drag."""
        return Control(self)

    @property
    def gravity_vec(self) -> wp.vec3 | wp.vec3d:
        """Gravity [m/s²] as this model's vec3."""
        return self.vec3(*self.gravity)

    # ------------------------------------------------------------------ worlds
    def world_slice(self, kind: str, w: int) -> slice:
        """Index range of world ``w``'s elements of ``kind`` ("particle", "spring", "tri", "tet",
        "bending") in this model's arrays."""
        return world_slice(self, kind, w)

    def particle_world(self) -> np.ndarray:
        """World index of every particle, int32 [particle_count] (zeros for one world)."""
        if self.world_offsets is None:
            return np.zeros(self.particle_count, np.int32)
        per = int(self.world_offsets["particle"][1])
        return (np.arange(self.particle_count) // per).astype(np.int32)

    def set_world_parameter(self, name: str, w: int, value: npt.ArrayLike) -> None:
        """Set world ``w``'s per-element parameter ``name``: ``spring_stiffness`` [N/m], ``spring_damping``
        [N s/m], ``spring_rest_length`` [m], ``bending_stiffness`` [N m/rad], ``tet_mu`` / ``tet_lam``
        [Pa] or ``particle_mass`` [kg] (the inverse masses follow; fixed particles stay fixed).

        ``value`` is a scalar or one value per element of the world. Solvers that precompute from the
        parameters must be told: call ``FastMassSpring.update_parameters()`` and ``ForceSolver.reset()``
        (its lagged L-BFGS Hessian) after changing them.

        Raises:
            ValueError: an unknown name, a world out of range, a wrong count or a value out of range.
        """
        set_world_parameter(self, name, w, value)

    def set_world_material(self, w: int, E: npt.ArrayLike, nu: npt.ArrayLike) -> None:
        """Young's modulus ``E`` [Pa] and Poisson ratio ``nu`` [-] of world ``w``'s tets (via Lamé)."""
        set_world_material(self, w, E, nu)

    def set_world_state(self, w: int, x: npt.ArrayLike | None = None, v: npt.ArrayLike | None = None) -> None:
        """Replace world ``w``'s initial positions ``x`` [m] and/or velocities ``v`` [m/s], [P, 3] each
        (what :meth:`state` and :meth:`reset_world` start from)."""
        set_world_state(self, w, x, v)

    def reset_world(self, state: State, w: int) -> None:
        """Put world ``w`` of ``state`` back to its initial positions and velocities; the other worlds are
        untouched (two device copies, no host transfer)."""
        reset_world(self, state, w)

    def total_mass(self) -> float:
        """Sum of particle masses [kg]."""
        return float(self.particle_mass_np.sum())

    @classmethod
    def parameters(cls) -> tuple[Parameter, ...]:
        """The per-element arrays the Model holds (masses, springs, tets, bending elements): the energies and
        constraints that read them declare the same parameters; the Model's declaration makes them known
        (to ``set_world_parameter``) without importing those."""
        return MODEL_ARRAYS
