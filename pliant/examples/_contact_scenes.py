"""Issue 39's five contact scenes, small enough for CI: they must never intersect
(tests/test_contact_scenes.py judges them with ipctk, an independent test).

* ``napkin``: a cloth on the ground, folded corner to corner by a kinematic handle;
* ``twist``: a square cloth whose two ends rotate at ±72°/s about its axis (Codim-IPC's twist set-up);
* ``sphere``: a cloth dropped on a sphere spinning at 180°/s about the vertical, friction μ = 0.4;
* ``boxes``: three soft boxes dropped in a stack on the ground;
* ``ball``: a 0.5 mm-thick cloth pinned at its corners, hit by a 5 cm ball at 20 m/s.

Every scene is mass-spring cloth or soft bodies with :class:`pliant.collision.SelfCollision` (particle–
particle and particle–triangle contact with a thickness) and :class:`pliant.collision.StepBound` (the
per-vertex displacement bound that keeps any vertex–triangle or edge–edge pair from crossing within a
step). Colliders that move (the spinning sphere) are kinematic triangle meshes in the model, so the same
contact code and the same bound see them. ``family`` picks the solver: ``"force"`` (symplectic Euler),
``"fms"`` (FastMassSpring) or ``"xpbd"``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

import pliant as pl

FAMILIES = ("force", "fms", "xpbd")

#: Speed [m/s] at which the twist's two ends approach each other (each end).
SQUEEZE = 0.0


@dataclass
class ContactScene:
    """A scene ready to run: its model and solver, the time stepping and the kinematic motion.

    Attributes:
        name: the scene's name.
        model: the Model (every contact surface is in ``model.tri_indices``).
        solver: the solver (contact handlers attached).
        frame_dt: time between recorded frames [s].
        substeps: solver steps per frame.
        frames: frames to run.
        drive: ``drive(t)`` → [K, 3] targets [m] of ``model``'s kinematic particles at time t [s]; None: none.
        wall: seconds the last :meth:`run` took (stepping only).
    """

    name: str
    model: pl.Model
    solver: pl.solvers.Solver
    frame_dt: float
    substeps: int
    frames: int
    drive: Callable[[float], np.ndarray] | None = None
    wall: float = field(default=0.0, init=False)

    def run(self, frames: int | None = None) -> np.ndarray:
        """Run ``frames`` frames (default: the scene's); returns [F + 1, N, 3] positions [m], frame 0
        first."""
        n = self.frames if frames is None else int(frames)
        m = self.model
        dt = self.frame_dt / self.substeps
        control = m.control()
        s0, s1 = m.state(), m.state()
        out = [s0.particle_q.numpy().copy()]
        start = time.perf_counter()
        for f in range(n):
            for k in range(self.substeps):
                if self.drive is not None:
                    control.kinematic_targets.assign(self.drive((f * self.substeps + k + 1) * dt))
                self.solver.step(s0, s1, control, dt)
                s0, s1 = s1, s0
            out.append(s0.particle_q.numpy().copy())
        self.wall = time.perf_counter() - start
        return np.array(out)


def _solver(
    model: pl.Model,
    family: str,
    contact: list,
    *,
    damping_rate: float = 1.0,
    iterations: int = 10,
    compliance: float = 0.0,
) -> pl.solvers.Solver:
    """The family's solver with the contact handlers (run after each step, the bound last)."""
    if family == "force":
        return pl.solvers.ForceSolver(
            model,
            pl.energies.mass_spring(),
            pl.integrators.SymplecticEuler(),
            damping_rate=damping_rate,
            collisions=contact,
        )
    if family == "fms":
        return pl.solvers.FastMassSpring(model, damping_rate=damping_rate, collisions=contact)
    if family == "xpbd":
        return pl.solvers.XPBD(
            model, iterations=iterations, compliance=compliance, damping=damping_rate, collisions=contact
        )
    raise ValueError(f"_contact_scenes: family must be one of {FAMILIES}, got {family!r}")


def _contact(model: pl.Model, thickness: float, friction: float, reach: float | None = None) -> list:
    """SelfCollision with ``thickness`` [m] and μ, then the step bound (γ = 0.4, reach [m], default the
    thickness), whose separation push has the same μ."""
    return [
        pl.collision.SelfCollision(model, thickness=thickness, friction=friction),
        pl.collision.StepBound(
            model,
            fraction=0.4,
            reach=thickness if reach is None else reach,
            separation=thickness,
            friction=friction,
        ),
    ]


def _smoothstep(s: float) -> float:
    s = min(max(s, 0.0), 1.0)
    return s * s * (3.0 - 2.0 * s)


def napkin(n: int = 16, family: str = "force", frames: int = 90) -> ContactScene:
    """A 0.5 m napkin of n × n cells on the ground, its corner carried over to the opposite corner in 1.2 s
    along an arch 0.15 m high (thickness 1 cm, as in the issue's 32 × 32 fold)."""
    h, size, radius = 0.01, 0.5, 0.004
    b = pl.ModelBuilder()
    b.add_cloth_grid(
        nx=n, ny=n, size=size, mass=0.1, stiffness=100.0, bend_stiffness=0.5, damping=0.002,
        origin=(-size / 2, radius, -size / 2), plane="xz", radius=radius,
    )  # fmt: skip
    b.add_kinematic([0])
    b.add_ground(0.0, friction=0.6)
    model = b.finalize(device="cpu")
    c0 = model.particle_q_np[0].astype(np.float64)
    c1 = model.particle_q_np[-1].astype(np.float64) + (0.0, 2.0 * h, 0.0)

    def drive(t: float) -> np.ndarray:
        s = _smoothstep(t / 1.2)
        return (c0 + s * (c1 - c0) + (0.0, 0.15 * np.sin(np.pi * s), 0.0))[None]

    contact = _contact(model, h, 0.2)
    return ContactScene("napkin", model, _solver(model, family, contact), 1 / 60, 40, frames, drive)


def twist(n: int = 16, family: str = "force", frames: int = 120) -> ContactScene:
    """A 0.4 m square cloth (n × n cells, no gravity) held by its two end columns, which rotate about the
    cloth's axis at +72°/s and −72°/s while moving 5 cm/s towards each other (2 s: 288° of twist)."""
    h, size = 0.005, 0.4
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_cloth_grid(
        nx=n, ny=n, size=size, mass=0.1, stiffness=200.0, bend_stiffness=0.2, damping=0.002,
        origin=(-size / 2, -size / 2, 0.0), plane="xy", radius=0.002,
    )  # fmt: skip
    x = b.positions()
    left = np.flatnonzero(np.isclose(x[:, 0], -size / 2))
    right = np.flatnonzero(np.isclose(x[:, 0], size / 2))
    ends = np.concatenate([left, right])
    b.add_kinematic(ends)
    model = b.finalize(device="cpu")
    rest = x[ends]
    sign = np.where(np.arange(len(ends)) < len(left), 1.0, -1.0)

    def drive(t: float) -> np.ndarray:
        a = sign * np.deg2rad(72.0) * t
        c, s = np.cos(a), np.sin(a)
        y, z = rest[:, 1], rest[:, 2]
        return np.stack([rest[:, 0] - sign * SQUEEZE * t, c * y - s * z, s * y + c * z], 1)

    contact = _contact(model, h, 0.2)
    return ContactScene("twist", model, _solver(model, family, contact), 1 / 60, 40, frames, drive)


def _sphere_surface(radius: float, center: tuple[float, float, float], resolution: int):
    """The surface of pliant's tet ball: ([V, 3] vertices [m], int [T, 3] triangles into them)."""
    mesh = pl.geometry.sphere_tets(radius, resolution, center)
    tris = pl.geometry.surface_from_tets(mesh.tets)
    used, inv = np.unique(tris, return_inverse=True)
    return mesh.points[used], inv.reshape(-1, 3)


def sphere(n: int = 16, family: str = "force", frames: int = 90) -> ContactScene:
    """A 0.5 m cloth (n × n cells) dropped from 5 cm above a 0.15 m sphere that spins about the vertical
    at 180°/s; cloth–sphere and cloth–cloth friction μ = 0.4 (the sphere is a kinematic triangle mesh,
    high enough that the draped cloth does not reach the ground)."""
    h, size, r, centre = 0.008, 0.5, 0.15, (0.0, 0.45, 0.0)
    b = pl.ModelBuilder()
    b.add_cloth_grid(
        nx=n, ny=n, size=size, mass=0.1, stiffness=150.0, bend_stiffness=0.5, damping=0.002,
        origin=(-size / 2, centre[1] + r + 0.05, -size / 2), plane="xz", radius=0.004,
    )  # fmt: skip
    pts, tris = _sphere_surface(r, centre, 3)
    first = b.add_particles(pts, 1.0, radius=0.0, name="sphere")
    b.add_triangles(tris + first)
    ids = np.arange(first, first + len(pts))
    b.add_kinematic(ids)
    b.add_ground(0.0, friction=0.4)
    model = b.finalize(device="cpu")
    rel = pts - np.asarray(centre)
    omega = np.pi  # 180°/s [rad/s]

    def drive(t: float) -> np.ndarray:
        c, s = np.cos(omega * t), np.sin(omega * t)
        return np.asarray(centre) + np.stack(
            [c * rel[:, 0] + s * rel[:, 2], rel[:, 1], -s * rel[:, 0] + c * rel[:, 2]], 1
        )

    contact = _contact(model, h, 0.4)
    return ContactScene("sphere", model, _solver(model, family, contact), 1 / 60, 40, frames, drive)


def boxes(cells: int = 3, family: str = "force", frames: int = 90) -> ContactScene:
    """Three soft 0.1 m mass-spring boxes (cells³ cells each), one above the other 1 cm apart, dropped
    into a stack on the ground; their surfaces are the contact triangles."""
    h, size = 0.005, 0.1
    b = pl.ModelBuilder()
    for k in range(3):
        mesh = pl.geometry.box_tets(
            cells,
            cells,
            cells,
            size=(size,) * 3,
            origin=(-size / 2, 0.006 + k * (size + 0.01), -size / 2),
        )
        first = b.add_tet_mesh(
            mesh.points, mesh.tets, density=200.0, stiffness=2000.0, damping=0.2, radius=0.005, name=f"box{k}"
        )
        b.add_triangles(pl.geometry.surface_from_tets(mesh.tets) + first, render=False)
    b.add_ground(0.0, friction=0.5)
    model = b.finalize(device="cpu")
    contact = _contact(model, h, 0.6)
    return ContactScene("boxes", model, _solver(model, family, contact, damping_rate=2.0), 1 / 60, 40, frames)


def ball(n: int = 24, family: str = "force", frames: int = 20) -> ContactScene:
    """A 0.2 m cloth (n × n cells) pinned at its corners, hit square on by a 5 cm ball at 20 m/s; the
    cloth's contact thickness is 0.5 mm. 20 frames of 0.5 ms (the ball travels 20 cm).

    The ball is a kinematic triangle mesh (prescribed motion, as heavy as it must be). A mover is not
    truncated by the bound, so the step is 5 µs: the ball moves 0.1 mm per step, half of what the bound
    lets a cloth vertex a thickness in front of it move (0.4 × 0.5 mm)."""
    h, size = 0.0005, 0.2
    b = pl.ModelBuilder()
    b.add_cloth_grid(
        nx=n, ny=n, size=size, mass=0.02, stiffness=2000.0, damping=0.01,
        origin=(-size / 2, -size / 2, 0.0), plane="xy", pin="corners", radius=0.0005,
    )  # fmt: skip
    pts, tris = _sphere_surface(0.025, (0.0, 0.0, 0.026), 2)
    first = b.add_particles(pts, 1.0, radius=0.0, name="ball")
    b.add_triangles(tris + first)
    b.add_kinematic(np.arange(first, first + len(pts)))
    model = b.finalize(device="cpu")

    def drive(t: float) -> np.ndarray:
        return pts + (0.0, 0.0, -20.0 * t)

    contact = _contact(model, h, 0.2, reach=0.005)
    return ContactScene(
        "ball", model, _solver(model, family, contact, damping_rate=0.0), 5e-4, 100, frames, drive
    )


#: The scenes by name.
SCENES: dict[str, Callable[..., ContactScene]] = {
    "napkin": napkin,
    "twist": twist,
    "sphere": sphere,
    "boxes": boxes,
    "ball": ball,
}
