"""Mesh / point-cloud export: PLY, OBJ sequences and time-sampled USD."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ._camera import as_points
from ._renderer import DEFAULT_COLOR

__all__ = ["export_ply", "export_obj", "export_ply_sequence", "export_obj_sequence", "export_usd"]


def _faces(faces: object | None, n: int) -> np.ndarray | None:
    if faces is None:
        return None
    if hasattr(faces, "numpy") and not isinstance(faces, np.ndarray):
        faces = faces.numpy()
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"faces must be an integer array [F, 3], got {f.dtype} {f.shape}")
    if len(f) and (f.min() < 0 or f.max() >= n):
        raise ValueError("faces index out of range of points")
    return f.astype(np.int32, copy=False)


def _trajectory(x: object) -> np.ndarray:
    if hasattr(x, "numpy") and not isinstance(x, np.ndarray):
        x = x.numpy()
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(f"x must have shape [T, N, 3], got {arr.shape}")
    return arr


def export_ply(
    path: str | os.PathLike, points: object, faces: object | None = None, *, double: bool = False
) -> Path:
    """Writes one frame as a binary little-endian PLY (triangle mesh, or point cloud).

    Args:
        path: Output file.
        points: Vertex positions [N, 3] in metres.
        faces: Triangles [F, 3] (0-based), or None for a point cloud.
        double: Store coordinates as float64 instead of float32.

    Returns:
        The output path.
    """
    pts = as_points(points)
    f = _faces(faces, len(pts))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ptype = "double" if double else "float"
    header = [
        "ply",
        "format binary_little_endian 1.0",
        "comment written by pliant",
        f"element vertex {len(pts)}",
        f"property {ptype} x",
        f"property {ptype} y",
        f"property {ptype} z",
    ]
    if f is not None:
        header += [f"element face {len(f)}", "property list uchar int vertex_indices"]
    header.append("end_header")
    with open(path, "wb") as fh:
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        fh.write(pts.astype("<f8" if double else "<f4").tobytes())
        if f is not None:
            rec = np.empty(len(f), dtype=[("n", "u1"), ("v", "<i4", (3,))])  # packed: 13 bytes
            rec["n"] = 3
            rec["v"] = f
            fh.write(rec.tobytes())
    return path


def export_obj(
    path: str | os.PathLike, points: object, faces: object | None = None, lines: object | None = None
) -> Path:
    """Writes one frame as a Wavefront OBJ (vertices with 9 significant digits, 1-based faces and lines).

    Args:
        path: Output file.
        points: Vertex positions [N, 3] in metres.
        faces: Triangles [F, 3] (0-based), or None for vertices only.
        lines: Line segments [S, 2] (0-based vertex pairs, e.g. a rope's links) written as ``l`` records,
            or None.

    Returns:
        The output path.
    """
    pts = as_points(points)
    f = _faces(faces, len(pts))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # One C-level %-format over the flattened arrays instead of a Python loop per row.
    parts = ["# written by pliant\n", ("v %.9g %.9g %.9g\n" * len(pts)) % tuple(pts.ravel().tolist())]
    if f is not None and len(f):
        parts.append(("f %d %d %d\n" * len(f)) % tuple((f.ravel() + 1).tolist()))
    if lines is not None:
        seg = np.asarray(lines, dtype=np.int64).reshape(-1, 2)
        if len(seg) and (seg.min() < 0 or seg.max() >= len(pts)):
            raise ValueError(f"lines index vertices outside 0..{len(pts) - 1}")
        parts.append(("l %d %d\n" * len(seg)) % tuple((seg.ravel() + 1).tolist()))
    path.write_text("".join(parts))
    return path


def _sequence_paths(folder: str | os.PathLike, prefix: str, n: int, ext: str) -> list[Path]:
    from ..io import check_file_stem

    if prefix:  # the files must land in `folder`: the prefix is part of one file name, never a path
        check_file_stem(prefix, "prefix")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    width = max(4, len(str(n - 1)))
    return [folder / f"{prefix}{k:0{width}d}{ext}" for k in range(n)]


def export_obj_sequence(
    folder: str | os.PathLike,
    x: object,
    faces: object | None = None,
    *,
    prefix: str = "frame_",
    lines: object | None = None,
) -> list[Path]:
    """Writes one OBJ per frame: ``folder/frame_0000.obj``, ``frame_0001.obj``, ...

    Args:
        folder: Output folder (created if needed).
        x: Positions [T, N, 3] in metres.
        faces: Triangles [F, 3] shared by all frames, or None.
        prefix: File-name prefix.
        lines: Line segments [S, 2] shared by all frames (``l`` records), or None.

    Returns:
        The written paths, in frame order.
    """
    xs = _trajectory(x)
    paths = _sequence_paths(folder, prefix, len(xs), ".obj")
    for p, xk in zip(paths, xs, strict=True):
        export_obj(p, xk, faces, lines)
    return paths


def export_ply_sequence(
    folder: str | os.PathLike,
    x: object,
    faces: object | None = None,
    *,
    prefix: str = "frame_",
    double: bool = False,
) -> list[Path]:
    """Writes one binary PLY per frame: ``folder/frame_0000.ply``, ...

    Args:
        folder: Output folder (created if needed).
        x: Positions [T, N, 3] in metres.
        faces: Triangles [F, 3] shared by all frames, or None (point clouds).
        prefix: File-name prefix.
        double: Store coordinates as float64.

    Returns:
        The written paths, in frame order.
    """
    xs = _trajectory(x)
    paths = _sequence_paths(folder, prefix, len(xs), ".ply")
    for p, xk in zip(paths, xs, strict=True):
        export_ply(p, xk, faces, double=double)
    return paths


def export_usd(
    path: str | os.PathLike,
    x: object,
    faces: object | None = None,
    fps: float = 30.0,
    *,
    t: object | None = None,
    point_radius: float | None = None,
    color: tuple[float, float, float] = DEFAULT_COLOR,
) -> Path:
    """Writes an animated USD stage (``.usd``/``.usda``/``.usdc``), y-up, metres, as one prim.

    For a recorded trajectory, :func:`export_usd_objects` writes one prim per object (TetMesh, Mesh,
    BasisCurves, Points), velocities, colliders and the ground; this function exports bare arrays.

    With faces, ``/pliant/mesh`` is a ``UsdGeom.Mesh`` with time-sampled ``points`` and
    ``extent``; without, ``/pliant/points`` is a ``UsdGeom.Points``. Needs ``usd-core``
    (``pip install "pliant[usd]"``), imported only when this function is called.

    Args:
        path: Output file.
        x: Positions [T, N, 3] in metres.
        faces: Triangles [F, 3], or None for particles.
        fps: Time codes per second; frame k is written at time code k (or ``t * fps``).
        t: Optional sample times [T] in seconds (time code = (t - t[0]) * fps).
        point_radius: Particle radius in metres for ``Points`` (default: 1% of the extent).
        color: Display colour (RGB in [0, 1]).

    Returns:
        The output path.
    """
    try:
        from pxr import Gf, Usd, UsdGeom, Vt
    except ImportError as err:
        from .._extras import pip_install

        raise ImportError(
            f"export_usd needs the USD Python bindings (usd-core): {pip_install('usd')}"
        ) from err

    xs = _trajectory(x)
    n_frames, n = xs.shape[:2]
    f = _faces(faces, n)
    if t is None:
        codes = np.arange(n_frames, dtype=np.float64)
    else:
        tt = np.asarray(t, dtype=np.float64).reshape(-1)
        if tt.shape != (n_frames,):
            raise ValueError(f"t must have shape [{n_frames}], got {tt.shape}")
        codes = (tt - tt[0]) * fps
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.exists():
        path.unlink()  # CreateNew refuses to overwrite
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(float(fps))
    stage.SetFramesPerSecond(float(fps))
    stage.SetStartTimeCode(float(codes[0]))
    stage.SetEndTimeCode(float(codes[-1]))
    root = UsdGeom.Xform.Define(stage, "/pliant")
    stage.SetDefaultPrim(root.GetPrim())

    if f is not None:
        geom = UsdGeom.Mesh.Define(stage, "/pliant/mesh")
        geom.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(f), 3, np.int32)))
        geom.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(f.ravel())))
        geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        geom.CreateDoubleSidedAttr(True)
    else:
        geom = UsdGeom.Points.Define(stage, "/pliant/points")
        finite = xs[np.all(np.isfinite(xs), axis=2)]
        extent = float(np.ptp(finite, axis=0).max()) if len(finite) else 1.0
        r = point_radius if point_radius is not None else 0.01 * max(extent, 1e-6)
        geom.CreateWidthsAttr(Vt.FloatArray([2.0 * r]))
        geom.SetWidthsInterpolation(UsdGeom.Tokens.constant)
    geom.CreateDisplayColorAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, color))]))
    points_attr = geom.CreatePointsAttr()
    extent_attr = geom.CreateExtentAttr()
    pad = 0.0 if f is not None else r
    for k in range(n_frames):  # per frame, not per element
        xk = np.ascontiguousarray(xs[k], dtype=np.float32)
        code = Usd.TimeCode(float(codes[k]))
        points_attr.Set(Vt.Vec3fArray.FromNumpy(xk), code)
        ok = np.all(np.isfinite(xk), axis=1)
        if ok.any():
            lo, hi = xk[ok].min(axis=0) - pad, xk[ok].max(axis=0) + pad
            extent_attr.Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]), code)
    stage.GetRootLayer().Save()
    return path
