"""Tests for pliant.geometry: counts, measures, orientation, topology and file I/O."""

from __future__ import annotations

import meshio
import numpy as np
import pytest
import trimesh

from pliant import geometry as geo


def _surface_volume(points: np.ndarray, tris: np.ndarray) -> float:
    """Divergence-theorem volume of a closed, outward-wound triangle surface."""
    a, b, c = points[tris[:, 0]], points[tris[:, 1]], points[tris[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _open_box() -> trimesh.Trimesh:
    """Unit box with its two +z triangles removed."""
    box = trimesh.creation.box()
    keep = box.face_normals[:, 2] < 0.5
    return trimesh.Trimesh(box.vertices, box.faces[keep], process=False)


# ---------------------------------------------------------------- rope / cloth


def test_rope_counts_and_spacing():
    """A rope of n segments has n+1 points, n edges, n-1 bend pairs and equal spacing along its direction."""
    r = geo.rope(10, 2.0, start=(1, 2, 3), direction=(0, 0, 5))
    assert r.points.shape == (11, 3)
    assert r.edges.shape == (10, 2) and r.edges.dtype == np.int32
    assert r.bend_edges.shape == (9, 2)
    np.testing.assert_array_equal(r.bend_edges[:, 1] - r.bend_edges[:, 0], 2)
    seg = np.linalg.norm(np.diff(r.points, axis=0), axis=1)
    np.testing.assert_allclose(seg, 0.2, rtol=1e-12)
    np.testing.assert_allclose(r.points[-1], [1, 2, 5], atol=1e-12)


@pytest.mark.parametrize(("nx", "ny"), [(4, 4), (5, 3)])
def test_cloth_counts(nx, ny):
    """Cloth vertex, triangle, spring and bending-pair counts match the grid formulas."""
    c = geo.cloth_grid(nx, ny)
    assert c.points.shape == ((nx + 1) * (ny + 1), 3)
    assert c.triangles.shape == (2 * nx * ny, 3)
    assert len(c.structural) == nx * (ny + 1) + ny * (nx + 1)
    assert len(c.shear) == 2 * nx * ny
    assert len(c.bend) == (nx - 1) * (ny + 1) + (ny - 1) * (nx + 1)
    # Interior edges = all edges (structural + one diagonal per cell) minus the 2(nx+ny) boundary edges.
    assert len(c.bending_pairs) == (len(c.structural) + nx * ny) - 2 * (nx + ny)
    for arr in (c.triangles, c.structural, c.shear, c.bend, c.bending_pairs):
        assert arr.dtype == np.int32
    springs = c.springs
    assert len(np.unique(np.sort(springs, axis=1), axis=0)) == len(springs)
    # Structural springs are exactly the triangle edges that are not cell diagonals.
    tri_edges = {tuple(e) for e in geo.edges_from_triangles(c.triangles)}
    assert {tuple(e) for e in c.structural} <= tri_edges
    assert len(tri_edges) == len(c.structural) + nx * ny


@pytest.mark.parametrize(("plane", "normal"), [("xz", 1), ("xy", 2), ("yz", 0)])
def test_cloth_area_and_orientation(plane, normal):
    """Triangle areas sum to sx*sy and every normal points along the documented +axis."""
    sx, sy = 1.3, 0.7
    c = geo.cloth_grid(6, 5, size=(sx, sy), origin=(0.1, -0.2, 0.3), plane=plane)
    assert abs(geo.triangle_areas(c.points, c.triangles).sum() - sx * sy) < 1e-12
    n = geo.triangle_normals(c.points, c.triangles)
    np.testing.assert_allclose(n[:, normal], 1.0, atol=1e-12)


def test_cloth_named_corners_xz():
    """For plane 'xz' top means max z and left means min x; pin sets pick those vertices."""
    c = geo.cloth_grid(4, 3, size=(2.0, 1.0), plane="xz")
    p = c.points
    tl, tr = p[c.corner_indices["top-left"]], p[c.corner_indices["top-right"]]
    np.testing.assert_allclose(tl, [0, 0, 1.0])
    np.testing.assert_allclose(tr, [2.0, 0, 1.0])
    top_edge = c.pin_indices("top-edge")
    assert len(top_edge) == 5 and np.all(p[top_edge, 2] == 1.0)
    np.testing.assert_array_equal(
        c.pin_indices("top-corners"), sorted([c.corner_indices[k] for k in ("top-left", "top-right")])
    )
    assert len(c.pin_indices("corners")) == 4
    assert c.pin_indices("top-left").tolist() == [c.corner_indices["top-left"]]
    assert np.all(p[c.pin_indices("left-corners"), 0] == 0.0)
    assert len(c.pin_indices("boundary")) == 2 * (4 + 3)
    with pytest.raises(ValueError, match="top-corners"):
        c.pin_indices("upper-side")


def test_cloth_top_is_max_y_for_xy():
    """For plane 'xy' (a hanging cloth) the top edge is the max-y row."""
    c = geo.cloth_grid(3, 2, size=1.0, origin=(0, 1, 0), plane="xy")
    np.testing.assert_allclose(c.points[c.pin_indices("top-edge"), 1], 2.0)


# ---------------------------------------------------------------- bending pairs / topology


def _check_bending_pairs(tris: np.ndarray, pairs: np.ndarray) -> None:
    tri_sets = [frozenset(t) for t in tris.tolist()]
    lookup: dict[frozenset, list[int]] = {}
    for k, s in enumerate(tri_sets):
        lookup.setdefault(s, []).append(k)
    for e0, e1, o0, o1 in pairs.tolist():
        assert e0 != e1 and o0 not in (e0, e1) and o1 not in (e0, e1) and o0 != o1
        t0, t1 = frozenset((e0, e1, o0)), frozenset((e0, e1, o1))
        assert t0 in lookup and t1 in lookup
        assert len(t0 & t1) == 2  # they share exactly the edge (e0, e1)
        # First triangle traverses e0 -> e1, second e1 -> e0 (consistent winding).
        ta = tris[lookup[t0][0]].tolist()
        tb = tris[lookup[t1][0]].tolist()
        assert ta[(ta.index(e0) + 1) % 3] == e1
        assert tb[(tb.index(e1) + 1) % 3] == e0


def test_bending_pairs_cloth_share_edge():
    """Each cloth bending pair names two triangles sharing exactly (e0, e1), opposite vertices off it."""
    c = geo.cloth_grid(5, 3)
    _check_bending_pairs(c.triangles, c.bending_pairs)


def test_bending_pairs_closed_surface_every_edge():
    """On a closed icosphere every edge yields one bending pair (E = 3F/2)."""
    s = trimesh.creation.icosphere(subdivisions=2)
    pairs = geo.bending_pairs(s.faces)
    assert len(pairs) == 3 * len(s.faces) // 2
    _check_bending_pairs(np.asarray(s.faces), pairs)


def test_bending_pairs_skip_nonmanifold_edges():
    """An edge shared by three triangles produces no bending pair."""
    tris = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    assert geo.bending_pairs(tris).shape == (0, 4)


def test_edges_unique_sorted():
    """edges_from_tets/triangles return unique int32 pairs with i < j (a tet has 6 edges)."""
    e = geo.edges_from_tets([[3, 1, 2, 0]])
    assert e.dtype == np.int32 and e.tolist() == [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]
    b = geo.box_tets(2, 2, 2)
    eb = geo.edges_from_tets(b.tets)
    assert np.all(eb[:, 0] < eb[:, 1]) and len(np.unique(eb, axis=0)) == len(eb)
    # Freudenthal grid edges: 3 axis + 3 face + 1 body diagonal per cell, plus boundary remainders.
    n = 3
    axis = 3 * n * n * (n - 1)
    face = 3 * (n - 1) ** 2 * n
    body = (n - 1) ** 3
    assert len(eb) == axis + face + body
    et = geo.edges_from_triangles([[0, 1, 2], [2, 1, 3]])
    assert et.tolist() == [[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]]


# ---------------------------------------------------------------- tets


def test_box_tets_volumes_positive_and_sum():
    """Box tets are all positive and their volumes sum to sx*sy*sz."""
    sx, sy, sz = 0.3, 1.7, 2.2
    b = geo.box_tets(3, 4, 5, size=(sx, sy, sz), origin=(-1, 0, 2))
    assert b.tets.shape == (6 * 3 * 4 * 5, 4) and b.tets.dtype == np.int32
    v = geo.signed_tet_volumes(b.points, b.tets)
    assert v.min() > 0
    assert abs(v.sum() - sx * sy * sz) < 1e-12
    np.testing.assert_allclose(b.points.min(axis=0), [-1, 0, 2])


def test_box_surface_count_and_outward():
    """Box boundary has 2(2nxny+2nynz+2nxnz) faces, and its divergence volume equals the tet volume."""
    nx, ny, nz = 2, 3, 4
    b = geo.box_tets(nx, ny, nz, size=(1.0, 2.0, 0.5))
    f = b.surface()
    assert len(f) == 2 * (2 * nx * ny + 2 * ny * nz + 2 * nx * nz)
    vol = geo.signed_tet_volumes(b.points, b.tets).sum()
    assert abs(_surface_volume(b.points, f) - vol) < 1e-12
    # A closed surface: every edge is used by exactly two faces, traversed once each way.
    assert len(geo.bending_pairs(f)) == 3 * len(f) // 2
    # Surface vertices are exactly the grid points on the box boundary.
    n_all = (nx + 1) * (ny + 1) * (nz + 1)
    assert len(np.unique(f)) == n_all - (nx - 1) * (ny - 1) * (nz - 1)


def test_box_conforming():
    """Every interior face of the box is shared by exactly two tets (no hanging faces)."""
    b = geo.box_tets(3, 3, 3)
    faces = np.sort(b.tets[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]].reshape(-1, 3), axis=1)
    _, counts = np.unique(faces, axis=0, return_counts=True)
    assert counts.max() == 2
    assert np.sum(counts == 1) == 2 * 3 * (2 * 9)


def test_sphere_tets_volume():
    """Sphere tets are positive and sum to their surface volume (1e-9) and to 4/3 pi r^3 within 3%."""
    r = 0.5
    s = geo.sphere_tets(radius=r, center=(1, 2, 3))
    v = geo.signed_tet_volumes(s.points, s.tets)
    assert v.min() > 0
    f = s.surface()
    pts = s.points - np.array([1, 2, 3])
    surf_vol = _surface_volume(pts, f)
    assert abs(v.sum() - surf_vol) < 1e-9 * surf_vol
    # The polyhedron lies inside the sphere and contains the ball touching its closest face plane,
    # so 4/3 pi d^3 <= V <= 4/3 pi r^3; at resolution 3 this bracket is within 3%.
    n = geo.triangle_normals(pts, f)
    d = np.min(np.einsum("ij,ij->i", n, pts[f[:, 0]]))
    exact = 4.0 / 3.0 * np.pi * r**3
    assert 4.0 / 3.0 * np.pi * d**3 <= v.sum() <= exact
    assert 1 - v.sum() / exact < 0.03


def test_cylinder_tets_volume():
    """Cylinder tets: positive and sum to the inscribed-prism volume (1e-9), within 1% of pi r^2 h."""
    r, h, n = 0.4, 1.5, 32
    c = geo.cylinder_tets(radius=r, height=h, resolution=n)
    v = geo.signed_tet_volumes(c.points, c.tets)
    assert v.min() > 0
    prism = 0.5 * n * np.sin(2 * np.pi / n) * r**2 * h
    assert abs(v.sum() - prism) < 1e-9 * prism
    assert abs(_surface_volume(c.points, c.surface()) - v.sum()) < 1e-9 * prism
    assert abs(v.sum() / (np.pi * r**2 * h) - 1) < 0.01
    np.testing.assert_allclose([c.points[:, 2].min(), c.points[:, 2].max()], [-h / 2, h / 2], atol=1e-12)


def test_tetrahedralize_icosphere_and_max_volume():
    """tetrahedralize(icosphere) gives positive tets summing to the surface volume; max_volume refines."""
    s = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    m = geo.tetrahedralize(s.vertices, s.faces)
    v = geo.signed_tet_volumes(m.points, m.tets)
    assert v.min() > 0
    assert abs(v.sum() - s.volume) < 1e-9 * s.volume
    fine = geo.tetrahedralize(s.vertices, s.faces, max_volume=0.01)
    vf = geo.signed_tet_volumes(fine.points, fine.tets)
    assert len(fine.tets) > 2 * len(m.tets)
    assert vf.max() < 0.02  # TetGen's bound is approximate; factor 2 slack
    assert abs(vf.sum() - s.volume) < 1e-9 * s.volume


def test_tetrahedralize_open_mesh_message():
    """An open box raises ValueError naming the mesh, the word 'watertight', the edge count and a repair."""
    box = _open_box()
    with pytest.raises(ValueError) as err:
        geo.tetrahedralize(box.vertices, box.faces, name="parts/open_box.obj")
    msg = str(err.value)
    assert "parts/open_box.obj" in msg
    assert "watertight" in msg
    assert "4 open boundary edge" in msg
    assert "fill_holes" in msg and "PyMeshFix" in msg


def test_tetrahedralize_unmerged_vertices_hint():
    """A closed surface with duplicated vertices per face is reported with the merge_vertices fix."""
    box = trimesh.creation.box()
    soup_v = box.vertices[box.faces].reshape(-1, 3)
    soup_f = np.arange(len(soup_v)).reshape(-1, 3)
    with pytest.raises(ValueError, match=r"merge_vertices"):
        geo.tetrahedralize(soup_v, soup_f, name="soup")


def test_tetrahedralize_inconsistent_winding():
    """Flipping one face of a closed box is reported as inconsistent winding with fix_winding."""
    box = trimesh.creation.box()
    faces = np.array(box.faces)
    faces[0] = faces[0, ::-1]
    with pytest.raises(ValueError, match=r"(?s)'flipped'.*consistently wound.*fix_winding"):
        geo.tetrahedralize(box.vertices, faces, name="flipped")


def test_tetrahedralize_self_intersection_wrapped(tmp_path, monkeypatch):
    """TetGen's self-intersection failure becomes a ValueError naming the mesh; no debug files are left."""
    monkeypatch.chdir(tmp_path)
    a = trimesh.creation.box()
    b = trimesh.creation.box()
    b.apply_translation([0.5, 0.5, 0.5])
    both = trimesh.util.concatenate([a, b])
    with pytest.raises(ValueError, match=r"(?s)TetGen failed on 'two_boxes'.*self-intersect.*PyMeshFix"):
        geo.tetrahedralize(both.vertices, both.faces, name="two_boxes")
    assert list(tmp_path.iterdir()) == []


def test_orient_tets_flips_negative():
    """orient_tets makes every volume positive without changing magnitudes."""
    b = geo.box_tets(2, 1, 1)
    bad = b.tets.copy()
    bad[::2] = bad[::2][:, [1, 0, 2, 3]]
    v_bad = geo.signed_tet_volumes(b.points, bad)
    assert np.sum(v_bad < 0) == len(bad) // 2
    fixed = geo.orient_tets(b.points, bad)
    v = geo.signed_tet_volumes(b.points, fixed)
    assert v.min() > 0
    np.testing.assert_allclose(v, np.abs(v_bad), rtol=1e-14)
    np.testing.assert_array_equal(np.sort(fixed, axis=1), np.sort(bad, axis=1))


def test_degenerate_detection():
    """Flat triangles/tets and coincident vertices are flagged; well-shaped ones are not, at any scale."""
    scale = 1e-3
    pts = scale * np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [2, 0, 0], [0.5, 0.5, 0]], float)
    tris = np.array([[0, 1, 2], [0, 1, 4], [0, 0, 3], [1, 2, 3]])
    assert geo.degenerate_triangles(pts, tris, eps=1e-6).tolist() == [1, 2]
    tets = np.array([[0, 1, 2, 3], [0, 1, 2, 5], [0, 1, 2, 2]])
    assert geo.degenerate_tets(pts, tets, eps=1e-6).tolist() == [1, 2]
    # Near-flat tet: height 1e-4 relative to unit edges gives ratio ~ 1.7e-5 / 8.
    pts2 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.3, 1e-4]])
    assert geo.degenerate_tets(pts2, [[0, 1, 2, 3]], eps=1e-4).tolist() == [0]
    assert geo.degenerate_tets(pts2, [[0, 1, 2, 3]], eps=1e-6).tolist() == []


