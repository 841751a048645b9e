"""``pliant info | bench | study | export``."""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from importlib import metadata
from pathlib import Path

from ._common import EXIT_OK, EXIT_USER, CliError


def _version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "not installed"


def cmd_info(args: argparse.Namespace) -> int:
    """Versions, devices and the Warp kernel cache directory; with a scene, its size estimate instead."""
    if getattr(args, "scene", None):
        return _scene_info(args)
    import warp as wp

    import pliant

    from .._warp import init

    init()
    rows = [
        ("pliant", f"{pliant.__version__} ({Path(pliant.__file__).parent})"),
        ("python", f"{platform.python_version()} ({sys.executable})"),
        ("platform", platform.platform()),
        ("warp", wp.config.version),
    ]
    for dist in ("numpy", "scipy", "pydantic", "imageio", "imageio-ffmpeg", "meshio", "trimesh", "tetgen"):
        rows.append((dist, _version(dist)))
    for dist in ("usd-core", "torch"):
        rows.append((f"{dist} (optional)", _version(dist)))
    devices = []
    for d in wp.get_devices():
        name = getattr(d, "name", "")
        devices.append(f"{d.alias} ({name})" if name and name != d.alias else str(d.alias))
    rows.append(("devices", ", ".join(devices)))
    rows.append(("cuda", "available" if wp.is_cuda_available() else "not available (CPU only)"))
    rows.append(("kernel cache", str(wp.config.kernel_cache_dir)))
    width = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"{k:<{width}}  {v}")
    return EXIT_OK


def _scene_info(args: argparse.Namespace) -> int:
    """``pliant info SCENE``: what the scene will allocate, estimated before building, against the memory
    available (the check ``pliant run`` makes; ``--force`` skips it)."""
    from ..scene import available_memory, format_bytes, scene_size
    from ._run import _load

    cfg = _load(args.scene, args.overrides, force=True)
    size = scene_size(cfg)
    have = available_memory()
    kind = "implicit" if size.implicit else "explicit"
    rows = [
        ("scene", f"{cfg.scene.name} ({cfg.source})"),
        ("particles", f"{size.particles}"),
        ("springs", f"{size.springs}"),
        ("tets", f"{size.tets}"),
        ("triangles", f"{size.triangles}"),
        ("counts", "exact (closed forms)" if size.exact else "estimates (TetGen fills, neighbour springs)"),
        ("solver", f"{cfg.solver_kind()} / {cfg.solver.integrator} ({kind}), {cfg.scene.dtype}"),
        ("model memory", f"{format_bytes(size.model_bytes)} (model and simulator states)"),
        ("solver memory", f"{format_bytes(size.solver_bytes)} (Hessian and its sparse LU on the CPU)"),
        ("total", format_bytes(size.total_bytes)),
        ("available", "unknown" if have is None else format_bytes(have)),
    ]
    fits = have is None or size.total_bytes <= have
    rows.append(("fits", "yes" if fits else "no: `pliant run` refuses it without --force"))
    width = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"{k:<{width}}  {v}")
    return EXIT_OK


def cmd_bench(args: argparse.Namespace) -> int:
    """Run benchmarks discovered in ``pliant.bench``; one JSON line each."""
    from .. import bench

    available = bench.discover()
    if args.list:
        for name, fn in sorted(available.items()):
            doc = (fn.__doc__ or "").strip().splitlines()
            print(f"{name}  {doc[0] if doc else ''}".rstrip())
        return EXIT_OK
    names = args.names or sorted(available)
    unknown = [n for n in names if n not in available]
    if unknown:
        raise CliError(
            f"unknown benchmark(s) {', '.join(unknown)}; available: {', '.join(sorted(available))}"
        )
    if not names:
        raise CliError("no benchmarks found in pliant.bench")
    if getattr(args, "graph", False):
        os.environ["PLIANT_BENCH_GRAPH"] = "1"  # read by the rows' timed loop (bench._common.run_timed)
    status = EXIT_OK
    sink = open(args.json, "a", encoding="utf-8") if args.json else None  # noqa: SIM115
    try:
        for name in names:
            try:
                result = bench.run(name, device=args.device, quick=args.quick)
            except Exception as exc:  # one failing benchmark must not hide the others
                print(f"pliant: error: benchmark {name}: {type(exc).__name__}: {exc}", file=sys.stderr)
                status = EXIT_USER
                continue
            line = json.dumps(result, default=str)
            print(line, flush=True)
            if sink is not None:
                sink.write(line + "\n")
                sink.flush()
    finally:
        if sink is not None:
            sink.close()
    return status


