"""Export object by object (issue 17): USD prim types round trip through pxr, VTU through meshio, OBJ keeps
the trajectory's vertex indices (interior vertices of tet bodies included)."""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl
from pliant.cli import main
from pliant.render import export_usd_objects, export_vtu_series, export_xdmf


def _traj() -> pl.Trajectory:
    """Four objects by hand: a tet body (with an interior vertex), a cloth quad, a rope and points."""
    rng = np.random.default_rng(1)
    tet_pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0.2, 0.2, 0.2]], float)
    n = [5, 4, 3, 2]
    x0 = np.concatenate([tet_pts, rng.random((4, 3)) + 2, rng.random((3, 3)) + 4, rng.random((2, 3)) + 6])
    x = np.stack([x0 + 0.1 * k for k in range(3)])
    v = rng.standard_normal(x.shape)
    tets = np.array([[0, 1, 2, 4], [0, 1, 3, 4], [0, 2, 3, 4], [1, 2, 3, 4]])
    surface = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    faces = np.concatenate([surface, np.array([[5, 6, 7], [5, 7, 8]])])
    starts = np.cumsum([0, *n[:-1]])
    kinds = ["soft_box", "cloth", "rope", "points"]
    objects = [
        {"name": f"o {k}", "kind": kind, "start": int(s), "count": c}
        for k, (kind, s, c) in enumerate(zip(kinds, starts, n))
    ]
    meta = {
        "dt": 0.05,
        "objects": objects,
        "ground": -0.5,
        "colliders": [{"points": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, 2]]}],
    }
    return pl.Trajectory(x=x, t=np.arange(3) * 0.05, v=v, faces=faces, tets=tets, meta=meta)


def test_usd_one_prim_per_object_round_trip(tmp_path):
    pxr = pytest.importorskip("pxr")
    from pxr import Usd, UsdGeom

    traj = _traj()
    path = export_usd_objects(tmp_path / "s.usda", traj)
    stage = Usd.Stage.Open(str(path))
    assert stage.GetTimeCodesPerSecond() == pytest.approx(20.0)
    prims = {p.GetName(): p for p in stage.GetPrimAtPath("/pliant").GetChildren()}
    assert [prims[n].GetTypeName() for n in ("o_0", "o_1", "o_2", "o_3")] == [
        "TetMesh",
        "Mesh",
        "BasisCurves",
        "Points",
    ]
    assert pxr is not None
    for k, o in enumerate(traj.meta["objects"]):
        geom = UsdGeom.PointBased(prims[f"o_{k}"])
        sl = slice(o["start"], o["start"] + o["count"])
        for f in range(3):
            np.testing.assert_allclose(np.array(geom.GetPointsAttr().Get(f)), traj.x[f, sl], rtol=1e-6)
            np.testing.assert_allclose(np.array(geom.GetVelocitiesAttr().Get(f)), traj.v[f, sl], rtol=1e-6)
    tm = UsdGeom.TetMesh(prims["o_0"])
    np.testing.assert_array_equal(np.array(tm.GetTetVertexIndicesAttr().Get()), traj.tets)
    np.testing.assert_array_equal(np.array(tm.GetSurfaceFaceVertexIndicesAttr().Get()), traj.faces[:4])
    cloth = UsdGeom.Mesh(prims["o_1"])
    np.testing.assert_array_equal(
        np.array(cloth.GetFaceVertexIndicesAttr().Get()), traj.faces[4:].ravel() - 5
    )
    assert list(UsdGeom.BasisCurves(prims["o_2"]).GetCurveVertexCountsAttr().Get()) == [3]
    collider = UsdGeom.Mesh(stage.GetPrimAtPath("/pliant/colliders/collider0"))
    assert len(collider.GetPointsAttr().Get()) == 3 and collider.GetPointsAttr().GetNumTimeSamples() == 0
    ground = np.array(UsdGeom.Mesh(stage.GetPrimAtPath("/pliant/ground")).GetPointsAttr().Get())
    np.testing.assert_allclose(ground[:, 1], -0.5)


def test_vtu_series_round_trip_with_meshio(tmp_path):
    import meshio

    traj = _traj()
    paths = export_vtu_series(tmp_path / "vtu", traj)
    assert len(paths) == 3 and (tmp_path / "vtu" / "frame_series.pvd").exists()
    for f, p in enumerate(paths):
        m = meshio.read(p)
        np.testing.assert_allclose(m.points, traj.x[f], rtol=1e-12)
        np.testing.assert_allclose(m.point_data["velocity"], traj.v[f], rtol=1e-12)
        cells = {c.type: c.data for c in m.cells}
        np.testing.assert_array_equal(cells["tetra"], traj.tets)
        np.testing.assert_array_equal(cells["triangle"], traj.faces[4:])
        np.testing.assert_array_equal(cells["line"], [[9, 10], [10, 11]])
        np.testing.assert_array_equal(cells["vertex"].ravel(), [12, 13])
    xd = export_xdmf(tmp_path / "s.xdmf", traj)
    with meshio.xdmf.TimeSeriesReader(str(xd)) as r:
        points, _ = r.read_points_cells()
        np.testing.assert_allclose(points, traj.x[0])
        t, data, _ = r.read_data(2)
        assert t == pytest.approx(0.1)
        np.testing.assert_allclose(points + data["displacement"], traj.x[2], rtol=1e-12)


def test_cli_export_obj_keeps_vertex_indices_and_usd_per_object(tmp_path):
    """A tet body's OBJ has every particle (interior ones too) as vertex k+1, faces as in the trajectory."""
    traj = _traj()
    traj.save(tmp_path / "t.npz")
    assert (
        main(["export", str(tmp_path / "t.npz"), "--out", str(tmp_path / "last.obj"), "--frame", "-1"]) == 0
    )
    lines = (tmp_path / "last.obj").read_text().splitlines()
    v = np.array([[float(a) for a in ln.split()[1:]] for ln in lines if ln.startswith("v ")])
    f = np.array([[int(a) for a in ln.split()[1:]] for ln in lines if ln.startswith("f ")])
    np.testing.assert_allclose(v, traj.x[-1], rtol=1e-8)
    np.testing.assert_array_equal(f - 1, traj.faces)
    pytest.importorskip("pxr")
    assert main(["export", str(tmp_path / "t.npz"), "--out", str(tmp_path / "t.usd")]) == 0
    assert main(["export", str(tmp_path / "t.npz"), "--format", "vtu", "--out", str(tmp_path / "v")]) == 0
    assert len(list((tmp_path / "v").glob("*.vtu"))) == 3


def test_unclaimed_particles_and_render_meshes_are_kept():
    """Particles no object lists become their own part; a list that does not fit is ignored (one body)."""
    from pliant.render import trajectory_objects

    traj = _traj()
    traj.meta["objects"] = traj.meta["objects"][:2]  # the rope and the points are unclaimed
    parts = trajectory_objects(traj)
    assert [(p.name, p.kind, p.start, p.count) for p in parts][2:] == [("particles_9", "points", 9, 5)]
    traj.meta["render_mesh"] = True
    assert [(p.kind, p.start, p.count) for p in trajectory_objects(traj)] == [("solid", 0, 14)]