def test_triangle_normals_zero_area_is_zero():
    """A zero-area triangle gets a zero normal instead of NaN."""
    pts = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]])
    n = geo.triangle_normals(pts, [[0, 1, 2]])
    assert np.all(n == 0)


# ---------------------------------------------------------------- springs from points


def _lattice(n: int, h: float) -> np.ndarray:
    g = np.arange(n) * h
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)


def test_springs_lattice_six_neighbours():
    """Cubic lattice, radius 1.01h, k=6: interior points get exactly 6 springs; no dups, no self edges."""
    n, h = 5, 0.1
    pts = _lattice(n, h)
    e = geo.springs_from_points(pts, radius=1.01 * h, max_neighbors=6)
    assert e.dtype == np.int32
    assert np.all(e[:, 0] < e[:, 1])
    assert len(np.unique(e, axis=0)) == len(e)
    np.testing.assert_allclose(np.linalg.norm(pts[e[:, 0]] - pts[e[:, 1]], axis=1), h, rtol=1e-12)
    deg = np.bincount(e.ravel(), minlength=len(pts))
    ijk = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3)
    interior = np.all((ijk > 0) & (ijk < n - 1), axis=1)
    assert np.all(deg[interior] == 6)
    assert len(e) == 3 * n * n * (n - 1)


