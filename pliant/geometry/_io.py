"""Mesh file loading with actionable errors."""

from __future__ import annotations

import contextlib
import io
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._measures import orient_tets
from ._meshes import TetMesh, TriMesh

_TRIMESH_EXTS = (".obj", ".ply", ".stl")
_MESHIO_EXTS = (".msh", ".vtk", ".vtu")
SUPPORTED_EXTENSIONS = _TRIMESH_EXTS + _MESHIO_EXTS


#: Largest vertex coordinate a mesh file may have [file units, metres for pliant]: beyond any object
#: pliant simulates, and where float32 positions are 64 m apart.
MAX_COORDINATE = 1e9


def _check_points(points: NDArray[np.float64], path: Path) -> None:
    if len(points) == 0:
        raise ValueError(f"mesh file '{path}' contains no vertices; is it empty or truncated?")
    bad = np.flatnonzero(~np.all(np.isfinite(points), axis=1))
    if bad.size:
        raise ValueError(
            f"mesh file '{path}' has {bad.size} vertex/vertices with NaN or inf coordinates "
            f"(first indices: {bad[:5].tolist()}); re-export the mesh from its source or "
            "remove those vertices and the faces that use them."
        )
    huge = np.flatnonzero(np.any(np.abs(points) > MAX_COORDINATE, axis=1))
    if huge.size:
        raise ValueError(
            f"mesh file '{path}' has {huge.size} vertex/vertices with coordinates beyond {MAX_COORDINATE:g} "
            f"(first indices: {huge[:5].tolist()}); the file is corrupt or in the wrong units: re-export it "
            "in metres (a scene's `scale` resizes a mesh)"
        )


def _check_cells(cells: NDArray[np.integer], n_points: int, path: Path, kind: str) -> None:
    if len(cells) == 0:
        raise ValueError(
            f"mesh file '{path}' contains no {kind}; supported element types are triangles "
            "(surface) and linear tetrahedra (volume)."
        )
    bad = np.flatnonzero(np.any((cells < 0) | (cells >= n_points), axis=1))
    if bad.size:
        raise ValueError(
            f"mesh file '{path}': {bad.size} {kind} reference vertex indices outside [0, {n_points}) "
            f"(first bad elements: {bad[:5].tolist()}); the file is corrupt or its vertex list is "
            "incomplete, re-export it."
        )


def _compact(points: NDArray[np.float64], cells: NDArray[np.integer]) -> tuple[np.ndarray, np.ndarray]:
    """Drop vertices no element uses (they would become massless free particles)."""
    used, inverse = np.unique(cells, return_inverse=True)
    if len(used) == len(points):
        return points, cells
    return points[used], inverse.reshape(cells.shape)


def _read(path: Path, reader: str, fn: Callable[[], Any]) -> Any:
    """Run a third-party mesh reader so that nothing escapes raw: meshio calls ``sys.exit(1)`` on a file it
    cannot parse (an empty .vtk is enough) and prints to stdout; trimesh raises whatever its parser meets
    (``IndexError``, a missing optional text-encoding module for binary junk, ...). Every failure becomes one
    ``ValueError`` naming the file, the reader's own words, and what to do."""
    out = io.StringIO()
    try:
        # The readers' own RuntimeWarnings on junk (overflowing casts) are noise: the checks that follow
        # (finite, in-range, sizes) decide.
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with np.errstate(all="ignore"):
                return fn()
    except (SystemExit, Exception) as exc:
        said = " ".join(out.getvalue().split())
        if isinstance(exc, SystemExit) or not str(exc):
            why = said or type(exc).__name__
        elif isinstance(exc, (ImportError, UnicodeDecodeError)):
            # Binary junk in a text format: trimesh then looks for an encoding detector it may not have.
            why = "the file is not valid text for this format (binary or corrupt data)"
        else:
            why = f"{type(exc).__name__}: {exc}"
        raise ValueError(
            f"could not read mesh file '{path}' with {reader} ({why[:300]}); the file is empty, truncated or "
            f"not a {path.suffix.lower()} mesh: re-export it, or convert it with `meshio convert`"
        ) from None


