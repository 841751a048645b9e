"""Export of a whole trajectory, object by object: USD (one prim per object, colliders and the ground as
static prims) and VTU / XDMF time series through meshio (ParaView).

A trajectory saved by ``pliant run`` (or :meth:`Simulator.trajectory`) lists its objects in
``meta["objects"]`` (name, kind, first particle, particle count); faces and tets are global particle
indices. Each object's prim gets its own particles, with indices renumbered from 0; a trajectory without
that list is one object.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from ..io import Trajectory

__all__ = [
    "ObjectPart",
    "curve_segments",
    "trajectory_objects",
    "export_usd_objects",
    "export_vtu_series",
    "export_xdmf",
]


@dataclass
class ObjectPart:
    """One simulated object of a trajectory: particles ``start`` .. ``start + count`` and its topology.

    ``kind`` is what it is exported as: ``"solid"`` (tets), ``"surface"`` (triangles: cloth, shells),
    ``"curve"`` (a rope: its particles in order) or ``"points"``. ``faces`` / ``tets`` are local indices.
    """

    name: str
    kind: str
    start: int
    count: int
    faces: np.ndarray
    tets: np.ndarray
    source_kind: str = ""  # the builder's kind ("cloth", "rope", "soft_box", "points", ...)


def _local(cells: np.ndarray | None, start: int, count: int, width: int) -> np.ndarray:
    if cells is None or not len(cells):
        return np.zeros((0, width), np.int32)
    c = np.asarray(cells, np.int64)
    inside = np.all((c >= start) & (c < start + count), axis=1)
    return (c[inside] - start).astype(np.int32)


def trajectory_objects(traj: Trajectory) -> list[ObjectPart]:
    """The objects of ``traj`` (a :class:`pliant.io.Trajectory`), from ``meta["objects"]`` when present.

    Particles no object claims (added by hand without ``register_object``) become ``particles_<first>``
    parts; a list that does not fit the trajectory (a ``.render.npz`` drawn mesh) is ignored: one object.
    """
    n = traj.x.shape[1]
    objs = [] if traj.meta.get("render_mesh") else list(traj.meta.get("objects") or [])
    spans = sorted((int(o["start"]), int(o["count"]), o) for o in objs)
    if any(s < 0 or c < 0 or s + c > n for s, c, _ in spans) or any(
        a[0] + a[1] > b[0] for a, b in zip(spans, spans[1:], strict=False)
    ):
        spans = []
    listed, at = [], 0
    for s, c, o in spans:
        if s > at:
            listed.append((at, s - at, {"name": f"particles_{at}", "kind": "particles"}))
        listed.append((s, c, o))
        at = s + c
    if at < n:
        listed.append((at, n - at, {"name": "body" if not spans else f"particles_{at}", "kind": "particles"}))
    parts: list[ObjectPart] = []
    for start, count, o in listed:
        if count == 0:
            continue
        faces = _local(traj.faces, start, count, 3)
        tets = _local(traj.tets, start, count, 4)
        if len(tets):
            kind = "solid"
        elif len(faces):
            kind = "surface"
        elif o.get("kind") == "rope" and count >= 2:
            kind = "curve"
        else:
            kind = "points"
        name = str(o.get("name") or f"object{len(parts)}")
        parts.append(ObjectPart(name, kind, start, count, faces, tets, str(o.get("kind", ""))))
    return parts


def _prim_names(parts: list[ObjectPart]) -> list[str]:
    out: list[str] = []
    for p in parts:
        base = re.sub(r"[^A-Za-z0-9_]", "_", p.name) or "object"
        if base[0].isdigit():
            base = "_" + base
        name, k = base, 1
        while name in out or name in ("colliders", "ground"):
            name, k = f"{base}_{k}", k + 1
        out.append(name)
    return out


def _time_codes(traj: Trajectory, fps: float) -> np.ndarray:
    t = np.asarray(traj.t, np.float64)
    return (t - t[0]) * fps


def _extent(xk: np.ndarray, pad: float = 0.0) -> tuple[np.ndarray, np.ndarray] | None:
    ok = np.all(np.isfinite(xk), axis=1)
    if not ok.any():
        return None
    return xk[ok].min(axis=0) - pad, xk[ok].max(axis=0) + pad


def export_usd_objects(
    path: str | os.PathLike,
    traj: Trajectory,
    fps: float | None = None,
    *,
    point_radius: float | None = None,
) -> Path:
    """Writes ``traj`` as an animated USD stage (y-up, metres) with one prim per object under ``/pliant``.

    Solids are ``UsdGeom.TetMesh`` (tets and their surface triangles), cloth and shells ``Mesh``, ropes
    linear ``BasisCurves``, particle objects ``Points``; ``points`` (and ``velocities`` when the trajectory
    recorded them, in m/s) are time-sampled, one time code per frame. Colliders recorded in
    ``meta["colliders"]`` (``pliant run`` stores the drawn ones) become static ``Mesh`` prims under
    ``/pliant/colliders``, and ``meta["ground"]`` (a height [m]) a static ground quad ``/pliant/ground``.
    Needs ``usd-core`` (``pip install "pliant[usd]"``).

    Args:
        path: Output file (``.usd``, ``.usda`` or ``.usdc``).
        traj: A :class:`pliant.io.Trajectory`.
        fps: Time codes per second (default: 1 / ``traj.frame_dt``, else 30).
        point_radius: Radius of ``Points`` particles and half the width of rope curves [m] (default: 1% of
            the motion's extent).

    Returns:
        The output path.
    """
    try:
        from pxr import Gf, Usd, UsdGeom, Vt
    except ImportError as err:
        from .._extras import pip_install

        raise ImportError(
            f"USD export needs the USD Python bindings (usd-core): {pip_install('usd')}"
        ) from err
    xs = np.asarray(traj.x, np.float64)
    if xs.ndim != 3 or xs.shape[2] != 3 or not len(xs):
        raise ValueError(f"the trajectory needs positions [T, N, 3] with T >= 1, got {xs.shape}")
    if fps is None:
        frame_dt = traj.frame_dt
        fps = 1.0 / frame_dt if frame_dt else 30.0
    codes = _time_codes(traj, fps)
    vs = None if traj.v is None else np.asarray(traj.v, np.float64)
    finite = xs[np.all(np.isfinite(xs), axis=2)]
    size = float(np.ptp(finite, axis=0).max()) if len(finite) else 1.0
    r = point_radius if point_radius is not None else 0.01 * max(size, 1e-6)

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
    has_tetmesh = hasattr(UsdGeom, "TetMesh")
    colors = [(0.95, 0.45, 0.15), (0.2, 0.5, 0.9), (0.3, 0.75, 0.35), (0.85, 0.25, 0.5)]

    def vec3i(a: np.ndarray) -> Any:
        return Vt.IntArray.FromNumpy(np.ascontiguousarray(a.ravel(), np.int32))

    parts = trajectory_objects(traj)
    for k, (part, name) in enumerate(zip(parts, _prim_names(parts), strict=True)):
        at = f"/pliant/{name}"
        pad = 0.0
        if part.kind == "solid" and has_tetmesh:
            geom = UsdGeom.TetMesh.Define(stage, at)
            geom.CreateTetVertexIndicesAttr(Vt.Vec4iArray.FromNumpy(np.ascontiguousarray(part.tets)))
            geom.CreateSurfaceFaceVertexIndicesAttr(Vt.Vec3iArray.FromNumpy(np.ascontiguousarray(part.faces)))
        elif part.kind in ("solid", "surface"):  # a solid as the Mesh of its surface on an older usd-core
            geom = UsdGeom.Mesh.Define(stage, at)
            geom.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(part.faces), 3, np.int32)))
            geom.CreateFaceVertexIndicesAttr(vec3i(part.faces))
            geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            geom.CreateDoubleSidedAttr(True)
        elif part.kind == "curve":
            geom = UsdGeom.BasisCurves.Define(stage, at)
            geom.CreateTypeAttr(UsdGeom.Tokens.linear)
            geom.CreateCurveVertexCountsAttr(Vt.IntArray([part.count]))
            geom.CreateWidthsAttr(Vt.FloatArray([2.0 * r]))
            geom.SetWidthsInterpolation(UsdGeom.Tokens.constant)
            pad = r
        else:
            geom = UsdGeom.Points.Define(stage, at)
            geom.CreateWidthsAttr(Vt.FloatArray([2.0 * r]))
            geom.SetWidthsInterpolation(UsdGeom.Tokens.constant)
            pad = r
        geom.GetPrim().SetCustomDataByKey("pliant:kind", part.source_kind)
        geom.CreateDisplayColorAttr(Vt.Vec3fArray([Gf.Vec3f(*colors[k % len(colors)])]))
        points_attr, extent_attr = geom.CreatePointsAttr(), geom.CreateExtentAttr()
        vel_attr = geom.CreateVelocitiesAttr() if vs is not None else None
        sl = slice(part.start, part.start + part.count)
        for f in range(len(xs)):  # per frame, not per element
            code = Usd.TimeCode(float(codes[f]))
            xk = np.ascontiguousarray(xs[f, sl], np.float32)
            points_attr.Set(Vt.Vec3fArray.FromNumpy(xk), code)
            if vel_attr is not None and vs is not None:
                vel_attr.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(vs[f, sl], np.float32)), code)
            box = _extent(xk, pad)
            if box is not None:
                extent_attr.Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, b)) for b in box]), code)

    _add_static_meshes(stage, traj, finite, codes)
    stage.GetRootLayer().Save()
    return path


def collider_points(collider: dict[str, Any], t: npt.ArrayLike) -> np.ndarray:
    """A drawn collider's points [m], [T, V, 3], at times ``t`` [s] (one per frame).

    Args:
        collider: a ``meta["colliders"]`` entry: ``points`` [m], [V, 3], where it was added and, for a moving
            collider, ``centre`` [m] (the point it rotates about, at t = 0), ``velocity`` [m/s] and
            ``angular_velocity`` [rad/s]: the rigid motion ``Colliders.apply`` gives it, c(t) = c + v t and
            R(t) = exp(ω t) about c(t).
        t: the frames' times [s] since it was added.

    Returns:
        The points per frame (the same points every frame for a static collider).
    """
    p = np.asarray(collider["points"], np.float64).reshape(-1, 3)
    ts = np.asarray(t, np.float64).reshape(-1)
    if "velocity" not in collider:
        return np.broadcast_to(p, (len(ts), *p.shape))
    c = np.asarray(collider["centre"], np.float64)
    v = np.asarray(collider["velocity"], np.float64)
    w = np.asarray(collider["angular_velocity"], np.float64)
    rate = float(np.linalg.norm(w))
    k = w / rate if rate > 0 else np.zeros(3)
    d = p - c
    cos, sin = np.cos(rate * ts)[:, None, None], np.sin(rate * ts)[:, None, None]  # Rodrigues, per frame
    turned = d * cos + np.cross(k, d) * sin + np.outer(d @ k, k) * (1.0 - cos)
    return c + ts[:, None, None] * v + turned


def _add_static_meshes(stage: object, traj: Trajectory, finite: np.ndarray, codes: np.ndarray) -> None:
    """Static ``Mesh`` prims on ``stage``: the colliders of ``traj.meta["colliders"]`` under
    ``/pliant/colliders`` and, when ``traj.meta["ground"]`` (a height, m) is set, a ground quad
    ``/pliant/ground`` around the finite positions ``finite`` [M, 3] (m). A moving collider's points are
    time-sampled at the time codes ``codes`` (its pose at each frame: :func:`collider_points`)."""
    from pxr import Gf, Usd, UsdGeom, Vt

    static = [(f"/pliant/colliders/collider{i}", c) for i, c in enumerate(traj.meta.get("colliders") or [])]
    if static:
        UsdGeom.Scope.Define(stage, "/pliant/colliders")
    ground = traj.meta.get("ground")
    if ground is not None and len(finite):
        lo, hi = finite.min(axis=0), finite.max(axis=0)
        c, h = 0.5 * (lo + hi), max(float(np.max(hi - lo)), 1.0)
        quad = [[c[0] - h, ground, c[2] - h], [c[0] + h, ground, c[2] - h], [c[0] + h, ground, c[2] + h]]
        quad.append([c[0] - h, ground, c[2] + h])
        static.append(("/pliant/ground", {"points": quad, "faces": [[0, 2, 1], [0, 3, 2]]}))
    for at, mesh in static:
        pts = np.asarray(mesh["points"], np.float32).reshape(-1, 3)
        tris = np.asarray(mesh["faces"], np.int32).reshape(-1, 3)
        geom = UsdGeom.Mesh.Define(stage, at)
        points_attr = geom.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(pts)))
        if "velocity" in mesh:  # a moving collider: its pose per frame, and its whole sweep's extent
            posed = collider_points(mesh, traj.t).astype(np.float32)
            for f in range(len(codes)):  # per frame, not per point
                code = Usd.TimeCode(float(codes[f]))
                points_attr.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(posed[f])), code)
            pts = posed.reshape(-1, 3)
        geom.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(tris), 3, np.int32)))
        geom.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(tris.ravel(), np.int32)))
        geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        geom.CreateDisplayColorAttr(Vt.Vec3fArray([Gf.Vec3f(0.6, 0.6, 0.6)]))
        box = _extent(pts)
        if box is not None:
            geom.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, b)) for b in box]))


def _cells(traj: Trajectory, lines: bool = True) -> list[tuple[str, np.ndarray]]:
    """meshio cell blocks with global particle indices: tets, triangles of objects without tets, rope
    segments (``lines``; else their particles as vertices), and single vertices of point objects."""
    blocks: dict[str, list[np.ndarray]] = {"tetra": [], "triangle": [], "line": [], "vertex": []}
    for p in trajectory_objects(traj):
        if p.kind == "solid":
            blocks["tetra"].append(p.tets + p.start)
        elif p.kind == "surface":
            blocks["triangle"].append(p.faces + p.start)
        elif p.kind == "curve" and lines:
            i = np.arange(p.start, p.start + p.count - 1)
            blocks["line"].append(np.stack([i, i + 1], axis=1))
        else:
            blocks["vertex"].append(np.arange(p.start, p.start + p.count)[:, None])
    return [(k, np.concatenate(v).astype(np.int64)) for k, v in blocks.items() if v]


def curve_segments(traj: Trajectory) -> np.ndarray:
    """The links of the trajectory's ropes as particle-index pairs [S, 2] (empty without a rope): what an
    OBJ export writes as ``l`` lines so that a rope is a curve, not loose vertices."""
    return dict(_cells(traj)).get("line", np.zeros((0, 2), np.int64))


def export_vtu_series(folder: str | os.PathLike, traj: Trajectory, *, prefix: str = "frame_") -> list[Path]:
    """Writes one VTU per frame (``folder/frame_0000.vtu`` ...) and ``folder/<prefix>series.pvd``, the
    ParaView collection with each frame's time [s]. Point data: ``velocity`` [m/s] when recorded.

    Args:
        folder: Output folder (created if needed).
        traj: A :class:`pliant.io.Trajectory`.
        prefix: File-name prefix.

    Returns:
        The VTU paths in frame order; the ``.pvd`` file is next to them.
    """
    import meshio

    from ._export import _sequence_paths

    xs = np.asarray(traj.x, np.float64)
    paths = _sequence_paths(folder, prefix, len(xs), ".vtu")
    cells = _cells(traj)
    for k, p in enumerate(paths):
        data = {} if traj.v is None else {"velocity": np.asarray(traj.v[k], np.float64)}
        meshio.write(p, meshio.Mesh(xs[k], cells, point_data=data), file_format="vtu")
    rows = "\n".join(
        f'    <DataSet timestep="{float(t):.9g}" file="{p.name}"/>'
        for t, p in zip(traj.t, paths, strict=True)
    )
    pvd = Path(folder) / f"{prefix}series.pvd"
    pvd.write_text(
        '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
        f"{rows}\n  </Collection>\n</VTKFile>\n"
    )
    return paths


def export_xdmf(path: str | os.PathLike, traj: Trajectory) -> Path:
    """Writes an XDMF time series (``path`` and its ``.h5``) through meshio. XDMF series share one
    geometry, so the frame-0 positions are the mesh and each step carries ``displacement`` (x - x0) [m]
    (ParaView: the "Warp By Vector" filter moves the mesh by it) and ``velocity`` [m/s] when recorded.
    Ropes are line cells, or their particles as vertex cells next to other cell types (meshio 5.3 cannot
    write lines in a mixed XDMF topology).

    Args:
        path: Output ``.xdmf`` file.
        traj: A :class:`pliant.io.Trajectory`.

    Returns:
        The output path.
    """
    import meshio

    xs = np.asarray(traj.x, np.float64)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # XML data (no HDF5, so no h5py dependency); fine for the sizes pliant exports.
    with meshio.xdmf.TimeSeriesWriter(str(path), data_format="XML") as w:
        cells = _cells(traj)
        if len(cells) > 1:  # meshio (5.3) cannot write line cells in a mixed XDMF topology
            cells = _cells(traj, lines=False)
        w.write_points_cells(xs[0], cells)
        for k in range(len(xs)):
            data = {"displacement": xs[k] - xs[0]}
            if traj.v is not None:
                data["velocity"] = np.asarray(traj.v[k], np.float64)
            w.write_data(float(traj.t[k]), point_data=data)
    return path