def test_springs_max_neighbors_caps():
    """Each point picks at most k springs (S <= N k); mutual=True caps every degree at k."""
    rng = np.random.default_rng(0)
    pts = rng.random((300, 3))
    k = 3
    e = geo.springs_from_points(pts, radius=0.3, max_neighbors=k)
    assert 0 < len(e) <= len(pts) * k
    em = geo.springs_from_points(pts, radius=0.3, max_neighbors=k, mutual=True)
    assert np.bincount(em.ravel(), minlength=len(pts)).max() <= k
    assert {tuple(x) for x in em} <= {tuple(x) for x in e}
    # Each spring is among the k nearest neighbours of at least one endpoint.
    d = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    knn = np.argsort(d, axis=1)[:, :k]
    for i, j in e.tolist():
        assert j in knn[i] or i in knn[j]
    # Radius is respected.
    assert np.linalg.norm(pts[e[:, 0]] - pts[e[:, 1]], axis=1).max() <= 0.3


def test_springs_skip_coincident_points():
    """Duplicate points are not connected by a zero-length spring."""
    pts = np.array([[0, 0, 0], [0, 0, 0], [1, 0, 0.0]])
    e = geo.springs_from_points(pts, radius=2.0, max_neighbors=5)
    assert e.tolist() == [[0, 2], [1, 2]]


