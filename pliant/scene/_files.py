"""Reading the files a scene refers to (meshes, ``.npy`` point sets) without trusting them: every problem
becomes a ``SceneError`` naming the scene file and the field, and sizes are checked before allocating."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ._errors import scene_error

if TYPE_CHECKING:
    from ..geometry import TetMesh, TriMesh
    from ._schema import SceneConfig

#: Default particle budget of one scene (``PLIANT_MAX_PARTICLES`` overrides it): about 1 GB of model and
#: solver arrays in float64, well above every built-in scene (the largest has ~17k particles).
DEFAULT_MAX_PARTICLES = 2_000_000


def max_particles() -> int:
    """The particle budget: ``PLIANT_MAX_PARTICLES`` (a positive integer) or :data:`DEFAULT_MAX_PARTICLES`."""
    raw = os.environ.get("PLIANT_MAX_PARTICLES", "")
    try:
        n = int(raw) if raw.strip() else DEFAULT_MAX_PARTICLES
    except ValueError:
        n = DEFAULT_MAX_PARTICLES
    return n if n > 0 else DEFAULT_MAX_PARTICLES


def budget_message(n: float, what: str) -> str:
    """The message for a scene whose ``what`` would create ``n`` particles, above the budget."""
    return (
        f"{what} would create about {n:.3g} particles, above the budget of {max_particles()} "
        "(PLIANT_MAX_PARTICLES); make it coarser, or raise PLIANT_MAX_PARTICLES if the machine has the memory"
    )


def scene_path(cfg: SceneConfig, rel: str, at: str) -> Path:
    """The file ``rel`` relative to the scene file's folder; it must exist and be a regular file."""
    if "\x00" in rel:
        raise scene_error(cfg, at, "the path contains a NUL character; give a plain file path")
    p = Path(cfg.base_dir) / rel
    try:
        ok = p.is_file()
    except (OSError, ValueError):
        ok = False
    if not ok:
        raise scene_error(cfg, at, f"no such file {str(p)!r}; paths are relative to the scene file's folder")
    return p


def npy_shape(cfg: SceneConfig, path: Path, at: str) -> tuple[tuple[int, ...], np.dtype]:
    """Shape and dtype from the ``.npy`` header, read without loading the data (or pickles)."""
    try:
        size = path.stat().st_size
        if size == 0:
            raise ValueError("the file is empty (0 bytes)")
        with open(path, "rb") as f:
            major, _ = np.lib.format.read_magic(f)
            read = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
            shape, _fortran, dtype = read(f)
            header = f.tell()
    except (OSError, ValueError, EOFError, SyntaxError, TypeError) as exc:
        msg = str(exc).split("\n")[0][:200]
        raise scene_error(cfg, at, f"{path.name} is not a readable .npy array ({msg})") from None
    if dtype.hasobject or dtype.kind not in "fiu":
        raise scene_error(
            cfg, at, f"{path.name} holds {dtype} values; points must be real numbers (float) of shape (N, 3)"
        )
    if len(shape) != 2 or shape[1] != 3:
        raise scene_error(cfg, at, f"{path.name} has shape {shape}; points must have shape (N, 3) [m]")
    if shape[0] * 3 * dtype.itemsize > size - header:
        raise scene_error(
            cfg, at, f"{path.name}: its header claims {shape[0]} points but the file is shorter"
        )
    return shape, dtype


def load_points_npy(cfg: SceneConfig, path: Path, at: str) -> np.ndarray:
    """Points [N, 3] float64 from a ``.npy`` file, shape and budget checked from the header first."""
    shape, _ = npy_shape(cfg, path, at)
    if shape[0] > max_particles():
        raise scene_error(cfg, at, budget_message(shape[0], path.name))
    if shape[0] == 0:
        raise scene_error(cfg, at, f"{path.name} holds no points")
    try:
        pts = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise scene_error(cfg, at, f"{path.name} is not a readable .npy array ({str(exc)[:200]})") from None
    pts = np.asarray(pts, np.float64)
    if not np.all(np.isfinite(pts)) or np.abs(pts).max() > 1e6:
        raise scene_error(cfg, at, f"{path.name} holds NaN, inf or coordinates beyond 1e6 m")
    return pts


def load_mesh_file(cfg: SceneConfig, rel: str, at: str) -> TriMesh | TetMesh:
    """``pl.geometry.load_mesh`` of a file named by the scene, its failures reported at ``at``."""
    from ..geometry import load_mesh

    path = scene_path(cfg, rel, at)
    try:
        mesh = load_mesh(path)
    except (ValueError, OSError, ImportError, KeyError, IndexError, TypeError, EOFError, SystemExit) as exc:
        # Third-party readers (trimesh, meshio) fail in many ways on a malformed file (meshio used to call
        # sys.exit); none of them may escape as a traceback or end the interpreter.
        msg = (
            "not a readable mesh file of its format"
            if isinstance(exc, SystemExit)
            else str(exc).split("\n")[0][:200] or type(exc).__name__
        )
        raise scene_error(cfg, at, f"cannot read the mesh {path.name}: {msg}") from None
    pts = np.asarray(mesh.points, np.float64)
    if pts.ndim != 2 or pts.shape[0] == 0 or pts.shape[1] != 3:
        raise scene_error(cfg, at, f"the mesh {path.name} has no 3D vertices")
    if not np.all(np.isfinite(pts)) or np.abs(pts).max() > 1e6:
        raise scene_error(cfg, at, f"the mesh {path.name} has NaN, inf or coordinates beyond 1e6 m")
    if pts.shape[0] > max_particles():
        raise scene_error(cfg, at, budget_message(pts.shape[0], path.name))
    return mesh


def load_surface_file(cfg: SceneConfig, rel: str, at: str) -> TriMesh:
    """:func:`load_mesh_file` of a file that must be a triangle surface (a collider, a render mesh): a
    tetrahedral mesh there is a SceneError naming the formats, not an AttributeError later."""
    from ..geometry import TriMesh

    mesh = load_mesh_file(cfg, rel, at)
    if not isinstance(mesh, TriMesh):
        raise scene_error(
            cfg, at, f"{Path(rel).name} is a tetrahedral mesh; give a triangle surface (OBJ, PLY or STL)"
        )
    return mesh
