"""Building a validated scene: the Model from the registered object kinds, contact handlers, handles, and
the Solver from the registered solver kind; :class:`Scene` holds what a run and its video need."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from .._prebuild import maybe_prebuild
from .._time import substep_dt
from ._context import BuildContext
from ._errors import SceneError
from ._registry import (
    COLLIDER_KINDS,
    CONSTRAINT_KINDS,
    ENERGY_KINDS,
    HANDLE_KINDS,
    OBJECT_KINDS,
    SOLVER_KINDS,
    handle_mode,
)
from ._replicate import replicate_scene
from ._schema import ObjectBase, OutputSection, SceneConfig

if TYPE_CHECKING:
    from ..collision import Colliders
    from ..model import Control, Model
    from ..render import Camera
    from ..sim import Simulator
    from ..solvers import Solver

#: Video colours (RGB in [0, 1]) of simulated bodies and of drawn colliders.
BODY_COLOR = (0.91, 0.42, 0.16)
COLLIDER_COLOR = (0.55, 0.62, 0.72)


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

        scene = pl.scene.build_scene(pl.scene.load_scene("cloth"), device="cpu")
        traj = scene.simulator().run(frames=scene.frames)
    """

    config: SceneConfig
    model: Model
    solver: Solver
    frame_dt: float  # frame duration [s] (the Simulator's dt); each frame runs `substeps` solver steps
    substeps: int
    frames: int
    camera: Camera | None = None  # None to frame the motion automatically
    outputs: OutputSection = field(default_factory=OutputSection)
    colliders: Colliders | None = None  # the [[colliders]], or None
    control_fn: Callable[[float, Control | None], None] | None = None  # moves the [[handles]]
    control_points: list = field(default_factory=list)  # pl.energies.ControlPoints of spring handles
    embeddings: list[Embedding] = field(default_factory=list)
    static_meshes: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)  # drawn colliders
    #: per drawn collider, its motion (``centre``, ``velocity``, ``angular_velocity``), empty when static
    static_motions: list[dict[str, Any]] = field(default_factory=list)

    @property
    def dt(self) -> float:
        """Deprecated alias of :attr:`frame_dt` (the frame duration [s])."""
        warnings.warn(
            "Scene.dt is deprecated; use Scene.frame_dt (the frame duration [s])",
            DeprecationWarning,
            stacklevel=2,
        )
        return self.frame_dt

    @property
    def substep_dt(self) -> float:
        """The solver's step ``dt`` [s]: ``frame_dt / substeps`` (:func:`pliant._time.substep_dt`)."""
        return substep_dt(self.frame_dt, self.substeps)

    @property
    def name(self) -> str:
        """The scene's name."""
        return self.config.scene.name

    @property
    def fps(self) -> float:
        """Video frame rate: ``[output] fps`` or 1 / frame_dt."""
        return float(self.outputs.fps or 1.0 / self.frame_dt)

    @property
    def sim_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :class:`pliant.Simulator` (``frame_dt``: the frame duration [s])."""
        kw: dict[str, Any] = {
            "frame_dt": self.frame_dt,
            "substeps": self.substeps,
            "max_speed": self.config.scene.max_speed,
        }
        if self.control_fn is not None:
            kw["control_fn"] = self.control_fn
        return kw

    def simulator(self, **overrides: Any) -> Simulator:
        """A fresh :class:`pliant.Simulator` (``overrides`` replace ``sim_kwargs`` entries)."""
        from ..sim import Simulator

        if self.control_fn is not None:
            self.control_fn(0.0, None)  # handles back to their start
        return Simulator(self.model, self.solver, **{**self.sim_kwargs, **overrides})

    def prebuild_kernels(self) -> int:
        """Start compiling the kernels a built-in scene's first frames launch, on background threads
        (:func:`pliant._prebuild.maybe_prebuild`: CPU, float32, no gradients, a stored manifest). The runner
        calls this before its first step, so the compilation overlaps what it does meanwhile (splats, the
        correction twin); building a scene alone compiles nothing.

        Returns the number of modules queued (0 when there is nothing to prebuild)."""
        return maybe_prebuild(self.config.scene.name, self.model)

    def _drawn(self) -> list[dict[str, Any]]:
        """The drawn colliders as ``meta["colliders"]`` entries (points, faces and a moving one's motion)."""
        motions = self.static_motions or [{} for _ in self.static_meshes]
        pairs = zip(self.static_meshes, motions, strict=True)
        return [{"points": p, "faces": f, **mo} for (p, f), mo in pairs]

    def trajectory_meta(self) -> dict[str, Any]:
        """What a saved trajectory carries beside the simulator's meta so that ``pliant view`` and
        ``pliant export`` draw the whole scene: its name, the ground height (None without one) and the drawn
        colliders (points where they were added and faces, rounded to µm; a moving one's ``centre``,
        ``velocity`` and ``angular_velocity`` too: :func:`pliant.render.collider_points` poses it)."""
        m = self.model
        out = []
        for c in self._drawn():
            c = {**c, "points": np.asarray(c["points"], float).round(6).tolist()}
            out.append(c | {"faces": np.asarray(c["faces"]).tolist()})
        return {
            "scene": self.config.scene.name,
            "ground": m.ground.height if m.ground is not None else None,
            "colliders": out,
        }

    def render_mesh(
        self, x: np.ndarray, faces: np.ndarray | None, t: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """What to draw for positions ``x`` [T, N, 3] (or [N, 3]): embedded fine surfaces replace their tet
        meshes' surfaces, and colliders with ``render = true`` are added as grey meshes.

        Args:
            x: particle positions [m] per frame.
            faces: the model's render triangles.
            t: the frames' times [s] since the start, one per frame: moving colliders are drawn where they
                are then (:func:`pliant.render.collider_points`); None: where they were added.

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
        for c in self._drawn():
            v = np.asarray(c["points"])
            if t is not None and "velocity" in c:
                from ..render import collider_points

                parts.append(collider_points(c, np.asarray(t).reshape(-1)[: xs.shape[0]]))
            else:
                parts.append(np.broadcast_to(v, (xs.shape[0], *v.shape)))
            fparts.append(c["faces"] + count)
            count += len(v)
        out = np.concatenate(parts, axis=1)
        out_faces = np.concatenate(fparts).astype(np.int32) if fparts else None
        colors = np.empty((count, 3))
        colors[:n_body] = BODY_COLOR
        colors[n_body:] = COLLIDER_COLOR
        return (out[0] if single else out), out_faces, colors


# ---------------------------------------------------------------------------------------------- steps
def _add_objects(ctx: BuildContext) -> None:
    for i, o in enumerate(ctx.cfg.objects):
        start = ctx.builder.particle_count
        try:
            OBJECT_KINDS[o.kind].build(ctx, o, i)
        except (ValueError, FileNotFoundError) as exc:
            if isinstance(exc, SceneError):
                raise
            raise ctx.fail(f"objects[{i}]", str(exc)) from None
        ctx.ranges.append((start, ctx.builder.particle_count))
        _distribute_mass(ctx, o, start)


def _distribute_mass(ctx: BuildContext, o: ObjectBase, start: int) -> None:
    """Spread object ``o``'s mass (particles ``start`` onwards) as its ``mass_distribution``,
    ``mass_uniformity`` and ``mass_slope_*`` say; the lumped default leaves the builder's masses untouched
    (bit for bit)."""
    from ..model import distribute_mass

    alpha, slope = o.mass_blend(), o.mass_slope()
    if alpha == 0.0 and not any(slope):
        return
    b = ctx.builder
    lumped = b.particle_masses(start)
    b.set_particle_masses(
        start, distribute_mass(lumped, b.positions()[start:], uniformity=alpha, slope=slope)
    )


def lumped_masses(cfg: SceneConfig) -> list[np.ndarray]:
    """The particle masses [kg] each object of ``cfg`` gets from its builder (its lumped distribution,
    whatever its ``mass_*`` fields say), one array per object; nothing is built on a device.

    Raises:
        SceneError: an object that cannot be built.
    """
    return [m for m, _ in lumped_particles(cfg)]


def lumped_particles(cfg: SceneConfig) -> list[tuple[np.ndarray, np.ndarray]]:
    """(lumped masses [kg], shape (n,); rest positions [m], shape (n, 3)) of each object of ``cfg``, as
    :func:`lumped_masses` builds them (on the host, no device).

    Raises:
        SceneError: an object that cannot be built.
    """
    from ..model import ModelBuilder

    cfg = cfg.model_copy(deep=True)
    for o in cfg.objects:
        o.mass_distribution, o.mass_uniformity = "lumped", None
        o.mass_slope_x = o.mass_slope_y = o.mass_slope_z = 0.0
    ctx = BuildContext(cfg, ModelBuilder(gravity=cfg.scene.gravity))
    _add_objects(ctx)
    m, q = ctx.builder.particle_masses(), ctx.builder.positions()
    return [(m[a:b], q[a:b]) for a, b in ctx.ranges]


def _select_handles(ctx: BuildContext) -> tuple[list, list]:
    """Kinematic handles (marked in the builder before finalize) and spring handles' control points."""
    names = ctx.cfg.object_names()
    kin: list[tuple[Any, slice, np.ndarray]] = []
    springs: list[tuple[int, Any, np.ndarray]] = []
    n_kin = 0
    for i, h in enumerate(ctx.cfg.handles):
        lo, hi = 0, ctx.builder.particle_count
        if h.object is not None:
            lo, hi = ctx.ranges[h.object if isinstance(h.object, int) else names.index(h.object)]
        idx, pts = HANDLE_KINDS[h.kind].select(ctx, h, lo, hi, i)
        if handle_mode(h) == "kinematic":
            ctx.builder.add_kinematic(idx)
            kin.append((h, slice(n_kin, n_kin + idx.size), pts))
            n_kin += idx.size
        else:
            springs.append((i, h, pts))
    return kin, springs


def _finalize(ctx: BuildContext, device: str | None, dtype: str | None, requires_grad: bool = False) -> None:
    cfg = ctx.cfg
    g = cfg.ground
    if g is not None and g.enabled:
        from ..collision import FRICTION_LAWS

        if g.friction_law not in FRICTION_LAWS:
            raise ctx.fail(
                "ground.friction_law", f"unknown law {g.friction_law!r}; one of {sorted(FRICTION_LAWS)}"
            )
        ctx.builder.add_ground(
            g.height,
            friction=g.friction,
            restitution=g.restitution,
            stick_velocity=g.stick_velocity,
            stiffness=g.stiffness,
            damping_ratio=g.damping_ratio or 0.0,
            friction_law=g.friction_law,
        )
    try:
        ctx.model = ctx.builder.finalize(
            device=device or cfg.scene.device, dtype=dtype or cfg.scene.dtype, requires_grad=requires_grad
        )
    except ValueError as exc:
        if device is None and cfg.scene.device is not None and "device" in str(exc):
            path = "scene.device"
        elif "device" in str(exc):
            raise
        else:
            path = "objects"
        raise ctx.fail(path, str(exc)) from None


def _embeddings(ctx: BuildContext, x0: np.ndarray) -> list[Embedding]:
    """Locate each object's fine render mesh in its tets."""
    import trimesh

    from ..geometry import locate_points
    from ._files import load_surface_file
    from ._objects import orient

    out = []
    tets = ctx.finalized.tet_indices_np
    for i, o in enumerate(ctx.cfg.objects):
        rm = getattr(o, "render_mesh", None)
        if rm is None:
            continue
        at = f"objects[{i}].render_mesh"
        start, stop = ctx.ranges[i]
        center = np.asarray(rm.center if rm.center is not None else o.origin)
        if rm.icosphere is not None:
            r = rm.radius or getattr(o, "radius", None) or 0.5 * float(min(getattr(o, "size", (1.0,))))
            m = trimesh.creation.icosphere(subdivisions=rm.icosphere, radius=r)
            v, f = np.asarray(m.vertices) + center, np.asarray(m.faces)
        else:
            mesh = load_surface_file(ctx.cfg, rm.path, f"{at}.path")
            # Turned like its object (up, rotation), so a rotated mesh keeps its render mesh aligned.
            v = orient(np.asarray(mesh.points) * np.asarray(rm.scale), o) + center
            f = np.asarray(mesh.triangles)
        mine = tets[np.all((tets >= start) & (tets < stop), axis=1)]
        if mine.shape[0] == 0:
            raise ctx.fail(at, f"objects[{i}] has no tetrahedra to embed a render mesh in")
        try:
            tet_ids, bary = locate_points(v, x0, mine)[:2]
        except (ValueError, IndexError) as exc:
            raise ctx.fail(at, f"cannot embed the render mesh in the object's tets ({exc})") from None
        out.append(
            Embedding(start, stop - start, mine, np.asarray(tet_ids), np.asarray(bary), f.astype(np.int32))
        )
    return out


def _colliders(ctx: BuildContext) -> tuple[Colliders | None, list, list]:
    """The [[colliders]], their drawings (vertices, faces) and the drawn ones' motions (empty: static)."""
    from ..collision import Colliders

    if not ctx.cfg.colliders:
        return None, [], []
    colliders, drawn, motions = Colliders(), [], []
    for i, c in enumerate(ctx.cfg.colliders):
        try:
            mesh = COLLIDER_KINDS[c.kind].add(colliders, ctx.cfg, c, f"colliders[{i}]")
        except (ValueError, FileNotFoundError) as exc:
            if isinstance(exc, SceneError):
                raise
            raise ctx.fail(f"colliders[{i}]", str(exc)) from None
        if mesh is not None:
            drawn.append((np.asarray(mesh[0], float), np.asarray(mesh[1], np.int32)))
            d = colliders.describe()[-1]
            motions.append({k: d[k] for k in ("centre", "velocity", "angular_velocity") if k in d})
    ctx.handlers.append(colliders)
    return colliders, drawn, motions


def _spring_handles(ctx: BuildContext, spring_handles: list) -> tuple[list, list]:
    """``pl.energies.ControlPoints`` of the spring handles (added to ``ctx.terms``)."""
    from .. import energies

    cps, springs = [], []
    for i, h, pts in spring_handles:
        try:
            cp = energies.ControlPoints(
                ctx.finalized,
                pts,
                stiffness=h.stiffness,
                radius=h.radius if h.radius is not None else 1e-6,
                max_links=h.max_links if h.kind == "points" else 1,
                damping=h.damping,
                zero_rest=h.kind == "box",
            )
        except ValueError as exc:
            raise ctx.fail(f"handles[{i}]", str(exc)) from None
        ctx.terms.append(cp)
        cps.append(cp)
        springs.append((h, cp, pts))
    return cps, springs


def _extra_constraints(ctx: BuildContext) -> None:
    """Shape matching of cluster objects, self-collision constraints and ``[[constraints]]`` (XPBD / PBD)."""
    from .. import constraints as C

    cfg, model = ctx.cfg, ctx.finalized
    by_k: dict[tuple[float, bool], list[np.ndarray]] = {}
    radii = model.particle_radius.numpy()
    for o, (lo, hi) in zip(cfg.objects, ctx.ranges, strict=True):
        if o.kind == "cluster":
            k_s = 1.0 if o.rigid else (o.shape_stiffness if o.shape_stiffness is not None else 0.5)
            by_k.setdefault((k_s, o.oriented), []).append(np.arange(lo, hi))
    for (k_s, oriented), clusters in by_k.items():
        ctx.constraints.append(C.ShapeMatching(clusters, stiffness=k_s, radii=radii if oriented else None))
    sc = cfg.solver.self_collision
    if sc is not None:
        if sc.particles:
            ctx.constraints.append(C.ParticleCollision(friction=sc.friction))
        if sc.triangles and model.tri_count:
            ctx.constraints.append(C.PointTriangleCollision(thickness=sc.thickness, friction=sc.friction))


def _entries(ctx: BuildContext, section: str, registry: dict, out: list) -> None:
    """The ``[[energies]]`` / ``[[constraints]]`` entries, built by their registered factories."""
    for i, e in enumerate(getattr(ctx.cfg, section)):
        try:
            out.append(registry[e.kind].factory(ctx.model, **e.options()))
        except (TypeError, ValueError) as exc:
            raise ctx.fail(f"{section}[{i}]", f"{e.kind}: {exc}") from None


def _make_control_fn(frame_dt: float, kin: list[tuple[Any, slice, np.ndarray]], springs: list):
    """f(t, control): kinematic targets / control points at the end of the coming frame (t + frame_dt)."""
    state: dict[str, np.ndarray | None] = {"targets": None}

    def control_fn(t: float, control: Control | None) -> None:
        te = t + frame_dt if control is not None else 0.0
        if kin:
            targets = state["targets"]
            if targets is None:
                targets = state["targets"] = np.concatenate([x0 for _, _, x0 in kin])
            tg = targets.copy()
            for h, sl, x0 in kin:
                tg[sl] = x0 + h.offset(te)
            if control is not None:
                control.set_kinematic_targets(tg)
        for h, cp, x0 in springs:
            vel = (h.offset(te + 1e-3) - h.offset(max(te - 1e-3, 0.0))) / (te + 1e-3 - max(te - 1e-3, 0.0))
            cp.set_positions(x0 + h.offset(te), np.broadcast_to(vel, x0.shape))

    return control_fn


def _camera(cfg: SceneConfig) -> Camera | None:
    c = cfg.camera
    if c.eye is None:
        return None
    if c.target is None:  # the loader's checks ask for both
        raise ValueError("camera.eye needs camera.target")
    from ..render import Camera

    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (c.eye, c.target, c.up))
    return Camera(eye=eye, target=target, up=up, fov_y=c.fov, width=c.width, height=c.height)


def _apply_parameters(ctx: BuildContext, solver: Solver, parameters: str) -> None:
    """``[scene] parameters``: per-element values (a fit's output, in the file ``parameters`` relative to
    the scene file) replace the built arrays."""
    from ..io import read_npz
    from ._files import scene_path

    path = scene_path(ctx.cfg, parameters, "scene.parameters")
    data = read_npz(path, "parameter", lambda msg: ctx.fail("scene.parameters", msg))
    for key, value in data.items():
        parts = key.split(".")
        if parts[0] == "model" and len(parts) == 2:
            target = getattr(ctx.model, parts[1], None)
        elif parts[0] == "constraints" and len(parts) == 3 and parts[1].isdigit():
            cons = getattr(solver, "constraints", [])
            c = cons[int(parts[1])] if int(parts[1]) < len(cons) else None
            target = getattr(c, parts[2], None)
        else:
            target = None
        if target is None or not hasattr(target, "assign") or tuple(target.shape) != value.shape:
            raise ctx.fail(
                "scene.parameters",
                f"{path}: {key} {value.shape} does not match this scene (expected model.<array> or "
                "constraints.<i>.<array> of the same shape); refit or remove the parameters key",
            )
        target.assign(value)


def build_scene(
    cfg: SceneConfig,
    device: str | None = None,
    dtype: str | None = None,
    requires_grad: bool = False,
    *,
    worlds: int = 1,
    world_parameters: Sequence[dict[str, Any]] | None = None,
) -> Scene:
    """Build the Model and Solver a scene describes, on ``device`` in ``dtype`` (defaults: the file's).

    Args:
        cfg: A validated scene (:func:`load_scene` / :func:`parse_scene`).
        device: Warp device (``"cpu"``, ``"cuda:0"``); None: ``[scene] device`` or Warp's default.
        dtype: ``"float32"`` or ``"float64"``; None: ``[scene] dtype``.
        requires_grad: Finalize the model with gradient arrays (tape-differentiable steps, for fitting).
        worlds: Replicate the objects into this many worlds (``ModelBuilder.replicate``); see
            :func:`~pliant.scene.build_worlds` for worlds of different material values.
        world_parameters: Per world, ``{model array: values}`` set with ``Model.set_world_parameter``
            before the solver is made.

    Raises:
        SceneError: a file, option or geometry the build cannot use, naming the field.
    """
    from ..model import ModelBuilder

    ctx = BuildContext(cfg, ModelBuilder(gravity=cfg.scene.gravity))
    _add_objects(ctx)
    x0 = ctx.builder.positions()
    kin, spring_handles = _select_handles(ctx)
    if worlds != 1:
        replicate_scene(ctx, worlds)
    _finalize(ctx, device, dtype, requires_grad)
    for w, params in enumerate(world_parameters or ()):
        for name, value in params.items():
            ctx.finalized.set_world_parameter(name, w, value)
    embeddings = _embeddings(ctx, x0)
    colliders, static_meshes, static_motions = _colliders(ctx)
    control_points, springs = _spring_handles(ctx, spring_handles)
    _entries(ctx, "energies", ENERGY_KINDS, ctx.terms)
    _extra_constraints(ctx)
    _entries(ctx, "constraints", CONSTRAINT_KINDS, ctx.constraints)
    solver = SOLVER_KINDS[cfg.solver_kind()].factory(ctx)
    if cfg.scene.parameters is not None:
        _apply_parameters(ctx, solver, cfg.scene.parameters)
    return Scene(
        config=cfg,
        model=ctx.finalized,
        solver=solver,
        frame_dt=cfg.scene.frame_dt,
        substeps=cfg.scene.substeps,
        frames=cfg.scene.frames,
        camera=_camera(cfg),
        outputs=cfg.output,
        colliders=colliders,
        control_fn=_make_control_fn(cfg.scene.frame_dt, kin, springs) if (kin or springs) else None,
        control_points=control_points,
        embeddings=embeddings,
        static_meshes=static_meshes,
        static_motions=static_motions,
    )
