"""Reading and validating scene files: TOML → :class:`SceneConfig`, then the cross-field rules, the option
names and the particle budget — all before anything is allocated or simulated."""

from __future__ import annotations

import importlib.resources
import os
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from ._errors import SceneError, line_of, problems_from
from ._files import budget_message, max_particles
from ._overrides import apply_overrides
from ._registry import HANDLE_KINDS, OBJECT_KINDS, SECTIONS, SOLVER_KINDS, handle_mode
from ._schema import SceneConfig
from ._size import scene_size, size_problem
from ._solvers import check_solver

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

#: The largest scene file read [bytes] (a scene is a few kB; this stops a mistaken multi-GB argument).
MAX_SCENE_BYTES = 10_000_000


def builtin_scenes() -> list[str]:
    """Names of the scenes shipped with pliant (``pliant run <name>``)."""
    root = importlib.resources.files("pliant") / "scenes"
    return sorted(p.name[: -len(".toml")] for p in root.iterdir() if p.name.endswith(".toml"))


def _resolve(path_or_name: str | os.PathLike) -> tuple[str, str, str]:
    """(display name, text, base directory) of a scene file or a built-in scene name."""
    p = Path(path_or_name)
    try:
        is_file = p.is_file()
    except (OSError, ValueError):
        is_file = False
    if is_file:
        try:
            if p.stat().st_size > MAX_SCENE_BYTES:
                raise OSError(f"larger than {MAX_SCENE_BYTES} bytes; is this a scene file?")
            return str(p), p.read_text(encoding="utf-8"), str(p.resolve().parent)
        except (OSError, UnicodeDecodeError) as exc:
            raise SceneError(str(p), [(None, "", f"cannot read the scene file ({exc})")]) from exc
    name = str(path_or_name)
    names = builtin_scenes()
    if name in names:
        res = importlib.resources.files("pliant") / "scenes" / f"{name}.toml"
        return f"{name}.toml", res.read_text(encoding="utf-8"), str(Path(str(res)).parent)
    raise SceneError(
        name,
        [(None, "", f"no such scene file, and not a built-in scene; built-in scenes: {', '.join(names)}")],
    )


def parse_scene(
    text: str,
    source: str = "<scene>",
    base_dir: str | os.PathLike = ".",
    overrides: Sequence[str] = (),
    *,
    force: bool = False,
) -> SceneConfig:
    """Validate the TOML ``text`` of a scene; ``source`` names it in errors (``base_dir``: where the files
    it refers to are looked up; ``overrides``: ``PATH=VALUE`` strings, e.g. ``"scene.frames=10"``, set
    before validation, so they are checked like the file's own values; ``force``: skip the size checks —
    the memory the scene needs (:func:`~pliant.scene.scene_size`) against the machine's available memory,
    and the particle budget — and build it anyway).

    Raises:
        SceneError: naming the file, line, field and the fix.
    """
    import re

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        msg = re.sub(r"\s*\(at line \d+, column \d+\)", "", str(exc))
        raise SceneError(
            source, [(int(m.group(1)) if m else None, "", f"TOML syntax error: {msg}")]
        ) from None
    except RecursionError:
        raise SceneError(source, [(None, "", "TOML nesting too deep")]) from None
    bad = apply_overrides(data, overrides)
    if bad:
        raise SceneError(source, [(None, p, f"(--set) {m}") for p, m in bad])
    try:
        cfg = SceneConfig.model_validate(data)
    except ValidationError as exc:
        raise SceneError(source, problems_from(exc, text)) from None
    cfg.source, cfg.base_dir, cfg.text = source, str(base_dir), text
    problems = [(line_of(text, p), p, m) for p, m in check(cfg, force=force)]
    if problems:
        raise SceneError(source, problems)
    return cfg