# ---------------------------------------------------------------- load_mesh


@pytest.mark.parametrize("ext", ["obj", "ply", "stl"])
def test_load_mesh_surface_round_trip(tmp_path, ext):
    """OBJ/PLY/STL written by trimesh load back with the same vertex/face counts and geometry."""
    src = trimesh.creation.icosphere(subdivisions=1, radius=0.7)
    path = tmp_path / f"ball.{ext}"
    src.export(path)
    m = geo.load_mesh(path)
    assert isinstance(m, geo.TriMesh)
    assert m.points.shape == src.vertices.shape and m.triangles.shape == src.faces.shape
    assert m.triangles.dtype == np.int32
    if ext == "stl":
        # STL has no shared vertex list; compare welded geometry up to ordering.
        np.testing.assert_allclose(np.sort(m.points, axis=0), np.sort(src.vertices, axis=0), atol=1e-6)
        assert abs(_surface_volume(m.points, m.triangles) - src.volume) < 1e-5
    else:
        np.testing.assert_allclose(m.points, src.vertices, atol=1e-6)
        np.testing.assert_array_equal(m.triangles, src.faces)


@pytest.mark.parametrize("ext", ["msh", "vtk", "vtu"])
def test_load_mesh_tet_round_trip(tmp_path, ext):
    """A tet mesh written by meshio loads back as a TetMesh with equal points and tets."""
    b = geo.box_tets(2, 2, 3, size=(1.0, 0.5, 0.25))
    path = tmp_path / f"box.{ext}"
    kwargs = {"file_format": "gmsh22", "binary": False} if ext == "msh" else {}
    meshio.write_points_cells(path, b.points, [("tetra", b.tets)], **kwargs)
    m = geo.load_mesh(path)
    assert isinstance(m, geo.TetMesh)
    np.testing.assert_allclose(m.points, b.points, atol=1e-12)
    np.testing.assert_array_equal(m.tets, b.tets)


