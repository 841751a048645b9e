"""pliant's soft box drop in Newton's SolverVBD beside pliant's own implicit row, judged by one error.

    PYTHONPATH=. python3 benchmarks/peers/box_vbd.py cuda:0 /tmp/box_vbd.jsonl --n 30
    PYTHONPATH=. /work/peers-venv/bin/python benchmarks/peers/box_vbd.py cpu /tmp/b.jsonl --n 4 --no-pliant

The box is exported from pliant's own model (``pliant.bench._fem.soft_box_model``: the same vertices, tets,
lumped masses, Lamé parameters, particle radius, ground and gravity) and stepped by ``SolverVBD`` at several
substep × iteration settings; with a CUDA device each frame's substeps (collision detection included) are
captured in a CUDA graph once and replayed. Every row carries the centre-of-mass height of every frame and
``trajectory_error``: the largest deviation of that curve over frames 1–24 from pliant's converged float64
reference, relative to the 0.1 m drop (``pliant.bench._box_reference``, the measure of pliant's
``soft_box_drop_*`` rows). pliant's ``soft_box_drop_N_implicit_pcg`` row runs in the same process
(``--no-pliant`` skips it). Each row is printed and appended to OUT as one JSON line.

Material mapping: pliant's stable neo-Hookean ψ = μ/2 (I_C − 3) − μ (J − 1) + (λ + μ)/2 (J − 1)² takes the
Lamé (μ, λ) of E, ν; VBD's kernel takes the same Lamé pair (k_mu = μ, k_lambda = λ) and forms
μ_NH = μ, λ_NH = λ + μ itself (Smith et al. 2018 §3.4), the same energy. No material damping (k_damp = 0).

Contact mapping: pliant's ground is a penalty ½ κ m_i max(0, r_i − y_i)² (κ = 1e6 1/s², r = 5 mm, no
damping) with Coulomb friction 0.5. Newton's particle–shape contact is a penalty ke·(r + margin − d) with one
stiffness for all particles (the mean of the model's ``soft_contact_ke`` and the ground shape's ``ke``; both
are set to the same value), so ke = κ m_face, the mass of a particle inside the bottom face (ρ h³ / 2 for
cells of side h): the bottom face's interior particles get pliant's stiffness, its edge and corner particles
(2×, 4× lighter) a stiffer one. kd = 0 (pliant's penalty is undamped), margin 0, friction 0.5 (VBD's smoothed
Coulomb, ``friction_epsilon`` at its default).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

#: pliant's ground penalty stiffness κ [1/s²] (pliant.energies.GroundPenalty's default, every soft box row).
KAPPA = 1.0e6
FRICTION = 0.5
#: (substeps per frame, VBD iterations per substep). Newton's soft-body examples run 10 × 10. VBD is backward
#: Euler: its error falls about as Δt^0.6 (10³ box, 10 iterations: 20 % at 10 substeps, 8.3 % at 40), and
#: more iterations do not help (4³: 10 × 10 and 10 × 40 are equal). Many substeps meet float32: g Δt² at 160
#: substeps (1e-7 m) is a few ulps of the 0.35 m height, and the 4³ box's free fall gains ~0.8 m/s².
#: In the order run: what --max-s skips first (the iteration variants) says least.
SETTINGS = ((10, 10), (10, 20), (20, 10), (40, 10), (80, 10), (160, 10), (40, 20), (20, 20))
QUICK_SETTINGS = ((10, 10), (20, 10), (40, 10))


def pliant_box(n: int):
    """pliant's n³ box as arrays: positions [m], tets, lumped masses [kg], μ, λ [Pa], radius [m], ground."""
    from pliant.bench._fem import soft_box_model

    m = soft_box_model(n, device="cpu", dtype="float64")
    mu, lam = m.tet_mu.numpy(), m.tet_lam.numpy()
    radius = m.particle_radius.numpy()
    if np.ptp(mu) > 0 or np.ptp(lam) > 0 or np.ptp(radius) > 0:
        raise ValueError("box_vbd expects one material and one particle radius in pliant's box")
    return {
        "q": m.particle_q.numpy().astype(np.float64),
        "tets": m.tet_indices_np.astype(np.int32),
        "mass": m.particle_mass_np.astype(np.float64),
        "mu": float(mu[0]),
        "lam": float(lam[0]),
        "radius": float(radius[0]),
        "ground": float(m.ground.height),
        "gravity": tuple(float(g) for g in m.gravity),
    }