def load_scene(
    path_or_name: str | os.PathLike, overrides: Sequence[str] = (), *, force: bool = False
) -> SceneConfig:
    """Read and validate a scene file, or a built-in scene by name (``"cloth"``, ``"rope"`` ...);
    ``overrides`` are ``PATH=VALUE`` strings (``"objects[0].material.stiffness=200"``) applied first;
    ``force`` skips the size checks (memory and particle budget; see :func:`parse_scene`).

    Raises:
        SceneError: a ``ValueError`` naming the file, line, field and the fix.
    """
    source, text, base = _resolve(path_or_name)
    return parse_scene(text, source, base, overrides, force=force)


def _check_models(cfg: SceneConfig, kind: str) -> list[tuple[str, str]]:
    """Each object's ``model`` against its kind and the solver kind."""
    out: list[tuple[str, str]] = []
    sk = SOLVER_KINDS.get(kind)
    for i, o in enumerate(cfg.objects):
        at, mat = f"objects[{i}]", o.material
        ok = OBJECT_KINDS[o.kind]
        if o.model == "fem":
            if not ok.volumetric:
                vol = ", ".join(n for n, k in OBJECT_KINDS.items() if k.volumetric)
                out.append(
                    (
                        f"{at}.model",
                        f"'fem' needs a volume (kind {vol}), not {o.kind}; "
                        'use model = "mass_spring" or "pbd"',
                    )
                )
            elif mat.E is None:
                out.append((f"{at}.material.E", "model 'fem' needs Young's modulus E [Pa], e.g. E = 1e5"))
        elif o.model == "mass_spring":
            if o.kind == "cloth" and mat.stiffness is None and mat.Et is None:
                msg = "mass_spring cloth needs stiffness [N/m] or Et (E·t [N/m]), e.g. stiffness = 300"
                out.append((f"{at}.material.stiffness", msg))
            elif o.kind != "cloth" and mat.stiffness is None:
                msg = "model 'mass_spring' needs stiffness [N/m], e.g. stiffness = 500"
                out.append((f"{at}.material.stiffness", msg))
        if sk is not None and o.model not in sk.models:
            needs = " or ".join(f'"{n}"' for n, k in SOLVER_KINDS.items() if o.model in k.models)
            what = (
                "is a cluster (shape matching):" if o.kind == "cluster" else f"uses model {o.model!r}, which"
            )
            out.append(("solver.kind", f"objects[{i}] {what} needs kind = {needs}"))
        if ok.check is not None:
            out += ok.check(cfg, o, at)
    laws = {o.material.law for o in cfg.objects if o.model == "fem"}
    if len(laws) > 1:
        i = next(i for i, o in enumerate(cfg.objects) if o.model == "fem" and o.material.law != min(laws))
        out.append((f"objects[{i}].material.law", f"all fem objects must share one law, got {sorted(laws)}"))
    return out


def _check_handles(cfg: SceneConfig, kind: str) -> list[tuple[str, str]]:
    out: list[tuple[str, str]] = []
    names = cfg.object_names()
    for i, h in enumerate(cfg.handles):
        at = f"handles[{i}]"
        hk = HANDLE_KINDS.get(h.kind)
        if hk is None:
            out.append((f"{at}.kind", f"unknown kind {h.kind!r}; allowed: {', '.join(HANDLE_KINDS)}"))
            continue
        if hk.check is not None:
            out += hk.check(cfg, h, at)
        if handle_mode(h) == "springs":
            if h.stiffness is None:
                out.append((f"{at}.stiffness", "mode 'springs' needs stiffness [N/m] per link, e.g. 1e3"))
            if kind != "force":
                out.append(
                    (
                        f"{at}.mode",
                        'springs (pl.energies.ControlPoints) need solver kind "force"; '
                        'use mode = "kinematic" with xpbd/pbd',
                    )
                )
        if h.path is not None and h.velocity is not None:
            out.append((f"{at}.velocity", "give path or velocity, not both"))
        speed = h.max_speed()
        if speed > cfg.scene.max_speed:
            out.append(
                (
                    f"{at}.path" if h.path is not None else f"{at}.velocity",
                    f"moves at {speed:.3g} m/s, above [scene] max_speed = {cfg.scene.max_speed:g} m/s; "
                    "slow it down or raise max_speed",
                )
            )
        if isinstance(h.object, int) and h.object >= len(cfg.objects):
            out.append(
                (f"{at}.object", f"index {h.object} out of range; there are {len(cfg.objects)} objects")
            )
        elif isinstance(h.object, str) and h.object not in names:
            out.append((f"{at}.object", f"no object named {h.object!r}; objects: {', '.join(names)}"))
    return out


