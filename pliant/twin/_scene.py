"""The twin's scene file: the carved volume as a tetrahedral mesh, a physical model on it, what holds it,
the ground, and the splats, written as ordinary TOML that ``pliant run`` and ``pliant view`` take.

Why these choices:

- **One geometry, three models.** The carved voxels' centres become the nodes of cubes of six tetrahedra
  (:func:`pliant.geometry.voxel_tets` with ``dual=True``: a carved hull is the object plus up to half a
  voxel, so the centres, not the voxels' corners, lie on its surface) in a ``.vtu`` file, loaded by a
  ``mesh`` object; PhysTwin's spring network (springs to the neighbours within a radius) takes the same
  particles as a ``points`` object. The same mesh
  carries the models the fit can choose among (``--models``): tetrahedral FEM (neo-Hookean) or the tet
  edges as springs.
- **An integrator that does not damp.** The twin must predict the held-out frames, so its step must not
  bleed energy numerically: implicit (backward) Euler damps every mode at a rate set by the step — the
  lecture's point about its artificial damping — and a fitted damping would then absorb that error. The
  implicit midpoint rule is symplectic for this Hamiltonian system and unconditionally stable, so the
  fitted Rayleigh damping (``damping_rate``) is the only dissipation.
- **Relative paths.** Every file the scene names sits beside it, so the twin folder can be moved.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

#: Substeps per observed frame of the implicit midpoint rule. One: the rule is unconditionally stable and
#: does not damp; at 30 frames/s it lengthens a 2 Hz mode's period by about 1 % ((ω dt)² / 12), which the
#: fitted stiffness absorbs because the twin is fitted with the same step. Two cost 1.5x (MuJoCo's beam,
#: 2,440 particles, one core: 3.8 s against 5.9 s for 63 frames).
SUBSTEPS = 1
#: Starting Young's modulus [Pa] of the fit (a soft rubber); CMA-ES searches a decade either side.
NOMINAL_E = 3e5
#: Most springs per particle of the ``springs`` model (PhysTwin: 30 within 2 cm; the 26 neighbours of a
#: cubic lattice within 1.8 spacings).
NEIGHBOURS = 26
#: Starting Rayleigh (mass-proportional) damping rate [1/s].
NOMINAL_DAMPING_RATE = 0.5


def write_mesh(path: Path, points: np.ndarray, tets: np.ndarray) -> Path:
    """Write a tetrahedral mesh as VTK unstructured grid (``.vtu``) that a ``mesh`` object loads."""
    import meshio

    meshio.write(str(path), meshio.Mesh(np.asarray(points, dtype=np.float64), [("tetra", np.asarray(tets))]))
    return path


def twin_scene(
    *,
    geometry_file: str,
    model: str,
    spacing: float,
    density: float,
    frame_dt: float,
    frames: int,
    boxes: list[tuple[np.ndarray, np.ndarray]],
    ground: float | None,
    splats_file: str | None,
    camera: dict[str, Any] | None,
    background: list[float] | None = None,
    centre: np.ndarray | None = None,
    particles: int = 0,
    name: str = "twin",
) -> dict[str, Any]:
    """The twin's scene as nested dicts (TOML tables), before any fit.

    Args:
        geometry_file: The tet mesh file (``fem``, ``mass_spring``) or the particles' ``.npy`` (``springs``),
            relative to the scene file.
        model: ``"fem"`` (neo-Hookean tets), ``"mass_spring"`` (the tet edges as springs) or ``"springs"``
            (PhysTwin's: springs to the neighbours within 1.8 spacings, at most :data:`NEIGHBOURS`).
        spacing: Voxel side [m] (the springs' starting stiffness is E times it).
        density: Mass density [kg/m³] (the object's mass follows from the carved volume).
        frame_dt: Time between observed frames [s].
        frames: Frames to simulate after frame 0.
        boxes: Kinematic box handles, (centre [3], half extents [3]) [m] each.
        ground: Ground height [m] along +y, or None.
        splats_file: The splats' PLY, relative to the scene file, or None.
        camera: The ``[camera]`` table (eye, target, fov), or None.
        background: RGB in [0, 1] behind the splats, or None for white.
        centre: ``springs``: the particles' mean [m] (a points object places its file's mean there).
        particles: ``springs``: the particle count (the mass is density times a voxel per particle).
        name: The object's name.

    Returns:
        The scene as dicts (:func:`pliant.fit.toml_dumps` writes it).
    """
    if model == "fem":
        material: dict[str, Any] = {"E": NOMINAL_E, "nu": 0.3, "law": "neohookean"}
    elif model in ("mass_spring", "springs"):
        # A spring of a cubic lattice of pitch h carries about E h (pliant.fit's model conversion).
        material = {"stiffness": NOMINAL_E * spacing}
    else:
        raise ValueError(f"--models: the twin builds fem, mass_spring or springs, got {model!r}")
    if model == "springs":
        assert centre is not None and particles > 0
        obj: dict[str, Any] = {
            "kind": "points",
            "name": name,
            "path": geometry_file,
            "origin": [float(v) for v in centre],
            "spacing": float(spacing),
            "mass": float(density * particles * spacing**3),
            "radius": 1.8 * float(spacing),
            "max_neighbors": NEIGHBOURS,
            "material": material,
        }
    else:
        obj = {
            "kind": "mesh",
            "name": name,
            "path": geometry_file,
            "model": model,
            "density": float(density),
            "material": material,
        }
    data: dict[str, Any] = {
        "scene": {"name": name, "frame_dt": float(frame_dt), "substeps": SUBSTEPS, "frames": int(frames)},
        "objects": [obj],
        "solver": {
            "kind": "force",
            "integrator": "ImplicitMidpoint",
            "damping_rate": NOMINAL_DAMPING_RATE,
            "options": {"minimizer": {"method": "auto"}},
        },
    }
    if boxes:
        data["handles"] = [
            {
                "kind": "box",
                "object": name,
                "center": [float(v) for v in c],
                "half_extents": [float(v) for v in h],
            }
            for c, h in boxes
        ]
    if ground is not None:
        data["ground"] = {"height": float(ground)}
    if splats_file is not None:
        data["gaussians"] = {"object": name, "ply": splats_file, "bind": "lbs"}
        if background is not None:
            data["gaussians"]["background"] = background
    if camera is not None:
        data["camera"] = camera
    data["output"] = {"fps": max(1, int(round(1.0 / frame_dt)))}
    return data


def camera_table(
    K: np.ndarray, world_to_camera: np.ndarray, height: int, target: np.ndarray
) -> dict[str, Any]:
    """A ``[camera]`` table at an observing camera's position, looking at ``target`` [m] with its vertical
    field of view (so ``pliant run``'s preview video looks like the footage)."""
    R, t = world_to_camera[:3, :3], world_to_camera[:3, 3]
    eye = -R.T @ t
    fov = float(np.degrees(2.0 * np.arctan(0.5 * height / K[1, 1])))
    return {
        "eye": [float(v) for v in eye],
        "target": [float(v) for v in target],
        "fov": min(max(fov, 5.0), 120.0),
    }


__all__ = ["NOMINAL_DAMPING_RATE", "NOMINAL_E", "SUBSTEPS", "camera_table", "twin_scene", "write_mesh"]
