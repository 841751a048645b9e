"""Cross-engine observations for ``pliant fit``: a cloth, a soft beam and a soft box thrown onto the ground,
simulated by Newton 1.8, written as pliant observation files (NPZ: ``t`` [T], ``points`` [T, K, 3],
``visible`` [T, K]; no ``particle``, so pliant binds each track to the nearest particle at frame 0).

SYNTHETIC DATA from another engine: it stands in for real measurements by giving a genuine model mismatch
(Newton's triangle membrane and Smith 2018 tets against pliant's springs and neo-Hookean tets), not by being
real. Needs Newton in its own venv (see README.md); never imported by pliant or its tests.

    cd benchmarks/peers
    /work/peers-venv/bin/python observe_newton.py cloth --out data/newton_cloth.npz
    /work/peers-venv/bin/python observe_newton.py beam --out data/newton_beam.npz

The pliant scenes that describe the same objects (geometry, masses, pins, nominal materials converted from
Newton's) are ``CLOTH`` and ``BEAM`` in ``benchmarks/fit_cross_engine.py``; the constants below must match.

``--fixture`` writes a test fixture instead (``tests/data/foreign/newton_{cloth,box}``, as
``observe_mujoco.py`` does): tracks with noise and occlusion, the noise-free truth, a JSON sidecar and a
pliant scene whose material is 5x too soft:

    /work/peers-venv/bin/python observe_newton.py cloth --fixture
    /work/peers-venv/bin/python observe_newton.py box --fixture

These give Newton pliant's lumped masses (the cloth) and mesh (the box); ``observe_own.py`` makes
``newton_cloth_own`` and ``newton_box_own`` Newton's own way (``add_cloth_grid``'s even masses,
``add_soft_grid``'s grid and masses, its default ground contact).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
from _foreign import (  # noqa: E402
    FPS,
    THROWN_BOX,
    box_tets,
    cloth_mesh,
    cloth_toml,
    fixture_meta,
    lumped_by_area,
    noisy_tracks,
    scene_toml,
    soft_box_toml,
    write_fixture,
)

FRAMES = 60  # frames after frame 0 (2 s)
GRAVITY = 9.81

# Cloth: a 12 × 12-cell square of 0.6 m in the xz plane at height 1.0, held at its two corners of largest z,
# released flat; 0.1 kg lumped by area as pliant lumps it. Newton membrane: tri_ke (μ·t) = tri_ka (λ·t) =
# 40 N/m, tri_kd = 0.05, dihedral bending edge_ke = 0.002.
CLOTH = dict(
    n=12,
    size=0.6,
    origin=(-0.3, 1.0, -0.3),
    mass=0.1,
    tri_ke=40.0,
    tri_ka=40.0,
    tri_kd=0.05,
    edge_ke=0.002,
    substeps=200,
)
# Beam: 6 × 2 × 2 cells, 0.36 × 0.1 × 0.1 m, centred at (0, 0.6, 0), clamped at its x = −0.18 face,
# released straight under gravity; ρ = 1000 kg/m³, E = 2e5 Pa, ν = 0.3, tet viscosity k_damp = 100 Pa s
# (Newton damps the rate of deformation; pliant's FEM has no such term, only a velocity damping rate).
BEAM = dict(
    cells=(6, 2, 2),
    size=(0.36, 0.1, 0.1),
    centre=(0.0, 0.6, 0.0),
    density=1000.0,
    E=2.0e5,
    nu=0.3,
    k_damp=100.0,
    substeps=100,
)
# Box: the soft cube of observe_mujoco.py (4 × 4 × 4 cells, side 0.2 m, centre (0, 0.45, 0), thrown at
# (1.2, -1, 0) m/s, ρ = 500 kg/m³, E = 4e4 Pa, ν = 0.3) with Smith 2018 tets, a tet viscosity of 20 Pa s and
# Newton's soft (penalty) ground contact: ke = 1e4 N/m, kd = 10 N s/m, friction 0.5, particle radius 5 mm.
BOX = dict(
    **THROWN_BOX,
    E=4.0e4,
    nu=0.3,
    k_damp=20.0,
    contact_ke=1.0e4,
    contact_kd=10.0,
    friction=0.5,
    radius=0.005,
    substeps=100,
)


def _cloth(newton, wp):
    c = CLOTH
    n, h = c["n"], c["size"] / c["n"]
    b = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=(0.0, -GRAVITY, 0.0))
    # Newton's grid lies in its local xy plane; a +90° turn about x maps local y onto world +z.
    b.add_cloth_grid(
        pos=wp.vec3(*c["origin"]),
        rot=wp.quat_from_axis_angle(wp.vec3(1.0, 0.0, 0.0), 0.5 * np.pi),
        vel=wp.vec3(0.0, 0.0, 0.0),
        dim_x=n,
        dim_y=n,
        cell_x=h,
        cell_y=h,
        mass=1.0,
        tri_ke=c["tri_ke"],
        tri_ka=c["tri_ka"],
        tri_kd=c["tri_kd"],
        edge_ke=c["edge_ke"],
        edge_kd=0.0,
        particle_radius=0.005,
    )
    x = np.array(b.particle_q, dtype=np.float64)
    # Masses lumped by area on pliant's triangles (a third of each on its corners), as pliant lumps them;
    # Newton's grid numbers its particles as pliant's (i along x, j along z: j (n + 1) + i).
    pts, tris, _, pin = cloth_mesh(c)
    if np.abs(x - pts).max() > 1e-6:
        raise SystemExit("Newton's cloth particles differ from pliant's grid")
    mass = lumped_by_area(pts, tris, c["mass"])
    mass[pin] = 0.0
    b.particle_mass = [float(v) for v in mass]
    return b, c["substeps"]


def _soft_mesh(newton, wp, c: dict):
    """A builder holding the box of ``c`` (Kuhn tets) with Smith 2018 tets of E, ν; returns it and the
    points."""
    origin = np.asarray(c["centre"]) - 0.5 * np.asarray(c["size"])
    points, tets = box_tets(c["cells"], c["size"], origin)
    E, nu = c["E"], c["nu"]
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    b = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=(0.0, -GRAVITY, 0.0))
    b.add_soft_mesh(
        pos=wp.vec3(0.0, 0.0, 0.0),
        rot=wp.quat_identity(),
        scale=1.0,
        vel=wp.vec3(*c.get("velocity", (0.0, 0.0, 0.0))),
        vertices=[wp.vec3(*p) for p in points],
        indices=tets.ravel().tolist(),
        density=c["density"],
        # SemiImplicit's tets are Smith et al. 2018 eq. 14 on the raw arguments: Smith's §3.4 mapping makes
        # the small-strain E, ν those above (see soft_box_newton.py).
        k_mu=4.0 / 3.0 * mu,
        k_lambda=lam + 5.0 / 6.0 * mu,
        k_damp=c["k_damp"],
        particle_radius=c.get("radius", 0.005),
    )
    return b, points, origin


def _beam(newton, wp):
    c = BEAM
    b, points, origin = _soft_mesh(newton, wp, c)
    mass = np.array(b.particle_mass)
    mass[np.abs(points[:, 0] - origin[0]) < 1e-9] = 0.0  # the clamped face
    b.particle_mass = [float(v) for v in mass]
    return b, c["substeps"]


def _box(newton, wp):
    c = BOX
    b, _, _ = _soft_mesh(newton, wp, c)
    b.add_ground_plane(cfg=newton.ModelBuilder.ShapeConfig(mu=c["friction"]))
    return b, c["substeps"]


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("object", choices=["cloth", "beam", "box"])
    out = ap.add_mutually_exclusive_group(required=True)
    out.add_argument("--out", help="observation NPZ to write (noise-free tracks)")
    out.add_argument("--fixture", action="store_true", help="write tests/data/foreign/newton_OBJECT.*")
    ap.add_argument("--tracks", type=int, default=40, help="tracked particles (a fixed random subset)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    import newton
    import warp as wp

    wp.config.quiet = True
    t0 = time.perf_counter()
    b, substeps = {"cloth": _cloth, "beam": _beam, "box": _box}[args.object](newton, wp)
    model = b.finalize(device="cpu")
    model.particle_grid = None  # no self-contact in these scenes
    solver = newton.solvers.SolverSemiImplicit(model, enable_tri_contact=False)
    contacts, pipeline = None, None
    if args.object == "box":
        model.soft_contact_ke = BOX["contact_ke"]
        model.soft_contact_kd = BOX["contact_kd"]
        model.soft_contact_mu = BOX["friction"]
        pipeline = newton.CollisionPipeline(model)
        contacts = pipeline.contacts()
    s0, s1, control = model.state(), model.state(), model.control()
    dt = 1.0 / FPS / substeps
    xs = [s0.particle_q.numpy().astype(np.float64)]
    for _ in range(FRAMES):
        for _ in range(substeps):
            s0.clear_forces()
            if pipeline is not None:
                pipeline.collide(s0, contacts)
            solver.step(s0, s1, control, contacts, dt)
            s0, s1 = s1, s0
        xs.append(s0.particle_q.numpy().astype(np.float64))
    x = np.stack(xs)
    if not np.all(np.isfinite(x)):
        raise SystemExit(f"{args.object}: Newton's simulation diverged; raise substeps")
    rng = np.random.default_rng(args.seed)
    free = np.flatnonzero(model.particle_inv_mass.numpy() > 0)
    row = {
        "object": args.object,
        "engine": f"newton {newton.__version__} SolverSemiImplicit",
        "particles": model.particle_count,
        "frames": FRAMES + 1,
        "substeps": substeps,
        "drop_m": float(x[0, :, 1].mean() - x[-1, :, 1].mean()),
    }
    t = np.arange(FRAMES + 1) / FPS
    if args.fixture:
        points, visible, pick, gaps = noisy_tracks(x, free, args.tracks, rng)
        meta, scene = _fixture(args, newton, model, substeps, pick, gaps, x)
        name = f"newton_{args.object}"
        written = write_fixture(name, dict(t=t, points=points, visible=visible), meta, truth=x, scene=scene)
        row["files"] = {p.name: p.stat().st_size for p in written}
    else:
        pick = np.sort(rng.choice(free, size=min(args.tracks, free.size), replace=False))
        pts = x[:, pick]
        np.savez_compressed(args.out, t=t, points=pts, visible=np.ones(pts.shape[:2], bool))
        row["out"] = args.out
    row.update(tracks=int(pick.size), wall_s=round(time.perf_counter() - t0, 2))
    print(json.dumps(row), flush=True)
    return row


def _fixture(args, newton, model, substeps, pick, gaps, x) -> tuple[dict, str]:
    """The sidecar and the pliant scene of a fixture."""
    if args.object not in ("cloth", "box"):
        raise SystemExit(f"--fixture: no fixture is defined for {args.object}; use cloth or box")
    free = model.particle_inv_mass.numpy() > 0
    t = np.arange(x.shape[0]) / FPS
    command = f"observe_newton.py {args.object} --fixture --tracks {args.tracks} --seed {args.seed}"
    meta = {
        **fixture_meta(
            f"newton_{args.object}", f"newton {newton.__version__}", t, pick, gaps, args.seed, command
        ),
        "integrator": f"SolverSemiImplicit (explicit), {substeps} substeps per frame, float32",
        "up_axis": "y up in Newton and in the files (pliant's axes): no conversion",
        "free_mass_kg": float(model.particle_mass.numpy()[free].astype(np.float64).sum()),
    }
    head = [
        f"Newton {newton.__version__} {{what}},",
        "described in pliant's terms (SYNTHETIC cross-engine data).",
        "Generated by benchmarks/peers/observe_newton.py --fixture; the sidecar JSON says how.",
        "Axes: y up in both engines (no conversion).",
    ]
    if args.object == "cloth":
        c = CLOTH
        mu, lam = c["tri_ke"], c["tri_ka"]
        Et = 4 * mu * (mu + lam) / (2 * mu + lam)  # plane-stress E·t of Lamé parameters (μt, λt)
        nu = lam / (2 * mu + lam)
        # The scene's numbers, rounded as written there.
        Et_nom, nu_r = round(Et / 5, 2), round(nu, 4)
        meta.update(
            model=f"add_cloth_grid {c['n']} x {c['n']} cells, {c['size']} m square in the xz plane at "
            f"height {c['origin'][1]} m, the two corners of largest z pinned (mass 0), {c['mass']} kg lumped "
            "by area on pliant's triangles, no contacts",
            material_engine={
                "membrane": "triangle FEM (tri_ke = mu t, tri_ka = lambda t)",
                "tri_ke_N_m": mu,
                "tri_ka_N_m": lam,
                "tri_kd": c["tri_kd"],
                "bending": "dihedral, edge_ke",
                "edge_ke": c["edge_ke"],
            },
            material_pliant_converted={"Et": Et, "nu": nu},
            material_pliant_nominal={"Et": Et_nom, "nu": nu_r, "note": "deliberately about 5x too soft"},
        )
        lines = [
            f"Converted: plane-stress Et = 4 mu t (mu t + lambda t) / (2 mu t + lambda t) = {Et:.4g} N/m and",
            f"nu = lambda / (2 mu + lambda) = {nu:.4g} from tri_ke = mu t = {mu:g} N/m and",
            f"tri_ka = lambda t = {lam:g} N/m.",
            f"No pliant equivalent: Newton's membrane damping tri_kd = {c['tri_kd']:g} and dihedral bending",
            f"edge_ke = {c['edge_ke']:g}.",
            f"NOMINAL material below: Et = {Et_nom:g} N/m, deliberately 5x too soft (where a fit starts).",
        ]
        body = cloth_toml(c, Et_nom, nu_r, Et, "mass 0 in Newton")
        what, sub = "cloth (triangle FEM membrane + dihedral bending)", 40
    else:
        c = BOX
        meta.update(
            model=f"add_soft_mesh: pliant's soft_box mesh, {c['cells']} cells x 6 tets (Kuhn split), "
            f"side {c['size'][0]} m, centre {list(c['centre'])} m, initial velocity {list(c['velocity'])} "
            f"m/s, rho {c['density']:g} kg/m3 lumped rho V/4; ground plane at height 0 (Newton soft contact)",
            material_engine={
                "elasticity": "Smith 2018 stable neo-Hookean (eq. 14) with Smith's Lame mapping of E, nu",
                "young_Pa": c["E"],
                "poisson": c["nu"],
                "k_damp_Pa_s": c["k_damp"],
                "soft_contact_ke_N_m": c["contact_ke"],
                "soft_contact_kd": c["contact_kd"],
                "friction": c["friction"],
                "contact_radius_m": c["radius"],
            },
            material_pliant_converted={"E": c["E"], "nu": c["nu"], "ground_friction": c["friction"]},
            material_pliant_nominal={
                "E": c["E"] / 5,
                "nu": c["nu"],
                "ground_friction": c["friction"],
                "note": "deliberately about 5x too soft",
            },
            lowest_vertex_m=float(x[:, :, 1].min()),
            ground_height_m=0.0,
        )
        lines = [
            f"Converted: E = {c['E']:g} Pa, nu = {c['nu']} (small-strain values of Newton's Smith 2018",
            f"tets),ground friction {c['friction']}, particle radius {c['radius']} m.",
            f"No pliant equivalent: Newton's tet viscosity k_damp = {c['k_damp']:g} Pa s and its penalty",
            f"ground (ke = {c['contact_ke']:g} N/m, kd = {c['contact_kd']:g} N s/m).",
            f"NOMINAL material below: E = {c['E'] / 5:g} Pa, deliberately 5x too soft (where a fit starts).",
        ]
        body = soft_box_toml(c, c["E"] / 5, c["E"], c["nu"], None)
        what, sub = "soft box (Smith 2018 tets) thrown onto the ground", 40
    head[0] = head[0].format(what=what)
    scene = scene_toml(head + lines, f"newton_{args.object}", sub, FRAMES, body)
    return meta, scene


if __name__ == "__main__":
    main()