def _check_view(cfg: SceneConfig) -> list[tuple[str, str]]:
    out: list[tuple[str, str]] = []
    cam = cfg.camera
    if (cam.eye is None) != (cam.target is None):
        out.append(
            (
                "camera.eye" if cam.eye is None else "camera.target",
                "give both eye and target, or neither (the camera then frames the motion)",
            )
        )
    elif cam.eye is not None and cam.target is not None:  # both given (the test above)
        d = np.subtract(cam.target, cam.eye)
        if not np.linalg.norm(d) > 1e-9:
            out.append(("camera.target", "must differ from camera.eye"))
        elif not np.linalg.norm(np.cross(d, cam.up)) > 1e-9 * np.linalg.norm(d) * (
            np.linalg.norm(cam.up) or 1
        ):
            out.append(("camera.up", "must not be parallel to the view direction (target - eye), nor zero"))
    if cfg.output.video and cfg.output.fps is None and not 1.0 <= 1.0 / cfg.scene.frame_dt <= 1000.0:
        out.append(
            (
                "output.fps",
                f"the default video rate 1 / frame_dt = {1.0 / cfg.scene.frame_dt:.3g} fps is "
                "outside [1, 1000]; set [output] fps, or video = false",
            )
        )
    return out


def _check_budget(cfg: SceneConfig) -> list[tuple[str, str]]:
    """The memory the scene needs against the machine's, then the particles the objects would create
    against the budget (both estimated from the schema, before anything is allocated)."""
    try:
        problems = size_problem(cfg)
    except SceneError as exc:  # a referenced file that cannot be sized
        return [(p, m) for _, p, m in exc.problems]
    if problems:
        return problems
    total, limit = 0.0, max_particles()
    for i, o in enumerate(cfg.objects):
        est = OBJECT_KINDS[o.kind].particles
        try:
            n = float(est(cfg, o)) if est is not None else 0.0
        except SceneError as exc:  # a referenced file that cannot be sized
            return [(p, m) for _, p, m in exc.problems]
        total += n
        if n > limit:
            return [(f"objects[{i}]", budget_message(n, f"this {o.kind} object"))]
    if total > limit:
        return [("objects", budget_message(total, "the objects together"))]
    return []


def _check_counts(cfg: SceneConfig) -> list[tuple[str, str]]:
    """With --force: only the absurd counts (non-finite, or above ``MAX_COUNT``), which no memory holds; a
    mesh file that cannot be read is left to the build, which names it."""
    try:
        scene_size(cfg)
    except SceneError as exc:
        if any("beyond any machine" in m for _, _, m in exc.problems):
            return [(p, m) for _, p, m in exc.problems]
    return []


def check(cfg: SceneConfig, *, force: bool = False) -> list[tuple[str, str]]:
    """Cross-field rules that pydantic's per-field types cannot express: (path, message) each (``force``:
    without the size checks)."""
    kind = cfg.solver_kind()
    out = check_solver(cfg)
    out += _check_models(cfg, kind)
    out += _check_handles(cfg, kind)
    out += _check_view(cfg)
    for sec in SECTIONS.values():
        value = getattr(cfg, sec.name, None)
        if value is not None and sec.check is not None:
            out += sec.check(cfg, value)
    if not out and not force:
        out += _check_budget(cfg)
    elif not out:
        out += _check_counts(cfg)
    return out
