"""A scene for a bare mesh file: the spring stiffness and substeps that run it stably, and the TOML text of a
scene that uses them (what ``pliant run mesh.obj`` prints). The mesh is filled with tets here, in the scene
layer, as ``kind = "mesh"`` fills it when the scene is built."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path, PurePath

import numpy as np

#: Strain under the body's own weight that the suggested spring stiffness gives (1 %: it keeps its shape).
MESH_SAG = 0.01
#: ω·Δt of the stiffest particle in the suggested scene: half the explicit limit 2 (a margin over the
#: Gershgorin bound of the spring network's highest frequency).
MESH_OMEGA_DT = 1.0


def mesh_scene_values(path: str | Path, density: float = 1000.0, frame_dt: float = 1.0 / 60.0) -> dict:
    """Spring stiffness and substeps that run ``path`` (a mesh file) as a stable mass-spring scene.

    The mesh is filled with tets as ``kind = "mesh"`` does (TetGen for a closed surface) and the scene's
    masses are lumped the same way (ρ·V/4 per tet corner). Stiffness: a spring network of edge length h
    behaves like a material of modulus E ≈ k/h, and a column of height H sags by the strain ρ g H / E under
    its own weight, so k = ρ g H h / ``MESH_SAG``. Substeps: the network's highest angular frequency is
    bounded by Gershgorin, ω² ≤ max_i 2 k n_i / m_i (n_i springs at particle i of mass m_i), and symplectic
    Euler is stable for ω Δt < 2; the substeps make ω Δt = ``MESH_OMEGA_DT``.

    Args:
        path: a surface (.obj, .ply, .stl, ...) or tet mesh (.msh, .vtk, .vtu) file.
        density: ρ [kg/m³] (the scene's default for a mesh object).
        frame_dt: the frame duration [s] (the scene's default).

    Returns:
        ``stiffness`` [N/m], ``substeps``, ``particles``, ``mass`` [kg], ``height`` [m] (the mesh's extent)
        and ``lift`` [m], the upward shift that puts its lowest point 10 % of that extent above y = 0.
    """
    from ..geometry import TetMesh, edges_from_tets, load_mesh, signed_tet_volumes, tetrahedralize

    mesh = load_mesh(path)
    pts = np.asarray(mesh.points, np.float64)
    if isinstance(mesh, TetMesh):
        tets = np.asarray(mesh.tets)
    else:
        tm = tetrahedralize(pts, mesh.triangles, name=str(path))
        pts, tets = np.asarray(tm.points, np.float64), np.asarray(tm.tets)
    m = np.zeros(len(pts))
    np.add.at(m, tets.ravel(), np.repeat(np.abs(signed_tet_volumes(pts, tets)) * density / 4.0, 4))
    edges = edges_from_tets(tets)
    h = float(np.median(np.linalg.norm(pts[edges[:, 0]] - pts[edges[:, 1]], axis=1)))
    height = float(np.ptp(pts, axis=0).max())
    k = density * 9.81 * height * h / MESH_SAG
    k = float(f"{k:.2g}")  # two significant digits (rounding changes ω by < 5 %, within the margin)
    n = np.bincount(edges.ravel(), minlength=len(pts))
    used = m > 0
    omega = math.sqrt(float(np.max(2.0 * k * n[used] / m[used])))
    substeps = max(1, math.ceil(frame_dt * omega / MESH_OMEGA_DT))
    lift = 0.1 * height - float(pts[:, 1].min())  # the lowest point 10 % of the size above the ground
    return {
        "stiffness": k,
        "substeps": substeps,
        "particles": len(pts),
        "mass": float(m.sum()),
        "height": height,
        "lift": lift,
    }


@dataclass
class MeshScene:
    """A scene that runs a mesh file (:func:`from_mesh`).

    Attributes:
        values: :func:`mesh_scene_values` of the mesh, or None when it could not be read (then the TOML
            carries a generic stiffness and a note to raise the substeps).
        toml: the scene file's text (comment lines first; ``path`` is the mesh's file name, so the scene is
            meant to be saved next to the mesh).
    """

    values: dict | None
    toml: str


def mesh_scene_toml(path: str | Path, values: dict | None) -> str:
    """The TOML text of a scene that drops the mesh ``path`` onto the ground, with the stiffness and substeps
    of ``values`` (:func:`mesh_scene_values`; None: a generic stiffness of 500 N/m and a note).

    Args:
        path: the mesh file (only its name is written: the scene is saved next to it).
        values: the mesh's values, or None.
    """
    p = PurePath(path)
    lines = [
        "# a closed surface is filled with tets, a tet mesh used as is; it falls onto the ground.",
        '# Add scale, origin, rotation = [x, y, z] degrees or up = "z" to [[objects]] as needed;',
        "# `pliant scenes show soft_box` shows a complete scene.",
    ]
    v = values
    if v is not None:
        lines += [
            "[scene]",
            f"substeps = {v['substeps']}   # explicit steps per frame: ω·Δt ≤ {MESH_OMEGA_DT:g} (< 2) for "
            "the stiffest particle",
        ]
    lines += ["[[objects]]", 'kind = "mesh"', f'path = "{p.name}"']
    if v is not None:
        lines.append(f"origin = [0.0, {v['lift']:.3g}, 0.0]   # [m]: its lowest point just above the ground")
        lines.append(
            f"material = {{ stiffness = {v['stiffness']:g} }}   # [N/m]: sags ~{MESH_SAG:.0%} under its own "
            f"weight ({v['particles']} particles, {v['mass']:.3g} kg, {v['height']:.3g} m)"
        )
    else:
        lines.append("material = { stiffness = 500 }   # [N/m]; raise [scene] substeps if it diverges")
    lines += ["[ground]", "friction = 0.5"]
    return "\n".join(lines)


def from_mesh(path: str | Path, *, density: float = 1000.0, frame_dt: float = 1.0 / 60.0) -> MeshScene:
    """A scene that runs the mesh file ``path`` stably as a mass-spring body falling onto the ground.

    Args:
        path: a surface (.obj, .ply, .stl, ...) or tet mesh (.msh, .vtk, .vtu) file.
        density: ρ [kg/m³] of the body.
        frame_dt: the frame duration [s] the substeps are chosen for.

    Returns:
        A :class:`MeshScene` (its ``toml`` saved next to the mesh is a scene :func:`load_scene` reads).

    Raises:
        ValueError, OSError: the mesh cannot be read or filled with tets (the message names the file).
    """
    values = mesh_scene_values(path, density, frame_dt)
    return MeshScene(values, mesh_scene_toml(path, values))
