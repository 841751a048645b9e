"""Cross-engine observations for ``pliant fit``: a cloth and a soft beam simulated by Newton 1.8, written as
pliant observation files (NPZ: ``t`` [T], ``points`` [T, K, 3], ``visible`` [T, K]; no ``particle``, so
pliant binds each track to the nearest particle at frame 0).

SYNTHETIC DATA from another engine: it stands in for real measurements by giving a genuine model mismatch
(Newton's triangle membrane and Smith 2018 tets against pliant's springs and neo-Hookean tets), not by being
real. Needs Newton in its own venv (see README.md); never imported by pliant or its tests.

    cd benchmarks/peers
    /work/peers-venv/bin/python observe_newton.py cloth --out data/newton_cloth.npz
    /work/peers-venv/bin/python observe_newton.py beam --out data/newton_beam.npz

The pliant scenes that describe the same objects (geometry, masses, pins, nominal materials converted from
Newton's) are ``CLOTH`` and ``BEAM`` in ``benchmarks/fit_cross_engine.py``; the constants below must match.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

FPS = 30.0
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

_KUHN = np.array([[0, 1, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 1, 7, 5], [0, 2, 7, 3], [0, 4, 7, 6]])


def box_tets(cells, size, origin):
    """pliant.geometry.box_tets without pliant: points [(nx+1)(ny+1)(nz+1), 3], tets [6 nx ny nz, 4]."""
    nx, ny, nz = cells
    axes = [np.linspace(0.0, size[d], cells[d] + 1) for d in range(3)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    points = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1) + np.asarray(origin)
    k, j, i = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    base = (i + (nx + 1) * (j + (ny + 1) * k)).reshape(-1, 1)
    corner = np.array(
        [dx + (nx + 1) * (dy + (ny + 1) * dz) for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)]
    )
    return points, (base + corner[None, :])[:, _KUHN].reshape(-1, 4).astype(np.int32)


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
    # Masses lumped by area (a third of each triangle on its corners), as pliant lumps them.
    tris = np.asarray(b.tri_indices, np.int64).reshape(-1, 3)
    area = 0.5 * np.linalg.norm(
        np.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]]), axis=1
    )
    mass = np.zeros(len(x))
    np.add.at(mass, tris.ravel(), np.repeat(area / 3.0, 3))
    mass *= c["mass"] / mass.sum()
    zmax = x[:, 2].max()
    pinned = (np.abs(x[:, 2] - zmax) < 1e-6) & (np.abs(np.abs(x[:, 0]) - 0.5 * c["size"]) < 1e-6)
    mass[pinned] = 0.0
    b.particle_mass = [float(v) for v in mass]
    return b, c["substeps"]


def _beam(newton, wp):
    c = BEAM
    origin = np.asarray(c["centre"]) - 0.5 * np.asarray(c["size"])
    points, tets = box_tets(c["cells"], c["size"], origin)
    E, nu = c["E"], c["nu"]
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    b = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=(0.0, -GRAVITY, 0.0))
    b.add_soft_mesh(
        pos=wp.vec3(0.0, 0.0, 0.0),
        rot=wp.quat_identity(),
        scale=1.0,
        vel=wp.vec3(0.0, 0.0, 0.0),
        vertices=[wp.vec3(*p) for p in points],
        indices=tets.ravel().tolist(),
        density=c["density"],
        # SemiImplicit's tets are Smith et al. 2018 eq. 14 on the raw arguments: Smith's §3.4 mapping makes
        # the small-strain E, ν those above (see soft_box_newton.py).
        k_mu=4.0 / 3.0 * mu,
        k_lambda=lam + 5.0 / 6.0 * mu,
        k_damp=c["k_damp"],
        particle_radius=0.005,
    )
    mass = np.array(b.particle_mass)
    mass[np.abs(points[:, 0] - origin[0]) < 1e-9] = 0.0  # the clamped face
    b.particle_mass = [float(v) for v in mass]
    return b, c["substeps"]


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("object", choices=["cloth", "beam"])
    ap.add_argument("--out", required=True, help="observation NPZ to write")
    ap.add_argument("--tracks", type=int, default=40, help="tracked particles (a fixed random subset)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    import newton
    import warp as wp

    wp.config.quiet = True
    t0 = time.perf_counter()
    b, substeps = (_cloth if args.object == "cloth" else _beam)(newton, wp)
    model = b.finalize(device="cpu")
    model.particle_grid = None  # no self-contact in these scenes
    solver = newton.solvers.SolverSemiImplicit(model, enable_tri_contact=False)
    s0, s1, control = model.state(), model.state(), model.control()
    dt = 1.0 / FPS / substeps
    xs = [s0.particle_q.numpy().astype(np.float64)]
    for _ in range(FRAMES):
        for _ in range(substeps):
            s0.clear_forces()
            solver.step(s0, s1, control, None, dt)
            s0, s1 = s1, s0
        xs.append(s0.particle_q.numpy().astype(np.float64))
    x = np.stack(xs)
    if not np.all(np.isfinite(x)):
        raise SystemExit(f"{args.object}: Newton's simulation diverged; raise substeps")
    rng = np.random.default_rng(args.seed)
    free = np.flatnonzero(model.particle_inv_mass.numpy() > 0)
    pick = np.sort(rng.choice(free, size=min(args.tracks, free.size), replace=False))
    pts = x[:, pick]
    np.savez_compressed(
        args.out,
        t=np.arange(FRAMES + 1) / FPS,
        points=pts,
        visible=np.ones(pts.shape[:2], bool),
    )
    row = {
        "object": args.object,
        "engine": f"newton {newton.__version__} SolverSemiImplicit",
        "particles": model.particle_count,
        "tracks": int(pick.size),
        "frames": FRAMES + 1,
        "substeps": substeps,
        "drop_m": float(x[0, :, 1].mean() - x[-1, :, 1].mean()),
        "wall_s": round(time.perf_counter() - t0, 2),
        "out": args.out,
    }
    print(json.dumps(row), flush=True)
    return row


if __name__ == "__main__":
    main()