def newton_model(box: dict, n: int, device: str):
    """Newton's model of ``box`` (same mesh, masses from the same ρ, Lamé pair, ground and contact)."""
    import newton
    import warp as wp

    from pliant.bench._fem import DENSITY, SIDE

    ke = KAPPA * DENSITY * (SIDE / n) ** 3 / 2.0  # κ m_face: see the module docstring
    b = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=wp.vec3(*box["gravity"]))
    b.add_soft_mesh(
        pos=wp.vec3(0.0, 0.0, 0.0),
        rot=wp.quat_identity(),
        scale=1.0,
        vel=wp.vec3(0.0, 0.0, 0.0),
        vertices=[wp.vec3(*p) for p in box["q"]],
        indices=box["tets"].ravel().tolist(),
        density=DENSITY,
        k_mu=box["mu"],
        k_lambda=box["lam"],
        k_damp=0.0,
        particle_radius=box["radius"],
        add_surface_mesh_edges=False,  # no bending: the scene has none
    )
    b.add_ground_plane(
        height=box["ground"], cfg=newton.ModelBuilder.ShapeConfig(ke=ke, kd=0.0, mu=FRICTION, margin=0.0)
    )
    b.color()
    model = b.finalize(device=device)
    model.soft_contact_ke, model.soft_contact_kd, model.soft_contact_mu = ke, 0.0, FRICTION
    mass = model.particle_mass.numpy().astype(np.float64)
    mass_err = float(np.max(np.abs(mass - box["mass"])) / box["mass"].max())
    if mass_err > 1e-5:
        raise ValueError(f"Newton's lumped masses differ from pliant's by {mass_err:.2e} (relative)")
    return model, ke, mass_err


def run_vbd(model, box: dict, n: int, device: str, substeps: int, iterations: int, frames: int) -> dict:
    """Drop the box with SolverVBD at ``substeps`` × ``iterations`` per 1/60 s frame; one row."""
    import newton
    import warp as wp

    from pliant.bench._box_reference import motion_fields
    from pliant.bench._fem import FRAME_DT

    cuda = wp.get_device(device).is_cuda
    solver = newton.solvers.SolverVBD(
        model, iterations=iterations, particle_enable_self_contact=False, particle_enable_tile_solve=cuda
    )
    pipeline = newton.CollisionPipeline(model)
    contacts = pipeline.contacts()
    control = model.control()
    dt = FRAME_DT / substeps
    pair = [model.state(), model.state()]

    def frame(s0, s1):
        for _ in range(substeps):
            s0.clear_forces()
            pipeline.collide(s0, contacts)
            solver.step(s0, s1, control, contacts, dt)
            s0, s1 = s1, s0

    t0 = time.perf_counter()
    frame(*pair)  # warm-up: kernel compilation or cache load
    wp.synchronize_device(device)
    graphs, graph_error = None, None
    if cuda:  # one graph per parity of the buffers (an odd substep count swaps them each frame)
        try:
            graphs = []
            for a, b in ((0, 1), (1, 0))[: 1 if substeps % 2 == 0 else 2]:
                with wp.ScopedCapture(device=device) as cap:
                    frame(pair[a], pair[b])
                graphs.append(cap.graph)
        except Exception as e:  # time the launches instead, and say why
            graphs, graph_error = None, repr(e)[:300]
            wp.synchronize_device(device)
    compile_s = time.perf_counter() - t0
    rest = model.state()
    for s in pair:  # back to rest in the captured arrays
        wp.copy(s.particle_q, rest.particle_q)
        wp.copy(s.particle_qd, rest.particle_qd)
    mass = box["mass"]
    com = []
    wp.synchronize_device(device)
    t0 = time.perf_counter()
    for f in range(frames):
        parity = (f * substeps) % 2
        if graphs is not None:
            wp.capture_launch(graphs[parity if substeps % 2 else 0])
        else:
            frame(pair[parity], pair[1 - parity])
        x = pair[(parity + substeps) % 2].particle_q
        # The motion check every frame, as pliant's rows do (a copy of N positions).
        com.append(float(mass @ x.numpy()[:, 1].astype(np.float64) / mass.sum()))
    wp.synchronize_device(device)
    wall = time.perf_counter() - t0
    last = pair[(frames * substeps) % 2]
    x, v = last.particle_q.numpy(), last.particle_qd.numpy()
    steps = frames * substeps
    curve = np.asarray(com)
    return {
        "benchmark": f"newton_vbd_soft_box_drop_{n}_{substeps}x{iterations}",
        "peer": f"newton {newton.__version__} (warp {wp.__version__})",
        "solver": "SolverVBD",
        "device": device,
        "device_name": wp.get_device(device).name,
        "dtype": "float32",
        "cuda_graph": graphs is not None,
        "cuda_graph_error": graph_error,
        "particles": model.particle_count,
        "elements": model.tet_count,
        "frames": frames,
        "substeps": substeps,
        "iterations_per_step": iterations,
        "dt": dt,
        "wall_s": round(wall, 4),
        "compile_s": round(compile_s, 3),
        "time_per_step_s": float(f"{wall / steps:.4g}"),
        "time_per_frame_s": float(f"{wall / frames:.4g}"),
        "ms_per_frame": float(f"{1e3 * wall / frames:.4g}"),
        "ms_per_step": float(f"{1e3 * wall / steps:.4g}"),
        "stable": bool(np.all(np.isfinite(x))),
        "final_max_speed": round(float(np.abs(v).max()), 5) if np.all(np.isfinite(v)) else None,
        "min_frame": int(np.argmin(curve)) + 1 if np.all(np.isfinite(curve)) else None,
        **motion_fields(n, curve),
        "com_curve": [round(c, 6) for c in com],
    }


