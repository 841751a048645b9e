"""Cross-engine fixtures made each engine's own way (issue 38, item 5): ``mujoco_cloth_own``,
``mujoco_cube_own`` (dropped; ``mujoco_cube_own_thrown`` thrown as ``mujoco_cube``), ``newton_cloth_own``
and ``newton_box_own`` in ``tests/data/foreign/``.

The fixtures of ``observe_mujoco.py`` and ``observe_newton.py`` set pliant's lumped masses into the other
engine, which makes them closer to pliant's model than a real capture is. These keep what each engine does
by itself: MuJoCo's flexcomp spreads its ``mass`` evenly over the vertices (the pinned ones' share goes to
the world body), its contacts are soft constraints at the default ``solref`` (0.02 s, 1) and ``solimp``;
Newton's ``add_cloth_grid`` gives every particle the same ``mass``, ``add_soft_grid`` gives every particle
one cell's mass (ρ h³, so the grid weighs (n+1)³/n³ times ρV) and splits each cell into 5 tets, and its
particle–ground contact is its default penalty (``Model.soft_contact_*`` averaged with the ground's
``ShapeConfig``). Only the generators' checks are kept: the start is a free fall (every free vertex
accelerates at g) and the tracks, noise, occlusion and camera conventions are those of the other fixtures.

The pliant scene beside each fixture is what a user would write: the geometry, the total mass or density
given to the engine, pliant's default mass lumping, contact and radius, the engine's documented material
converted, made too soft as a fit's starting point. It is not adapted to the engine's masses or contact.
The sidecar JSON records the engine's mass distribution, contact parameters, version and the truth.

    cd benchmarks/peers
    /work/peers-venv/bin/python observe_own.py mujoco_cloth mujoco_cube mujoco_cube_thrown newton_cloth \
        newton_box

SYNTHETIC DATA; needs the peers' venv (README.md); never imported by pliant or its tests.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
import observe_mujoco as om  # noqa: E402
from _foreign import (  # noqa: E402
    FPS,
    THROWN_BOX,
    box_tets,
    cloth_mesh,
    cloth_toml,
    fixture_meta,
    floats,
    lumped_by_area,
    noisy_tracks,
    scene_toml,
    write_fixture,
)
from _scene import lumped_mass  # noqa: E402

FRAMES = 60  # frames after frame 0 (61 frames, 2 s at 30 fps)
GRAVITY = 9.81
#: The MuJoCo cube: issue 38's (E = 5e4 Pa, its scene starts from 2e4 Pa), dropped from rest with its bottom
#: 0.15 m above the ground (the vertices sink 15 mm: the issue's case) ...
MJ_CUBE = dict(
    **{**THROWN_BOX, "centre": (0.0, 0.25, 0.0), "velocity": (0.0, 0.0, 0.0)},
    young=5.0e4,
    poisson=0.3,
    damping=0.002,
    nominal_factor=2.5,
)
#: ... and thrown as mujoco_cube is (mujoco_cube_own_thrown).
MJ_CUBE_THROWN = {**MJ_CUBE, "centre": THROWN_BOX["centre"], "velocity": THROWN_BOX["velocity"]}
#: The Newton box: newton_box's material (Smith tets, E = 4e4 Pa) on Newton's own grid, masses and default
#: contact; the scene starts 2.5x too soft as the cube's. No tet viscosity (newton_box has 20 Pa s): Newton
#: 1.8's SolverSemiImplicit damps dJ/dt as dJ/dx_i · v_i over three of the four vertices only
#: (kernels_particle.eval_tetrahedra, f_damp), so a rigid translation is damped too and the thrown box is
#: not a free fall (first substep off by 2.6 g); the default ground's kd damps it instead.
NT_BOX = dict(**THROWN_BOX, E=4.0e4, nu=0.3, k_damp=0.0, radius=0.005, substeps=100, nominal_factor=2.5)
CLOTH_NOMINAL_FACTOR = 5.0  # the cloths' scenes start 5x too soft, as mujoco_cloth's and newton_cloth's


def _tracks(name: str, x: np.ndarray, candidates: np.ndarray, args, meta: dict, scene: str) -> dict:
    """Noisy, occluded tracks of ``x`` [T, N, 3] (the other fixtures' noise and occlusion) and the files."""
    rng = np.random.default_rng(args.seed)
    points, visible, pick, gaps = noisy_tracks(x, candidates, args.tracks, rng)
    t = np.arange(x.shape[0]) / FPS
    command = f"observe_own.py {name.replace('_own', '')} --tracks {args.tracks} --seed {args.seed}"
    head = fixture_meta(name, meta.pop("engine"), t, pick, gaps, args.seed, command)
    written = write_fixture(
        name, dict(t=t, points=points, visible=visible), {**head, **meta}, truth=x, scene=scene
    )
    return {
        "fixture": name,
        "files": {p.name: p.stat().st_size for p in written},
        "vertices": int(x.shape[1]),
        "lowest_vertex_m": float(x[..., 1].min()),
    }


def _mass_record(kind: str, mass: np.ndarray, free: np.ndarray, how: str, pliant: np.ndarray) -> dict:
    """The sidecar's ``mass_distribution``: the engine's per-vertex masses [kg] beside pliant's lumping."""
    m = np.asarray(mass, np.float64)
    return {
        "kind": kind,
        "how": how,
        "vertex_mass_kg": [float(v) for v in m],
        "free_mass_kg": float(m[free].sum()),
        "free_mass_spread": float(m[free].max() / m[free].min()),
        "pliant_default_vertex_mass_kg": [float(v) for v in pliant],
        "pliant_default_free_mass_kg": float(pliant[free].sum()),
    }


def _mj_comments(mujoco, what: str, lines: list[str]) -> list[str]:
    return om._comments(mujoco, what, lines)[:2] + [
        "Generated by benchmarks/peers/observe_own.py (the engine's own masses and contact);",
        "the sidecar JSON says how.",
        *om._comments(mujoco, what, lines)[3:],
    ]


# ---------------------------------------------------------------------------------------------- MuJoCo
def _mj_simulate(mujoco, model, data, frames: int) -> np.ndarray:
    """MuJoCo's motion, FRAMES + 1 frames [m] in pliant's axes, each at its frame's time.

    Unlike ``observe_mujoco._simulate``, positions are read after ``mj_forward``: ``mj_step`` computes the
    kinematics (``flexvert_xpos``) before it integrates, so what it leaves are the positions one step
    (1/600 s) earlier: a free fall then drops g t (t - h) / 2 instead of g t (t + h) / 2, and the thrown
    cube lags 2 mm along its throw.
    """
    mujoco.mj_forward(model, data)
    xs = [om._flex_vertices(model, data)]
    for _ in range(frames):
        for _ in range(om.SUBSTEPS):
            mujoco.mj_step(model, data)
        mujoco.mj_forward(model, data)
        xs.append(om._flex_vertices(model, data))
    x = np.stack(xs)
    if not np.all(np.isfinite(x)):
        raise SystemExit("MuJoCo's simulation diverged")
    return x


def mujoco_cloth(args) -> dict:
    """mujoco_cloth's flex cloth with flexcomp's own even vertex masses (no mass is set afterwards)."""
    mujoco = om._mujoco()
    c = om.CLOTH
    pts, tris, uv, pin = cloth_mesh(c)
    model = mujoco.MjModel.from_xml_string(om._cloth_xml(pts, tris, uv, pin))
    data = mujoco.MjData(model)
    # flexcomp's even masses were compiled with mj_setConst, so gravity and inertia agree: a free fall.
    om._check_free_fall(model, data)
    x = _mj_simulate(mujoco, model, data, FRAMES)
    if np.abs(x[0] - pts).max() > 1e-9:
        raise SystemExit("MuJoCo's vertex order differs from the points given")
    free, body = om._free_vertex_bodies(model)
    mass = np.zeros(len(pts))
    mass[free] = model.body_mass[body]
    Et = c["young"] * c["thickness"]
    nominal = Et / CLOTH_NOMINAL_FACTOR
    comments = _mj_comments(
        mujoco,
        "flex cloth (2D, StVK membrane + hinge bending), flexcomp's own even masses",
        [
            f"Converted: Et = E t = {c['young']:g} Pa * {c['thickness']:g} m = {Et:g} N/m,",
            f"nu = {c['poisson']}.",
            f"MuJoCo spreads mass = {c['mass']} kg evenly over the {len(pts)} vertices; pliant lumps it by",
            "area (its default): the scene is not adapted to MuJoCo's masses.",
            f"NOMINAL material below: Et = {nominal:g} N/m, deliberately 5x too soft (where a fit starts).",
        ],
    )
    body_toml = cloth_toml(c, nominal, c["poisson"], Et, "pinned in MuJoCo too").replace(
        "lumped by area in both engines", "pliant lumps by area; MuJoCo: even"
    )
    scene = scene_toml(comments, "mujoco_cloth_own", 40, FRAMES, body_toml)
    meta = {
        "engine": f"mujoco {mujoco.__version__}",
        "made_the_engines_own_way": True,
        "integrator": f"discrete (implicit), {om.SOLVER} solver, timestep 1/{round(FPS * om.SUBSTEPS)} s",
        "up_axis": "files in pliant's axes (y up); MuJoCo ran z up: pliant (x, y, z) = MuJoCo (z, x, y)",
        "model": f"flexcomp type='direct' dim=2, {c['n']} x {c['n']} cells ({len(pts)} vertices), "
        f"{c['size']} m square in the xz plane at height {c['origin'][1]} m, two corners pinned (<pin>), "
        f"flexcomp mass={c['mass']} kg spread evenly (the pinned vertices' share is the world's), "
        "no contacts",
        "mass_distribution": _mass_record(
            "even",
            mass,
            free,
            f"flexcomp mass / vertex count = {c['mass']} / {len(pts)} kg on every vertex",
            lumped_by_area(pts, tris, c["mass"]),
        ),
        "contact": "none (contype 0, conaffinity 0)",
        "free_mass_kg": float(mass[free].sum()),
        "material_engine": {
            "elasticity": "flex 2D, elastic2d='both': StVK membrane (plane stress) + hinge bending",
            "young_Pa": c["young"],
            "poisson": c["poisson"],
            "thickness_m": c["thickness"],
            "rayleigh_damping_s": om.CLOTH_DAMPING,
        },
        "truth_values": {"Et": Et, "nu": c["poisson"], "rayleigh_damping_s": om.CLOTH_DAMPING},
        "material_pliant_converted": {"Et": Et, "nu": c["poisson"]},
        "material_pliant_nominal": {
            "Et": nominal,
            "nu": c["poisson"],
            "factor_too_soft": CLOTH_NOMINAL_FACTOR,
        },
    }
    return _tracks("mujoco_cloth_own", x, np.setdiff1d(np.arange(len(pts)), pin), args, meta, scene)


def _mj_cube_xml(pts: np.ndarray, tets: np.ndarray, mass: float, c: dict) -> str:
    # Nothing of the contact is set: MuJoCo's defaults (solref 0.02 1, solimp 0.9 0.95 0.001 0.5 2,
    # friction 1, condim 3, flex radius 5 mm, pyramidal cone) for the ground geom and the flex alike.
    return f"""
<mujoco model="cube_own">
  {om._option()}
  <worldbody>
    <geom name="ground" type="plane" size="5 5 0.1"/>
    <flexcomp name="cube" type="direct" dim="3" mass="{mass!r}" point="{floats(om.to_mj(pts))}"
              element="{om._ints(tets)}">
      <contact selfcollide="none"/>
      <elasticity young="{c["young"]}" poisson="{c["poisson"]}" damping="{c["damping"]}"/>
    </flexcomp>
  </worldbody>
</mujoco>
"""


def mujoco_cube(args, thrown: bool = False) -> dict:
    """A MuJoCo soft cube dropped (or ``thrown``) onto its ground with MuJoCo's default soft contact and
    even masses: ``mujoco_cube_own`` (``mujoco_cube_own_thrown``)."""
    mujoco = om._mujoco()
    c = MJ_CUBE_THROWN if thrown else MJ_CUBE
    name = "mujoco_cube_own_thrown" if thrown else "mujoco_cube_own"
    how = "thrown" if thrown else "dropped"
    corner = np.asarray(c["centre"]) - 0.5 * np.asarray(c["size"])
    pts, tets = box_tets(c["cells"], c["size"], corner)
    total = c["density"] * float(np.prod(c["size"]))
    model = mujoco.MjModel.from_xml_string(_mj_cube_xml(pts, tets, total, c))
    data = mujoco.MjData(model)
    free, body = om._free_vertex_bodies(model)
    dof = model.jnt_dofadr[model.body_jntadr[body]]
    for a in range(3):  # each vertex body has three slide joints along MuJoCo's x, y, z
        data.qvel[dof + a] = om.to_mj(np.asarray(c["velocity"]))[a]
    om._check_free_fall(model, data)
    x = _mj_simulate(mujoco, model, data, FRAMES)
    if np.abs(x[0] - pts).max() > 1e-9:
        raise SystemExit("MuJoCo's vertex order differs from the points given")
    radius = float(model.flex_radius[0])
    low = float(x[..., 1].min())
    contact = {
        "kind": "MuJoCo soft constraint (flex vertex spheres against the ground plane), all defaults",
        "solref": [float(v) for v in model.flex_solref[0]],
        "solref_ground_geom": [float(v) for v in model.geom_solref[0]],
        "solimp": [float(v) for v in model.flex_solimp[0]],
        "friction": [float(v) for v in model.flex_friction[0]],
        "friction_ground_geom": [float(v) for v in model.geom_friction[0]],
        "condim": int(model.flex_condim[0]),
        "cone": "pyramidal" if model.opt.cone == 0 else "elliptic",
        "flex_radius_m": radius,
        "margin_m": float(model.flex_margin[0]),
        "selfcollide": "none",
        "source": "MuJoCo's defaults: nothing of the contact is set in the MJCF",
    }
    penetration = radius - low  # how far the vertex spheres sank into the ground [m]
    E = c["young"]
    nominal = E / c["nominal_factor"]
    mu = contact["friction"][0]
    comments = _mj_comments(
        mujoco,
        f"flex soft cube (3D, StVK) {how} onto the ground, MuJoCo's own masses and contact",
        [
            f"Converted: E = {E:g} Pa, nu = {c['poisson']}, law stvk (MuJoCo's 3D flex elasticity is StVK);",
            f"ground friction {mu:g} (MuJoCo's default). MuJoCo spreads {total:g} kg evenly over the",
            "vertices and its default soft contact (solref 0.02 s) lets them sink",
            f"{penetration * 1e3:.0f} mm into the ground; pliant's defaults below (mass lumped rho V / 4,",
            "its ground, its radius) are not adapted to either.",
            f"NOMINAL material below: E = {nominal:g} Pa, {c['nominal_factor']:g}x too soft",
            "(where a fit starts).",
        ],
    )
    body_toml = f"""[[objects]]
kind = "soft_box"
model = "fem"
cells = {om_vec(c["cells"])}
size = {om_vec(c["size"])}
origin = {om_vec(c["centre"])}      # centre [m]
density = {c["density"]:g}               # [kg/m³]: the {total:g} kg given to MuJoCo over the box's volume
velocity = {om_vec(c["velocity"])}  # [m/s]

[objects.material]
E = {nominal:g}        # [Pa]; converted: {E:g}
nu = {c["poisson"]}
law = "stvk"

[ground]
height = 0.0
friction = {mu:g}
"""
    scene = scene_toml(comments, name, 40, FRAMES, body_toml)
    mass = np.zeros(len(pts))
    mass[free] = model.body_mass[body]
    meta = {
        "engine": f"mujoco {mujoco.__version__}",
        "made_the_engines_own_way": True,
        "integrator": f"discrete (implicit), {om.SOLVER} solver, timestep 1/{round(FPS * om.SUBSTEPS)} s",
        "up_axis": "files in pliant's axes (y up); MuJoCo ran z up: pliant (x, y, z) = MuJoCo (z, x, y)",
        "model": f"flexcomp type='direct' dim=3: pliant's soft_box mesh, {list(c['cells'])} cells x 6 tets "
        f"(Kuhn split; {len(pts)} vertices, {len(tets)} tets), side {c['size'][0]} m, centre "
        f"{list(c['centre'])} m, initial velocity {list(c['velocity'])} m/s, flexcomp mass={total:g} kg "
        "(rho V) spread evenly; ground plane at height 0 with MuJoCo's default soft contact",
        "mass_distribution": _mass_record(
            "even",
            mass,
            free,
            f"flexcomp mass / vertex count = {total:g} / {len(pts)} kg on every vertex",
            lumped_mass(pts, tets, c["density"]),
        ),
        "contact": contact,
        "free_mass_kg": float(mass[free].sum()),
        "material_engine": {
            "elasticity": "flex 3D StVK",
            "young_Pa": E,
            "poisson": c["poisson"],
            "rayleigh_damping_s": c["damping"],
            "friction": mu,
            "contact_radius_m": radius,
        },
        "truth_values": {
            "E": E,
            "nu": c["poisson"],
            "rayleigh_damping_s": c["damping"],
            "ground_friction": mu,
        },
        "material_pliant_converted": {"E": E, "nu": c["poisson"], "law": "stvk", "ground_friction": mu},
        "material_pliant_nominal": {
            "E": nominal,
            "nu": c["poisson"],
            "law": "stvk",
            "ground_friction": mu,
            "factor_too_soft": c["nominal_factor"],
        },
        "ground_height_m": 0.0,
        "lowest_vertex_m": low,
        "max_penetration_m": penetration,
        "penetration": "contact radius minus the lowest vertex height: how deep the vertex spheres sink",
    }
    return _tracks(name, x, np.arange(len(pts)), args, meta, scene)


def om_vec(v) -> str:
    return "[" + ", ".join(f"{a:g}" for a in v) + "]"


# ---------------------------------------------------------------------------------------------- Newton
def _newton():
    import newton
    import warp as wp

    wp.config.quiet = True
    return newton, wp


def _run_newton(newton, model, substeps: int, contact: bool) -> np.ndarray:
    """Newton's SolverSemiImplicit from the builder's state: positions [FRAMES + 1, N, 3] [m]."""
    model.particle_grid = None  # no self-contact in these scenes
    solver = newton.solvers.SolverSemiImplicit(model, enable_tri_contact=False)
    pipeline = newton.CollisionPipeline(model) if contact else None
    contacts = pipeline.contacts() if contact else None
    s0, s1, control = model.state(), model.state(), model.control()
    dt = 1.0 / FPS / substeps
    xs = [s0.particle_q.numpy().astype(np.float64)]
    v0 = s0.particle_qd.numpy().astype(np.float64)
    for f in range(FRAMES):
        for k in range(substeps):
            s0.clear_forces()
            if pipeline is not None:
                pipeline.collide(s0, contacts)
            solver.step(s0, s1, control, contacts, dt)
            s0, s1 = s1, s0
            if f == 0 and k == 0:
                _check_newton_free_fall(model, v0, s0.particle_qd.numpy().astype(np.float64), dt)
        xs.append(s0.particle_q.numpy().astype(np.float64))
    x = np.stack(xs)
    if not np.all(np.isfinite(x)):
        raise SystemExit("Newton's simulation diverged; raise substeps")
    return x


def _check_newton_free_fall(model, v0: np.ndarray, v1: np.ndarray, dt: float, tol: float = 1e-3) -> None:
    """Stop unless every free particle's velocity changed by g dt (to ``tol`` × g dt) in the first substep
    ``dt`` [s] from the unstrained, contact-free start: masses, gravity and inertia agree."""
    free = model.particle_inv_mass.numpy() > 0
    dv = v1[free] - v0[free]
    want = np.array([0.0, -GRAVITY * dt, 0.0])
    err = float(np.abs(dv - want).max())
    if err > tol * GRAVITY * dt:
        raise SystemExit(f"Newton's start is not a free fall (|dv - g dt| up to {err:.3g} m/s)")


def newton_cloth(args) -> dict:
    """newton_cloth's cloth with add_cloth_grid's own even particle masses (mass per particle)."""
    newton, wp = _newton()
    from observe_newton import CLOTH

    c = CLOTH
    n, h = c["n"], c["size"] / c["n"]
    per = c["mass"] / (n + 1) ** 2
    b = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=(0.0, -GRAVITY, 0.0))
    b.add_cloth_grid(
        pos=wp.vec3(*c["origin"]),
        rot=wp.quat_from_axis_angle(wp.vec3(1.0, 0.0, 0.0), 0.5 * np.pi),
        vel=wp.vec3(0.0, 0.0, 0.0),
        dim_x=n,
        dim_y=n,
        cell_x=h,
        cell_y=h,
        mass=per,  # add_cloth_grid's mass is per particle: Newton's cloth weighs evenly
        tri_ke=c["tri_ke"],
        tri_ka=c["tri_ka"],
        tri_kd=c["tri_kd"],
        edge_ke=c["edge_ke"],
        edge_kd=0.0,
    )
    pts, tris, _, pin = cloth_mesh(c)
    if np.abs(np.array(b.particle_q) - pts).max() > 1e-6:
        raise SystemExit("Newton's cloth particles differ from pliant's grid")
    mass = np.array(b.particle_mass, np.float64)
    mass[pin] = 0.0  # Newton pins a particle by giving it zero mass
    b.particle_mass = [float(v) for v in mass]
    model = b.finalize(device="cpu")
    x = _run_newton(newton, model, c["substeps"], contact=False)
    free = np.flatnonzero(mass > 0)
    mu, lam = c["tri_ke"], c["tri_ka"]
    Et = 4 * mu * (mu + lam) / (2 * mu + lam)
    nu = lam / (2 * mu + lam)
    nominal, nu_r = round(Et / CLOTH_NOMINAL_FACTOR, 2), round(nu, 4)
    comments = [
        f"Newton {newton.__version__} cloth (triangle FEM membrane + dihedral bending), add_cloth_grid's own",
        "even particle masses, described in pliant's terms (SYNTHETIC cross-engine data).",
        "Generated by benchmarks/peers/observe_own.py; the sidecar JSON says how.",
        "Axes: y up in both engines (no conversion).",
        f"Converted: plane-stress Et = {Et:.4g} N/m, nu = {nu:.4g} from tri_ke = mu t = {mu:g} N/m,",
        f"tri_ka = lambda t = {lam:g} N/m. Newton gives each of the {len(pts)} particles {per:.4g} kg;",
        f"pliant lumps the {c['mass']} kg by area (its default): the scene is not adapted to Newton's",
        "masses.",
        f"NOMINAL material below: Et = {nominal:g} N/m, deliberately 5x too soft (where a fit starts).",
    ]
    body_toml = cloth_toml(c, nominal, nu_r, Et, "mass 0 in Newton").replace(
        "lumped by area in both engines", "pliant lumps by area; Newton: even"
    )
    scene = scene_toml(comments, "newton_cloth_own", 40, FRAMES, body_toml)
    meta = {
        "engine": f"newton {newton.__version__}",
        "made_the_engines_own_way": True,
        "integrator": f"SolverSemiImplicit (explicit), {c['substeps']} substeps per frame, float32",
        "up_axis": "y up in Newton and in the files (pliant's axes): no conversion",
        "model": f"add_cloth_grid {n} x {n} cells, {c['size']} m square in the xz plane at height "
        f"{c['origin'][1]} m, mass={per:.6g} kg per particle, the two corners of largest z pinned (mass 0), "
        "no contacts",
        "mass_distribution": _mass_record(
            "even",
            mass,
            free,
            f"add_cloth_grid(mass={per:.6g}) on every particle (total {c['mass']} kg before pinning)",
            lumped_by_area(pts, tris, c["mass"]),
        ),
        "contact": "none",
        "free_mass_kg": float(mass[free].sum()),
        "material_engine": {
            "membrane": "triangle FEM (tri_ke = mu t, tri_ka = lambda t)",
            "tri_ke_N_m": mu,
            "tri_ka_N_m": lam,
            "tri_kd": c["tri_kd"],
            "edge_ke": c["edge_ke"],
        },
        "truth_values": {"Et": Et, "nu": nu, "tri_kd": c["tri_kd"], "edge_ke": c["edge_ke"]},
        "material_pliant_converted": {"Et": Et, "nu": nu},
        "material_pliant_nominal": {"Et": nominal, "nu": nu_r, "factor_too_soft": CLOTH_NOMINAL_FACTOR},
    }
    return _tracks("newton_cloth_own", x, free, args, meta, scene)


