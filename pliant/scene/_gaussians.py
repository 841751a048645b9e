"""The ``[gaussians]`` section: Gaussian splats bound to one object, rendered by ``pliant run``, and optional
visual correction from images of a "real" twin (``[gaussians.correction]``).

The scene layer only validates the section into a plain spec (files exist, the object exists, options fit
the object); building, binding, rendering and correcting happen above it (``pl.gaussians``, the CLI)::

    [gaussians]
    object = "cloth"          # name or index; default: the first object
    generate = "mesh"         # one flat splat per surface triangle (default), or ply = "splats.ply"
    bind = "triangles"        # triangles | barycentric | lbs | rigid (default: by object)
    checker = 0.125           # colour checker cell [m] of generated splats (0: plain color)

    [gaussians.correction]    # run a twin with these overrides, render it, correct this run toward it
    set = ["objects[0].material.stiffness=300"]
    cameras = 3
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, Strict

from ._registry import OBJECT_KINDS, register_section
from ._schema import MAX_NAME, MAX_PIXELS, Float, Fraction, NonNegFloat, PosFloat, Section, Vec3

_Colour = Vec3
_Pixels = Annotated[int, Strict(), Field(ge=8, le=MAX_PIXELS)]


class GaussianCorrectionSection(Section):
    """``[gaussians.correction]``: the twin's overrides, its cameras and the corrector's settings."""

    set: Annotated[list[Annotated[str, Field(max_length=1000)]], Field(min_length=1, max_length=100)]
    cameras: Annotated[int, Strict(), Field(ge=1, le=16)] = 3
    width: _Pixels = 96
    height: _Pixels = 72
    method: Literal["state", "forces"] = "state"
    iterations: Annotated[int, Strict(), Field(ge=1, le=1000)] | None = None
    max_step: Annotated[float, Strict(), Field(gt=0, le=1e6)] | None = None  # [m] trust region
    position_gain: Fraction = 1.0
    velocity_gain: NonNegFloat = 0.5
    force_gain: NonNegFloat = 0.2
    report_uncorrected: bool = True  # also run without correction and print both drifts


class GaussiansSection(Section):
    """``[gaussians]``: which splats, bound how, to which object (see the module doc)."""

    object: Annotated[str, Field(max_length=MAX_NAME)] | Annotated[int, Strict(), Field(ge=0)] | None = None
    ply: Annotated[str, Field(min_length=1, max_length=4096)] | None = None
    generate: Literal["mesh"] | None = None
    bind: Literal["triangles", "barycentric", "lbs", "rigid"] | None = None
    k: Annotated[int, Strict(), Field(ge=1, le=64)] = 16
    neighbours: Annotated[int, Strict(), Field(ge=2, le=64)] = 16
    scale: PosFloat = 1.0  # generated splats: size relative to their triangle
    opacity: Annotated[Fraction, Field(gt=0)] = 0.9
    color: _Colour = (0.85, 0.35, 0.2)
    color2: _Colour = (0.95, 0.9, 0.75)
    checker: NonNegFloat = 0.0  # checker cell size [m] of generated splats' colours; 0: plain ``color``
    background: _Colour = (1.0, 1.0, 1.0)
    # Lambertian shading of the splats: (ambient, Lx, Ly, Lz, headlight), L the directional light's
    # direction × intensity (towards the light); `pliant fit`'s appearance stage writes it. None: unlit.
    light: Annotated[list[Float], Field(min_length=5, max_length=5)] | None = None
    correction: GaussianCorrectionSection | None = None


def object_index(cfg, g: GaussiansSection) -> int | None:
    """Index of the object ``[gaussians] object`` names (0 when unset), or None if there is no such object."""
    if g.object is None:
        return 0
    if isinstance(g.object, int):
        return g.object if g.object < len(cfg.objects) else None
    names = cfg.object_names()
    return names.index(g.object) if g.object in names else None


def _check(cfg, g: GaussiansSection) -> list[tuple[str, str]]:
    from ._errors import SceneError
    from ._files import scene_path

    out: list[tuple[str, str]] = []
    i = object_index(cfg, g)
    if i is None:
        what = f"no object named {g.object!r}"
        if isinstance(g.object, int):
            what = f"index {g.object} out of range"
        out.append(("gaussians.object", f"{what}; objects: {', '.join(cfg.object_names())}"))
    if g.ply is not None and g.generate is not None:
        out.append(("gaussians.generate", "give ply (splats from a file) or generate, not both"))
    elif g.ply is not None:
        try:
            scene_path(cfg, g.ply, "gaussians.ply")
        except SceneError as exc:
            out += [(p, m) for _, p, m in exc.problems]
    if i is not None:
        o = cfg.objects[i]
        if g.bind == "barycentric" and not OBJECT_KINDS[o.kind].volumetric:
            out.append(
                (
                    "gaussians.bind",
                    f"'barycentric' embeds splats in tets, but objects[{i}] ({o.kind}) has none; "
                    'use "triangles" (a surface) or "lbs"',
                )
            )
    if g.correction is not None:
        for j, item in enumerate(g.correction.set):
            if "=" not in item:
                out.append((f"gaussians.correction.set[{j}]", f"expected PATH=VALUE, got {item!r}"))
        if len(cfg.objects) != 1:
            out.append(
                ("gaussians.correction", "visual correction needs a scene with exactly one object (for now)")
            )
    return out


register_section("gaussians", GaussiansSection, check=_check)