def pliant_row(
    n: int, device: str, frames: int, substeps: int | None = None, dtype: str | None = None
) -> dict:
    """pliant's ``soft_box_drop_N_implicit_pcg`` row (ImplicitMidpoint at ``_fem.implicit_substeps(n)``,
    float64, Newton-PCG on the device, frames replayed as graphs) for any n, plus ms per frame and per step;
    an ``error`` row if it fails. ``substeps`` and ``dtype`` replace the row's own (then named
    ``..._pcg_<substeps>_<dtype>``)."""
    from pliant.bench import _fem

    name = f"soft_box_drop_{n}_implicit_pcg"
    if substeps is not None or dtype is not None:
        substeps = substeps or _fem.implicit_substeps(n)
        dtype = dtype or _fem.IMPLICIT_DTYPE
        name += f"_{substeps}_{dtype}"
    try:  # the row's own settings (_fem.BENCHMARKS names it for n = 10 and 30 only)
        row = _fem.soft_box_drop(
            n,
            "implicit",
            substeps or _fem.implicit_substeps(n),
            frames,
            device=device,
            dtype=dtype or _fem.IMPLICIT_DTYPE,
            minimizer="pcg",
            integrator="ImplicitMidpoint",
        )
    except Exception as e:
        return {"benchmark": name, "error": repr(e)}
    steps = row["frames"] * row["substeps"]
    row["ms_per_frame"] = float(f"{1e3 * row['wall_s'] / row['frames']:.4g}")
    row["ms_per_step"] = float(f"{1e3 * row['wall_s'] / steps:.4g}")
    return {"benchmark": name, **row}