def _load_trimesh(path: Path) -> TriMesh:
    import trimesh

    # process=False: keep the file's vertex order and keep NaNs for our own check
    # (processing would silently drop them).
    def read() -> tuple[np.ndarray, np.ndarray]:
        mesh = trimesh.load(str(path), force="mesh", process=False)
        points = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
        faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64).reshape(-1, 3)
        return points, faces

    points, faces = _read(path, "trimesh", read)
    _check_points(points, path)
    _check_cells(faces, len(points), path, "triangles")
    if path.suffix.lower() == ".stl":
        # STL stores each triangle's corners separately; weld them so the surface is connected.
        def weld() -> tuple[np.ndarray, np.ndarray]:
            mesh = trimesh.Trimesh(points, faces, process=False)
            mesh.merge_vertices()
            return np.asarray(mesh.vertices), np.asarray(mesh.faces)

        points, faces = _read(path, "trimesh", weld)
    points, faces = _compact(points, faces)
    return TriMesh(points=np.ascontiguousarray(points, np.float64), triangles=faces.astype(np.int32))


def _load_meshio(path: Path) -> TriMesh | TetMesh:
    import meshio

    def read() -> tuple[np.ndarray, dict[str, list[np.ndarray]]]:
        m = meshio.read(str(path))
        points = np.asarray(m.points, dtype=np.float64)
        if points.ndim == 2 and points.shape[1] == 2:  # 2-D gmsh meshes: embed in z = 0
            points = np.hstack([points, np.zeros((len(points), 1))])
        points = points.reshape(-1, 3)
        blocks: dict[str, list[np.ndarray]] = {c.type: [] for c in m.cells}
        for c in m.cells:
            data = np.asarray(c.data)
            if c.type in ("tetra", "triangle"):
                data = data.astype(np.int64).reshape(-1, 4 if c.type == "tetra" else 3)
            blocks[c.type].append(data)
        return points, blocks

    points, blocks = _read(path, "meshio", read)
    _check_points(points, path)

    if "tetra" in blocks:
        tets = np.concatenate(blocks["tetra"]).astype(np.int64)
        _check_cells(tets, len(points), path, "tetrahedra")
        points, tets = _compact(points, tets)
        return TetMesh(points=np.ascontiguousarray(points), tets=orient_tets(points, tets))
    if "triangle" in blocks:
        tris = np.concatenate(blocks["triangle"]).astype(np.int64)
        _check_cells(tris, len(points), path, "triangles")
        points, tris = _compact(points, tris)
        return TriMesh(points=np.ascontiguousarray(points), triangles=tris.astype(np.int32))
    found = ", ".join(sorted(blocks)) or "none"
    raise ValueError(
        f"mesh file '{path}' contains no triangles or linear tetrahedra (cell types found: {found}); "
        "re-export with first-order 'triangle' or 'tetra' elements (e.g. gmsh -order 1)."
    )


def load_mesh(path: str | Path) -> TriMesh | TetMesh:
    """Load a triangle or tetrahedral mesh from disk.

    OBJ, PLY and STL are read with trimesh into a :class:`TriMesh` (STL vertices are
    welded, since the format repeats them per triangle). MSH, VTK and VTU are read
    with meshio: a :class:`TetMesh` if the file has ``tetra`` cells (reoriented to
    positive volume), else a :class:`TriMesh` from its ``triangle`` cells. Vertices
    used by no returned element are dropped and indices remapped.

    Args:
        path: File path.

    Returns:
        :class:`TriMesh` or :class:`TetMesh` with float64 points (file units) and
        int32 indices.

    Raises:
        FileNotFoundError: No such file.
        ValueError: Unsupported extension, unreadable or empty file, NaN/inf
            coordinates, or element indices out of range; the message names the file.
    """
    p = Path(path)
    if not p.is_file():
        where = "is a directory, not a file" if p.is_dir() else "does not exist"
        raise FileNotFoundError(f"mesh file '{p}' {where} (resolved to '{p.resolve()}'); check the path.")
    ext = p.suffix.lower()
    if ext in _TRIMESH_EXTS or ext in _MESHIO_EXTS:
        try:
            return _load_trimesh(p) if ext in _TRIMESH_EXTS else _load_meshio(p)
        except ValueError as exc:
            if str(p) in str(exc):
                raise
            # The mesh classes' own checks (degenerate elements, ...): say which file.
            raise ValueError(f"mesh file '{p}': {exc}") from None
    raise ValueError(
        f"cannot load '{p}': unsupported extension {ext or '(none)'!r}; supported: "
        f"{', '.join(SUPPORTED_EXTENSIONS)}. Convert other formats with `meshio convert` "
        "or trimesh."
    )