def cmd_study(args: argparse.Namespace) -> int:
    """``pliant study integrators``: calls ``pliant.studies.run_integrator_study``."""
    try:
        from ..studies import run_integrator_study
    except ImportError as exc:
        raise CliError(
            f"the integrator study (pliant.studies) is not available in this version ({exc})"
        ) from None
    t0 = time.perf_counter()
    result = run_integrator_study(Path(args.out), args.quick)
    print(f"study done in {time.perf_counter() - t0:.1f} s; outputs in {Path(args.out).resolve()}")
    if isinstance(result, dict):
        for k, v in result.items():
            text = str(v)
            print(f"  {k}: {text if len(text) <= 200 else type(v).__name__ + ' (see the outputs)'}")
    elif isinstance(result, (list, tuple)):
        for v in result:
            print(f"  {v}")
    return EXIT_OK


def cmd_export(args: argparse.Namespace) -> int:
    """``pliant export TRAJ.npz --format ply|obj|usd --out PATH``."""
    from .. import render
    from ..io import OutputPathError, Trajectory, check_file_stem, check_out_dir

    out = Path(args.out)
    try:  # before reading anything: a folder name no file system takes, a file name with a separator
        check_out_dir(out.parent if out.suffix else out)
        if out.suffix:
            check_file_stem(out.name, "--out file name", 255 - 16)
    except OutputPathError as exc:
        raise CliError(str(exc)) from None
    traj = Trajectory.load(args.trajectory)
    suffixes = {".ply": "ply", ".obj": "obj", ".usd": "usd", ".usda": "usd", ".usdc": "usd", ".xdmf": "xdmf"}
    fmt = args.format or suffixes.get(out.suffix.lower())
    if fmt is None:
        raise CliError(f"cannot tell the format from --out {out}; give --format ply, obj, usd, vtu or xdmf")
    if traj.frame_count == 0:
        raise CliError(f"{args.trajectory}: the trajectory has no frames")
    if fmt in ("usd", "vtu", "xdmf"):
        if args.frame is not None:
            raise CliError(f"--frame applies to ply/obj; {fmt.upper()} stores the whole animation")
        if fmt == "usd":
            path = render.export_usd_objects(out, traj)
            prims = len(render.trajectory_objects(traj))
            print(f"wrote {path} ({traj.frame_count} frames, {prims} object prim(s))")
        elif fmt == "xdmf":
            path = render.export_xdmf(out, traj)
            print(f"wrote {path} ({traj.frame_count} steps; frame 0 + displacement per step)")
        else:
            paths = render.export_vtu_series(out, traj)
            print(f"wrote {len(paths)} VTU files and {out / 'frame_series.pvd'} (open the .pvd in ParaView)")
        return EXIT_OK
    from ..render import curve_segments

    # OBJ has polylines (`l`): a rope is written as its links; PLY keeps its vertices only.
    lines = curve_segments(traj) if fmt == "obj" else None
    if args.frame is not None:
        k = args.frame
        if not -traj.frame_count <= k < traj.frame_count:
            raise CliError(f"--frame {k} out of range: the trajectory has {traj.frame_count} frames")
        if lines is not None:
            path = render.export_obj(out, traj.x[k], traj.faces, lines=lines)
        else:
            path = render.export_ply(out, traj.x[k], traj.faces)
        print(f"wrote {path}")
        return EXIT_OK
    if lines is not None:
        paths = render.export_obj_sequence(out, traj.x, traj.faces, lines=lines)
    else:
        paths = render.export_ply_sequence(out, traj.x, traj.faces)
    print(f"wrote {len(paths)} {fmt.upper()} files to {out}/ ({paths[0].name} ... {paths[-1].name})")
    return EXIT_OK