def summary(n: int, mine: dict, rows: list[dict]) -> dict:
    """pliant's row against VBD's: the fastest VBD setting at pliant's trajectory error or better, else the
    VBD setting of least error (``equal_error`` False), with pliant's speed-up per frame over it."""
    err = mine.get("trajectory_error")
    judged = [r for r in rows if r.get("trajectory_error") is not None]
    if "error" in mine or err is None or not judged:
        return {"benchmark": f"summary_soft_box_drop_{n}", "error": "no pliant row or no judged VBD row"}
    at_err = [r for r in judged if r["trajectory_error"] <= err]
    best = (
        min(at_err, key=lambda r: r["ms_per_frame"])
        if at_err
        else min(judged, key=lambda r: r["trajectory_error"])
    )
    fast = min(judged, key=lambda r: r["ms_per_frame"])
    return {
        "benchmark": f"summary_soft_box_drop_{n}",
        "device": mine["device"],
        "pliant_ms_per_frame": mine["ms_per_frame"],
        "pliant_trajectory_error": err,
        "vbd_setting": f"{best['substeps']}x{best['iterations_per_step']}",
        "vbd_ms_per_frame": best["ms_per_frame"],
        "vbd_trajectory_error": best["trajectory_error"],
        "equal_error": bool(at_err),
        "pliant_speedup": round(best["ms_per_frame"] / mine["ms_per_frame"], 3),
        "vbd_least_error": min(r["trajectory_error"] for r in judged),
        "vbd_fastest_setting": f"{fast['substeps']}x{fast['iterations_per_step']}",
        "vbd_fastest_ms_per_frame": fast["ms_per_frame"],
        "vbd_fastest_trajectory_error": fast["trajectory_error"],
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("device", help="cpu or cuda:0")
    ap.add_argument("out", help="JSON-lines file the rows are appended to")
    ap.add_argument("--n", default="30", help="comma-separated cells per side (references: 4, 10, 20, 30)")
    ap.add_argument("--settings", default=None, help="comma-separated SUBSTEPSxITERATIONS (default: a sweep)")
    ap.add_argument("--frames", type=int, default=24, help="frames of 1/60 s (24: the judged window)")
    ap.add_argument(
        "--max-s",
        type=float,
        default=150.0,
        help="skip VBD settings predicted to end past this script time [s]",
    )
    ap.add_argument("--quick", action="store_true", help="n = 10 and three settings")
    ap.add_argument("--no-pliant", action="store_true", help="skip pliant's own implicit row")
    ap.add_argument("--no-vbd", action="store_true", help="only pliant's row (no Newton needed)")
    ap.add_argument(
        "--pliant-settings",
        default="",
        help="more pliant rows, comma-separated SUBSTEPS:DTYPE (e.g. 5:float32,10:float32)",
    )
    args = ap.parse_args(argv)

    import warp as wp

    wp.config.quiet = True
    sizes = [10] if args.quick else [int(s) for s in args.n.split(",")]
    if args.settings:
        try:
            settings = [tuple(int(v) for v in s.split("x")) for s in args.settings.split(",")]
        except ValueError as e:
            raise SystemExit(
                f"--settings: expected SUBSTEPSxITERATIONS,... (e.g. 10x10,20x10), got {args.settings!r}"
            ) from e
        if any(len(s) != 2 or min(s) < 1 for s in settings):
            raise SystemExit(f"--settings: two positive integers per setting, got {args.settings!r}")
    else:
        settings = list(QUICK_SETTINGS if args.quick else SETTINGS)
    t_all = time.perf_counter()
    with open(args.out, "a") as out:

        def emit(row: dict) -> None:
            line = json.dumps({"t": round(time.perf_counter() - t_all, 1), **row})
            print(line if len(line) < 600 else line[: line.find(', "com_curve"')] + "}", flush=True)
            out.write(line + "\n")
            out.flush()

        for n in sizes:
            mine = None
            if not args.no_pliant:
                mine = pliant_row(n, args.device, args.frames)
                emit(mine)
                for spec in filter(None, args.pliant_settings.split(",")):
                    sub, _, dt = spec.partition(":")
                    emit(pliant_row(n, args.device, args.frames, int(sub), dt or None))
            if args.no_vbd:
                continue
            t = time.perf_counter()
            box = pliant_box(n)
            model, ke, mass_err = newton_model(box, n, args.device)
            emit(
                {
                    "benchmark": f"newton_vbd_soft_box_drop_{n}_model",
                    "k_mu": box["mu"],
                    "k_lambda": box["lam"],
                    "soft_contact_ke": ke,
                    "particle_radius": box["radius"],
                    "colors": len(model.particle_color_groups),
                    "mass_rel_diff": mass_err,
                    "build_s": round(time.perf_counter() - t, 2),
                }
            )
            rows: list[dict] = []
            for substeps, iterations in settings:
                if rows:  # the cost of one iteration pass so far predicts this setting's
                    last = rows[-1]
                    passes = last["frames"] * last["substeps"] * last["iterations_per_step"]
                    need = last["wall_s"] / passes * args.frames * substeps * iterations + last["compile_s"]
                    if time.perf_counter() - t_all + need > args.max_s:
                        emit(
                            {
                                "benchmark": f"newton_vbd_soft_box_drop_{n}_{substeps}x{iterations}",
                                "skipped": f"about {need:.0f} s more would pass --max-s {args.max_s:g}",
                            }
                        )
                        continue
                try:
                    rows.append(run_vbd(model, box, n, args.device, substeps, iterations, args.frames))
                    emit(rows[-1])
                except Exception as e:  # keep the sweep going; the error is a row
                    emit(
                        {
                            "benchmark": f"newton_vbd_soft_box_drop_{n}_{substeps}x{iterations}",
                            "error": repr(e),
                        }
                    )
            if mine is not None:
                emit(summary(n, mine, rows))


if __name__ == "__main__":
    main()