def newton_box(args) -> dict:
    """A Newton soft box from add_soft_grid (its 5-tet cells, one cell's mass ρ h³ on every particle)
    thrown onto a default ground plane with Newton's default particle-ground penalty."""
    newton, wp = _newton()
    c = NT_BOX
    n = c["cells"]
    h = [c["size"][d] / n[d] for d in range(3)]
    corner = np.asarray(c["centre"]) - 0.5 * np.asarray(c["size"])
    E, nu = c["E"], c["nu"]
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    b = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=(0.0, -GRAVITY, 0.0))
    b.add_soft_grid(
        pos=wp.vec3(*corner),
        rot=wp.quat_identity(),
        vel=wp.vec3(*c["velocity"]),
        dim_x=n[0],
        dim_y=n[1],
        dim_z=n[2],
        cell_x=h[0],
        cell_y=h[1],
        cell_z=h[2],
        density=c["density"],
        # Smith 2018's §3.4 mapping of the small-strain E, ν (as observe_newton.py's box).
        k_mu=4.0 / 3.0 * mu,
        k_lambda=lam + 5.0 / 6.0 * mu,
        k_damp=c["k_damp"],
        # Newton's default radius (ModelBuilder.default_particle_radius, 0.1 m) is half the box: the box
        # would rest 10 cm above its ground. A Newton user sets it; 5 mm is also pliant's default.
        particle_radius=c["radius"],
    )
    b.add_ground_plane()  # Newton's default ShapeConfig (ke, kd, mu ...)
    pts, tets = box_tets(n, c["size"], corner)
    if np.abs(np.array(b.particle_q) - pts).max() > 1e-6:
        raise SystemExit("Newton's grid particles differ from pliant's box")
    model = b.finalize(device="cpu")
    x = _run_newton(newton, model, c["substeps"], contact=True)
    mass = model.particle_mass.numpy().astype(np.float64)
    free = np.flatnonzero(mass > 0)
    g = 0  # the ground: the builder's only shape
    avg = lambda a, s: 0.5 * (float(a) + float(s))  # noqa: E731  Newton averages particle and shape
    contact = {
        "kind": "Newton SolverSemiImplicit particle-shape penalty (eval_particle_body_contact): "
        "normal ke c + kd min(vn, 0), Coulomb friction min(kf |vt|, mu ke c); all defaults but the radius",
        "model_soft_contact": {
            "ke": float(model.soft_contact_ke),
            "kd": float(model.soft_contact_kd),
            "kf": float(model.soft_contact_kf),
            "mu": float(model.soft_contact_mu),
        },
        "ground_shape": {
            "ke": float(model.shape_material_ke.numpy()[g]),
            "kd": float(model.shape_material_kd.numpy()[g]),
            "kf": float(model.shape_material_kf.numpy()[g]),
            "mu": float(model.shape_material_mu.numpy()[g]),
        },
        "particle_radius_m": c["radius"],
        "source": "Model.soft_contact_* and ModelBuilder.ShapeConfig defaults; Newton averages the two",
    }
    for k in ("ke", "kd", "kf", "mu"):
        contact[f"effective_{k}"] = avg(contact["model_soft_contact"][k], contact["ground_shape"][k])
    low = float(x[..., 1].min())
    penetration = c["radius"] - low
    total = float(mass.sum())
    nominal = E / c["nominal_factor"]
    fr = contact["effective_mu"]
    comments = [
        f"Newton {newton.__version__} soft box (add_soft_grid: Smith 2018 tets, 5 per cell) thrown onto",
        "the ground, Newton's own masses and contact, described in pliant's terms",
        "(SYNTHETIC cross-engine data).",
        "Generated by benchmarks/peers/observe_own.py; the sidecar JSON says how.",
        "Axes: y up in both engines (no conversion).",
        f"Converted: E = {E:g} Pa, nu = {nu} (small-strain values of Newton's Smith 2018 tets); ground",
        f"friction {fr:g} (Newton's default, averaged). Newton gives every particle one cell's mass,",
        f"rho h^3, {total:.4g} kg in all for a {c['density'] * np.prod(c['size']):g} kg box; its default",
        f"penalty ground lets the particles sink {penetration * 1e3:.0f} mm. pliant's defaults below",
        "(rho V / 4, its ground) are not adapted to either.",
        f"NOMINAL material below: E = {nominal:g} Pa, {c['nominal_factor']:g}x too soft",
        "(where a fit starts).",
    ]
    body_toml = f"""[[objects]]
kind = "soft_box"
model = "fem"
cells = {om_vec(n)}
size = {om_vec(c["size"])}
origin = {om_vec(c["centre"])}      # centre [m]
density = {c["density"]:g}               # [kg/m³]: the density given to Newton
velocity = {om_vec(c["velocity"])}  # [m/s]

[objects.material]
E = {nominal:g}        # [Pa]; converted: {E:g}
nu = {nu}

[ground]
height = 0.0
friction = {fr:g}
"""
    scene = scene_toml(comments, "newton_box_own", 40, FRAMES, body_toml)
    meta = {
        "engine": f"newton {newton.__version__}",
        "made_the_engines_own_way": True,
        "integrator": f"SolverSemiImplicit (explicit), {c['substeps']} substeps per frame, float32",
        "up_axis": "y up in Newton and in the files (pliant's axes): no conversion",
        "model": f"add_soft_grid {list(n)} cells x 5 tets (Newton's alternating split; {len(pts)} particles, "
        f"{model.tet_count} tets), side {c['size'][0]} m, centre {list(c['centre'])} m, initial velocity "
        f"{list(c['velocity'])} m/s, density {c['density']:g} kg/m3 given to Newton, which puts rho h^3 on "
        "every particle; default ground plane, Newton's default soft contact",
        "mass_distribution": _mass_record(
            "even",
            mass,
            free,
            f"add_soft_grid: density x cell volume = {mass[0]:.4g} kg on every particle, "
            f"total {total:.4g} kg "
            f"= (n+1)^3 / n^3 = {total / (c['density'] * np.prod(c['size'])):.4g} x rho V",
            lumped_mass(pts, tets, c["density"]),
        ),
        "total_mass_over_rho_V": total / (c["density"] * float(np.prod(c["size"]))),
        "contact": contact,
        "free_mass_kg": float(mass[free].sum()),
        "material_engine": {
            "elasticity": "Smith 2018 stable neo-Hookean (eq. 14) with Smith's Lame mapping of E, nu",
            "young_Pa": E,
            "poisson": nu,
            "k_damp_Pa_s": c["k_damp"],
            "tets_per_cell": 5,
            "friction": fr,
            "contact_radius_m": c["radius"],
        },
        "truth_values": {
            "E": E,
            "nu": nu,
            "k_damp_Pa_s": c["k_damp"],
            "ground_friction": fr,
            # The E that moves pliant's box (ρ V, the scene's density) as Newton's heavier grid moves: under
            # gravity and contact only E / ρ matters.
            "E_at_scene_density_Pa": E / (total / (c["density"] * float(np.prod(c["size"])))),
        },
        "material_pliant_converted": {"E": E, "nu": nu, "ground_friction": fr},
        "material_pliant_nominal": {
            "E": nominal,
            "nu": nu,
            "ground_friction": fr,
            "factor_too_soft": c["nominal_factor"],
        },
        "ground_height_m": 0.0,
        "lowest_vertex_m": low,
        "max_penetration_m": penetration,
        "penetration": "contact radius minus the lowest particle height: how deep the particles sink",
    }
    return _tracks("newton_box_own", x, free, args, meta, scene)


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    make = {
        "mujoco_cloth": mujoco_cloth,
        "mujoco_cube": mujoco_cube,
        "mujoco_cube_thrown": lambda args: mujoco_cube(args, thrown=True),
        "newton_cloth": newton_cloth,
        "newton_box": newton_box,
    }
    ap.add_argument("fixtures", nargs="+", choices=sorted(make))
    ap.add_argument("--tracks", type=int, default=40, help="tracked vertices (a fixed random subset)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    rows = []
    for name in args.fixtures:
        t0 = time.perf_counter()
        row = make[name](args)
        row["wall_s"] = round(time.perf_counter() - t0, 2)
        print(json.dumps(row), flush=True)
        rows.append(row)
    return rows


if __name__ == "__main__":
    main()