def test_load_mesh_meshio_triangles_and_orientation(tmp_path):
    """A .vtk with only triangles gives a TriMesh; inverted tets in a file are reoriented positive."""
    c = geo.cloth_grid(2, 2)
    path = tmp_path / "cloth.vtk"
    meshio.write_points_cells(path, c.points, [("triangle", c.triangles)])
    m = geo.load_mesh(path)
    assert isinstance(m, geo.TriMesh) and m.triangles.shape == (8, 3)
    b = geo.box_tets(1, 1, 1)
    path2 = tmp_path / "inv.vtu"
    meshio.write_points_cells(path2, b.points, [("tetra", b.tets[:, [1, 0, 2, 3]])])
    t = geo.load_mesh(path2)
    assert geo.signed_tet_volumes(t.points, t.tets).min() > 0


def test_load_mesh_missing_file(tmp_path):
    """A missing file raises FileNotFoundError naming the path."""
    path = tmp_path / "nope.obj"
    with pytest.raises(FileNotFoundError, match=r"nope\.obj.*does not exist"):
        geo.load_mesh(path)


def test_load_mesh_unknown_extension(tmp_path):
    """An unsupported extension names the file and lists the supported ones."""
    path = tmp_path / "thing.fbx"
    path.write_text("x")
    with pytest.raises(ValueError) as err:
        geo.load_mesh(path)
    msg = str(err.value)
    assert "thing.fbx" in msg and "'.fbx'" in msg
    for ext in (".obj", ".ply", ".stl", ".msh", ".vtk", ".vtu"):
        assert ext in msg


