"""Scene files (TOML): load, validate and build a Model, a Solver and a Simulator.

A scene file has the sections ``[scene]``, ``[[objects]]`` (one per body), ``[[colliders]]``, ``[[handles]]``,
``[[energies]]``, ``[[constraints]]``, ``[ground]``, ``[solver]``, ``[camera]``, ``[output]`` and registered
sections such as ``[gaussians]`` (``register_section``); README.md
documents every field. Errors name the file, the line when it can be found, the field as a dotted path
(``objects[1].material.E``) and the fix. Object, collider, handle and solver kinds, energies and
constraints are registries (``register_*``): a new kind is one registered function.
"""

from __future__ import annotations

from . import _contacts, _gaussians, _objects  # noqa: F401 - register the built-in kinds and sections
from ._build import Embedding, Scene, build_scene, lumped_masses, lumped_particles
from ._context import BuildContext
from ._errors import SceneError
from ._files import scene_path
from ._from_mesh import MeshScene, from_mesh, mesh_scene_toml, mesh_scene_values
from ._gaussians import GaussianCorrectionSection, GaussiansSection, object_index
from ._knobs import KNOBS, Around, Knob, UpTo, knob, knob_arrays, registry_arrays
from ._load import builtin_scenes, load_scene, parse_scene
from ._registry import (
    register_collider_kind,
    register_constraint,
    register_energy,
    register_handle_kind,
    register_object_kind,
    register_section,
    register_solver,
)
from ._replicate import coupled, worlds_unsupported
from ._schema import ColliderBase, Material, ObjectBase, SceneConfig
from ._size import SceneSize, available_memory, format_bytes, scene_size
from ._solvers import integrator_names, make_integrator
from ._terms import register_builtin_terms
from ._worlds import build_worlds, material_only

register_builtin_terms()

__all__ = [
    "lumped_masses",
    "lumped_particles",
    "scene_path",
    "GaussianCorrectionSection",
    "GaussiansSection",
    "object_index",
    "coupled",
    "worlds_unsupported",
    "format_bytes",
    "material_only",
    "KNOBS",
    "Around",
    "BuildContext",
    "ColliderBase",
    "Embedding",
    "Knob",
    "Material",
    "MeshScene",
    "ObjectBase",
    "Scene",
    "SceneConfig",
    "SceneError",
    "SceneSize",
    "available_memory",
    "build_scene",
    "build_worlds",
    "builtin_scenes",
    "from_mesh",
    "integrator_names",
    "knob",
    "knob_arrays",
    "load_scene",
    "make_integrator",
    "mesh_scene_toml",
    "mesh_scene_values",
    "parse_scene",
    "register_collider_kind",
    "register_constraint",
    "register_energy",
    "register_handle_kind",
    "register_object_kind",
    "register_section",
    "register_solver",
    "registry_arrays",
    "scene_size",
    "UpTo",
]