def test_load_mesh_nan_coordinates(tmp_path):
    """NaN coordinates are reported with their count and first indices."""
    path = tmp_path / "bad.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nv 0 0 1\nv 0 inf 0\nf 1 2 3\nf 1 2 4\nf 1 3 5\n")
    with pytest.raises(ValueError, match=r"bad\.obj.*2 vertex/vertices with NaN or inf.*\[2, 4\]"):
        geo.load_mesh(path)


def test_load_mesh_empty_and_out_of_range(tmp_path):
    """An empty OBJ and a .vtk tet referencing a missing vertex each get their own message."""
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing\n")
    with pytest.raises(ValueError, match=r"empty\.obj.*no vertices"):
        geo.load_mesh(empty)
    pts = np.eye(4, 3)
    path = tmp_path / "oor.vtk"
    meshio.write_points_cells(path, pts, [("tetra", np.array([[0, 1, 2, 3], [0, 1, 2, 7]]))])
    with pytest.raises(ValueError, match=r"oor\.vtk.*1 tetrahedra reference vertex indices outside \[0, 4\)"):
        geo.load_mesh(path)


def test_geometry_sources_do_not_import_warp():
    """No module in pliant/geometry imports warp (the folder is NumPy-only)."""
    import ast
    from pathlib import Path

    files = sorted(Path(geo.__file__).parent.glob("*.py"))
    assert len(files) >= 2
    for f in files:
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            else:
                continue
            assert not any(n.split(".")[0] == "warp" for n in names), f"{f.name} imports warp"
