"""Fitted parameters: global ones (scene-file values, changed by rebuilding the scene) and per-element ones
(model arrays changed in place, with gradients from the tape). Both name the registry parameters
(:mod:`pliant.model._parameters`) they drive; the arrays and the classes that read them come from there.

Global parameters (``GLOBAL``) live in the scene file: they are the knobs of :data:`pliant.scene.KNOBS`
(declared once, beside the schema), and every table here is a view of them. The CMA-ES stage searches them
in a box normalised to [0, 1]ᵈ, log-scaled for positive magnitudes. Topology parameters (spring radius and
neighbour count of point-cloud objects) rebuild the springs, so only the derivative-free stage may
change them.
Per-element parameters (``PER_ELEMENT``) are log-scale factors θ on model arrays, ``a = a₀ · exp(θ)``:
``stiffness`` (per spring k) and ``E`` (per tet, μ and λ together: ν unchanged).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..scene import KNOBS, Knob, registry_arrays

if TYPE_CHECKING:
    from ..io import Observations
    from ..model import Parameter
    from ..scene import Scene, SceneConfig


class FitError(ValueError):
    """A fitting set-up that cannot work (unknown parameter, nothing to fit, no gradient); one line, with the
    fix."""


#: A global parameter is a knob (:class:`pliant.scene.Knob`): its scene field, bounds, search box and the
#: registry parameters it drives are declared once, in ``pliant/scene/_knobs.py``.
GlobalParam = Knob

#: The global parameters: the knobs the fit may search (:attr:`Knob.fit`), in :data:`pliant.scene.KNOBS`
#: order. The CMA-ES stage searches them in a box normalised to [0, 1]ᵈ: ``Knob.box(value)``, the knob's
#: declared policy around the scene's value (×/÷ 10 for most magnitudes), not its physical bounds.
GLOBAL: dict[str, GlobalParam] = {n: k for n, k in KNOBS.items() if k.fit}


def scene_constraints(scene: Scene) -> list[Any]:
    """The constraint sets of the scene's solver (XPBD / PBD), indexed as in ``constraints.<i>.<array>``
    keys; empty for the other solvers. Each is a :class:`~pliant.constraints.Constraint` of some kind;
    callers read what their kind has (``indices``, the ``parameters()`` that ``@declares`` checked)."""
    return list(getattr(scene.solver, "constraints", []))


def _per_element(name: str, what: str) -> Callable[[Any], dict[str, Any]]:
    def arrays(scene: Scene) -> dict[str, Any]:
        out = registry_arrays(scene, GLOBAL[name].drives)
        if not out:
            raise FitError(f"--per-element: this scene's model has no {what}")
        for key, a in out.items():
            if key.startswith("constraints.") and not np.all(a.numpy() > 0):
                c = scene_constraints(scene)[int(key.split(".")[1])]
                raise FitError(
                    f"--per-element {name}: {type(c).__name__} constraints are rigid (α = 0), which a "
                    "log-scale factor cannot change; give the scene a compliance > 0"
                )
        return out

    return arrays


#: Per-element parameters: name → (the arrays scaled together by exp(θ) per element, what it is): the knobs
#: with :attr:`~pliant.scene.Knob.per_element`, over the model arrays and constraint arrays of the registry
#: parameters each drives.
PER_ELEMENT: dict[str, tuple[Callable[[Any], dict[str, Any]], str]] = {
    n: (_per_element(n, k.per_element[0]), k.per_element[1])
    for n, k in GLOBAL.items()
    if k.per_element is not None
}

#: Default parameters per object model, each with why it is searched (issue 25): the ones that matter for
#: motion recorded elsewhere — the stiffness, and the two dissipations (velocity damping rate and, for
#: mass-spring, the dashpot along the springs), which another engine's or a real object's motion always has.
#: A view of the knobs' ``default_for`` and ``why``, in knob order.
WHY: dict[str, tuple[tuple[str, str], ...]] = {
    model: tuple((n, k.why) for n, k in GLOBAL.items() if model in k.default_for)
    for model in dict.fromkeys(m for k in GLOBAL.values() for m in k.default_for)
}
#: Default parameter names per object model (the names of :data:`WHY`).
DEFAULTS = {model: tuple(n for n, _ in rows) for model, rows in WHY.items()}
#: The per-element parameter of each model (``per_element="auto"``): its first default knob that has one.
PER_ELEMENT_OF = {
    model: next(n for n in names if n in PER_ELEMENT)
    for model, names in DEFAULTS.items()
    if any(n in PER_ELEMENT for n in names)
}

#: Compliant contact's knobs (``[ground] stiffness``, ``damping_ratio``), searched by default when the tracks
#: sink into the ground (:func:`sinks_into_ground`).
COMPLIANT = ("ground_stiffness", "ground_damping_ratio")
#: Ground coefficients (the other knobs of the ``[ground]`` section), searched by default when the
#: observations reach the ground.
CONTACT = tuple(n for n, k in GLOBAL.items() if k.section == "ground" and n not in COMPLIANT)
#: How far [m] the lowest track must go below the ground, at least, before the fit explains it by compliant
#: contact: beyond the tracks' noise (a tracker's millimetre or two; synthetic tracks have 1 mm), so that a
#: body resting on a hard ground with noisy tracks does not switch it on. Noisier tracks raise the bar
#: (:func:`sink_threshold`).
SINK_NOISE = 2.0e-3
#: Standard deviations of the tracks' noise (:func:`track_noise`) the lowest track must go below the ground:
#: the lowest of the thousand or so samples near a ground is about 3.7 σ below the truth for Gaussian noise
#: (√(2 ln 1000)), so 4 σ leaves a resting body on a hard ground alone in all but a few per cent of cases.
SINK_SIGMAS = 4.0
#: The share of quietest frames :func:`track_noise` pools: a quarter recovers the 1.5 mm of the foreign
#: fixtures' tracks as 1.35-1.58 mm (2.53 mm on Newton's bouncing box; all frames: 3.3 mm there), and
#: 1.26-1.60 mm from 8 tracks of a cube; a tenth reads as low as 1.03 mm from those 8 tracks.
NOISE_QUANTILE = 0.25


#: Mass-distribution knobs searched by default when the tracks cover the object (:func:`tracks_cover`); the
#: density field's ``mass_slope_x/y/z`` are searched only when named (``--params``).
MASS = ("mass_uniformity",)
#: The tracks cover the object, so :data:`MASS` is searched by default, when every particle lies within this
#: fraction of its object's size (the diagonal of its rest bounding box) of a track's first position: only
#: motion recorded across the whole object tells how its mass is spread. Measured on the repository's
#: fixtures: 40 random tracks on a 13 × 13 cloth reach within 0.137 of every particle (covered); 40 surface
#: tracks of a 5³ cube leave its interior 0.25 away, and 12 of a 5 × 5 cloth's 25 particles 0.25 (not).
MASS_REACH = 0.15


def _lumped(cfg: SceneConfig) -> list[np.ndarray] | None:
    """Each object's lumped particle masses [kg] (objects built on the host, no device), or None when one
    cannot be built here (the fit reports that itself when it builds the scene)."""
    rest = _rest(cfg)
    return None if rest is None else [m for m, _ in rest]


def _rest(cfg: SceneConfig) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """Each object's (lumped masses [kg], rest positions [m]), or None when one cannot be built here."""
    from ..scene import SceneError, lumped_particles

    try:
        return lumped_particles(cfg)
    except (SceneError, ValueError, OSError):
        return None


def tracks_cover(cfg: SceneConfig, obs: Observations | None) -> float | None:
    """The worst gap between a particle and the nearest track (each track's first visible position, or the
    particle a bound track follows), as a fraction of its object's size (the diagonal of its rest bounding
    box), when it is at most :data:`MASS_REACH` (the tracks cover the object), else None (no tracks, a gap
    wider than that, or a scene that cannot be built here)."""
    if obs is None or obs.tracks == 0 or not cfg.objects:
        return None
    rest = _rest(cfg)
    if not rest:
        return None
    from scipy.spatial import cKDTree

    x = np.concatenate([q for _, q in rest])
    vis = np.asarray(obs.visible, dtype=bool)
    seen = vis.any(axis=0)
    if not seen.any():
        return None
    if obs.particle is not None:
        idx = np.asarray(obs.particle)[seen]
        tracked = x[idx[(idx >= 0) & (idx < len(x))]]
    else:
        first = vis.argmax(axis=0)  # each track's first visible frame
        tracked = np.asarray(obs.points)[first, np.arange(vis.shape[1])][seen]
    if len(tracked) == 0:
        return None
    worst = 0.0
    for _, q in rest:
        if len(q) == 0:
            continue
        size = float(np.linalg.norm(q.max(axis=0) - q.min(axis=0)))
        gap = float(cKDTree(tracked).query(q)[0].max())
        worst = max(worst, gap / size if size > 0 else 0.0)
    return worst if worst <= MASS_REACH else None


def lumped_spread(cfg: SceneConfig, masses: list[np.ndarray] | None = None) -> float:
    """The largest ratio max m / min m of one object's lumped particle masses (1: every object's builder
    spreads its mass evenly already, as a rope's, a point cloud's and a cluster's do, so ``mass_uniformity``
    changes nothing; 1 too when an object cannot be built here). ``masses``: each object's lumped masses
    [kg] when the caller has them."""
    masses = _lumped(cfg) if masses is None else masses
    return max((float(m.max() / m.min()) for m in masses or () if m.size), default=1.0)


def ground_contact(cfg: SceneConfig, obs: Observations) -> float | None:
    """The lowest visible track height above the scene's ground [m] when the observations come within 5 % of
    their extent of it (they show contact), else None (no ground, no tracks, or motion well above it)."""
    g = getattr(cfg, "ground", None)
    if g is None or not g.enabled or obs is None or obs.tracks == 0:
        return None
    pts = obs.points[obs.visible]
    if pts.size == 0:
        return None
    gap = float(pts[:, 1].min()) - float(g.height)
    extent = float(np.ptp(pts, axis=0).max())
    return gap if gap <= 0.05 * max(extent, 1e-9) else None


def track_noise(obs: Observations) -> float:
    """A robust estimate of the tracks' position noise σ [m] per coordinate, from their third differences in
    time: x(t+3) − 3x(t+2) + 3x(t+1) − x(t) cancels any motion of constant acceleration (free fall, a steady
    swing) and has variance 20 σ² for white noise. A soft body's ringing after an impact makes third
    differences of millimetres too, so the estimate is taken from the quietest frames: those whose median
    |Δ³x| over tracks and axes is within the lowest :data:`NOISE_QUANTILE` of the frames, pooled, and
    σ = 1.4826 · median|Δ³x| / √20 there. Only runs of four visible frames count; 0 when there are none."""
    p, vis = obs.points, obs.visible
    if p.shape[0] < 4 or p.shape[1] == 0:
        return 0.0
    ok = vis[3:] & vis[2:-1] & vis[1:-2] & vis[:-3]
    d3 = np.abs(p[3:] - 3.0 * p[2:-1] + 3.0 * p[1:-2] - p[:-3])
    d3 = d3[ok.any(axis=1)]
    ok = ok[ok.any(axis=1)]
    if d3.size == 0:
        return 0.0
    d3 = np.where(ok[..., None], d3, np.nan).reshape(len(d3), -1)
    per_frame = np.nanmedian(d3, axis=1)
    quiet = per_frame <= np.quantile(per_frame, NOISE_QUANTILE)
    return float(1.4826 * np.nanmedian(d3[quiet]) / np.sqrt(20.0))


def sink_threshold(obs: Observations) -> float:
    """How far [m] the lowest track must go below the ground to count as sinking into it: :data:`SINK_SIGMAS`
    times the tracks' noise (:func:`track_noise`), and never less than :data:`SINK_NOISE`."""
    return max(SINK_NOISE, SINK_SIGMAS * track_noise(obs))


def sinks_into_ground(cfg: SceneConfig, obs: Observations | None) -> float | None:
    """How deep [m] (> 0) the lowest visible track goes below the scene's ground, when deeper than the
    tracks' noise allows (:func:`sink_threshold`); else None (no ground, no contact, or within the noise)."""
    gap = ground_contact(cfg, obs) if obs is not None else None
    if gap is None or obs is None:
        return None
    return -gap if gap < -sink_threshold(obs) else None


def contact_start(cfg: SceneConfig, obs: Observations | None) -> float | None:
    """κ [1/s²] that rests as deep as the tracks sink under the scene's gravity, |g|/d
    (:func:`sinks_into_ground`), or None when they do not sink. A lower bound of the truth twice over: an
    impact sinks deeper than the body rests, and a body's lowest particles carry more than their own weight
    (a 4 × 4 × 4-cell box's bottom layer about 8 times). Starting at the load-corrected g (M/m_c)/d instead
    fitted worse, on the MuJoCo soft cube and on tests/test_compliant_contact.py's: it puts the truth at the
    bottom of the search box."""
    depth = sinks_into_ground(cfg, obs)
    if depth is None:
        return None
    return float(np.linalg.norm(cfg.scene.gravity)) / depth


def seed_contact(cfg: SceneConfig, obs: Observations | None, names: list[str]) -> bool:
    """Start compliant contact where the tracks sink: set ``cfg``'s unset ``[ground] stiffness`` (in place)
    to :func:`contact_start` when ``names`` searches ``ground_stiffness``; whether it did (the scene then
    differs from the one given: its hard ground became a compliant one)."""
    g = getattr(cfg, "ground", None)
    if "ground_stiffness" not in names or g is None or not g.enabled or g.stiffness is not None:
        return False
    k = contact_start(cfg, obs)
    if k is None:
        return False
    g.stiffness = k
    return True


def default_params(cfg: SceneConfig, obs: Observations | None = None) -> list[str]:
    """The default parameters of the scene's models (:data:`WHY`: mass-spring k or E·t, damping rate,
    dashpot γ; FEM: E, ν, damping rate; XPBD: compliance, damping rate), plus the mass distribution
    (:data:`MASS`) when the tracks of ``obs`` (Observations) cover the object (:func:`tracks_cover`) and its
    lumped masses are uneven (:func:`lumped_spread`: a cloth's or a volume's, not a rope's), the ground's
    friction and restitution when they reach the ground (:func:`ground_contact`), and compliant contact's κ
    and ζ instead of the restitution when they sink into it (:func:`sinks_into_ground`)."""
    return list(default_reasons(cfg, obs))


def default_reasons(cfg: SceneConfig, obs: Any = None) -> dict[str, str]:
    """:func:`default_params` with why each is searched (name → reason). Tracks that sink deeper than
    their noise allows (:func:`sink_threshold`) into the ground add compliant contact (:data:`COMPLIANT`,
    starting from :func:`contact_start`) in place of the restitution, which compliant contact does not use."""
    out: dict[str, str] = {}
    for o in cfg.objects:
        for name, why in WHY.get(o.model, ()):
            if name not in out and GLOBAL[name].where(cfg.model_copy(deep=True)):
                out[name] = why
    reach = tracks_cover(cfg, obs) if obs is not None and obs.tracks else None
    spread = lumped_spread(cfg) if reach is not None else 1.0
    if reach is not None and spread > 1.0 + 1e-6:
        for name in MASS:
            if GLOBAL[name].where(cfg.model_copy(deep=True)):
                out[name] = (
                    f"{GLOBAL[name].why} (the tracks cover the object: every particle within "
                    f"{reach:.0%} of its size of one; the lumped masses differ up to {spread:.3g}×)"
                )
    gap = ground_contact(cfg, obs)
    if gap is not None:
        for name in CONTACT:
            out[name] = f"the observations reach the ground (lowest track {gap * 1e3:.3g} mm above it)"
    depth = sinks_into_ground(cfg, obs)
    if depth is not None:
        out.pop("ground_restitution", None)
        assert cfg.ground is not None  # sinks_into_ground found it
        given = cfg.ground.stiffness
        start = (
            f"from the scene's κ = {given:.3g} 1/s²"
            if given is not None
            else f"starting at κ = g/d = {contact_start(cfg, obs):.3g} 1/s², which rests that deep"
        )
        sink = (
            f"the tracks sink {depth * 1e3:.3g} mm into the ground (beyond "
            f"{sink_threshold(obs) * 1e3:.3g} mm of noise)"
        )
        out["ground_stiffness"] = f"{sink}: compliant contact, {start}"
        out["ground_damping_ratio"] = f"{sink}: compliant contact's damping ratio (the rebound), from ζ = 1"
    return out


def auto_per_element(cfg: SceneConfig, obs: Observations) -> str | None:
    """``per_element="auto"``: the per-element parameter of the scene's first object's model
    (:data:`PER_ELEMENT_OF`), or None for image observations (per-element fits need tracks)."""
    if obs is not None and getattr(obs, "images", None) is not None:
        return None
    return PER_ELEMENT_OF.get(cfg.objects[0].model) if cfg.objects else None


def _critical_damping(scene: Scene) -> float | None:
    """2·√(k·m) [N s/m] of a typical spring (median k, median free particle mass), or None."""
    m = scene.model
    if m.spring_count == 0:
        return None
    k = float(np.median(m.spring_stiffness.numpy()))
    mass = m.particle_mass.numpy()[m.particle_inv_mass.numpy() > 0]
    if mass.size == 0 or k <= 0:
        return None
    return 2.0 * math.sqrt(k * float(np.median(mass)))


def widen_bounds(bounds: list[Any], scene: Scene) -> None:
    """Physically scaled bounds, set in place: a dashpot γ spans 10⁻⁴ … 1 × the critical damping
    2√(k m) of a typical spring of ``scene`` (built at the nominal values; a placeholder γ of 0 would
    otherwise leave a box around 10⁻⁵ N s/m), and a damping rate of 0 its knob's physical range."""
    for b in bounds:
        if b.name == "damping":
            gc = _critical_damping(scene)
            if gc is None:
                continue
            if (b.scene_value or 0.0) > 0:  # a value of the scene's own: widen the box around it
                b.lo, b.hi = min(b.lo, 1e-4 * gc), max(b.hi, gc)
            else:  # a placeholder 0: the physical range alone
                b.lo, b.hi = 1e-4 * gc, gc
        elif b.name == "damping_rate" and not (b.scene_value or 0.0) > 0:
            b.lo, b.hi = b.param.physical_bounds()
        else:
            continue
        if not (b.scene_value or 0.0) > 0:
            b.nominal = math.sqrt(b.lo * b.hi)
        b.nominal = min(max(b.nominal, b.lo), b.hi)


@dataclass
class Bound:
    """A global parameter resolved for one scene: where the search starts (``nominal``), its bounds, the
    scene's own value (which may lie outside them: a damping rate of 0 starts the log-scale search at
    √(lo·hi)) and why it is searched."""

    param: GlobalParam
    nominal: float
    lo: float
    hi: float
    scene_value: float | None = None
    why: str = "named by --params"

    @property
    def name(self) -> str:
        return self.param.name


def resolve_globals(cfg: SceneConfig, names: list[str]) -> list[Bound]:
    """Check ``names`` against the scene and return their nominal values and bounds.

    Raises:
        FitError: an unknown name, or one the scene has no value for (with the names that exist).
    """
    out = []
    for name in names:
        p = GLOBAL.get(name)
        if p is None:
            raise FitError(
                f"--params: unknown parameter {name!r}; the global parameters are {', '.join(GLOBAL)}"
            )
        where = p.where(cfg)
        if not where:
            usable = [n for n, q in GLOBAL.items() if q.where(cfg.model_copy(deep=True))]
            raise FitError(
                f"--params: {name!r} ({p.doc}) does not exist in this scene; it has "
                f"{', '.join(usable) or 'none'}"
            )
        nominal = scene_value = float(getattr(*where[0]))
        lo, hi = p.box(nominal)
        if p.log and nominal <= 0:
            nominal = math.sqrt(lo * hi)
        out.append(Bound(p, min(max(nominal, lo), hi), lo, hi, scene_value))
    return out


def apply_globals(cfg: SceneConfig, values: dict[str, float]) -> SceneConfig:
    """A deep copy of the scene config with the global parameters set (``values``: name → value)."""
    cfg = cfg.model_copy(deep=True)
    for name, v in values.items():
        p = GLOBAL[name]
        for section, field in p.where(cfg):
            setattr(section, field, int(v) if p.integer else float(v))
    return cfg


def per_element_incidence(scene: Scene, name: str) -> np.ndarray:
    """The particles of each element of per-element parameter ``name``, int [n_elements, k] (springs: 2,
    tets: 4, constraints: their arity): which elements are neighbours for the smoothness term."""
    key = next(iter(per_element_arrays(scene, name)))
    parts = key.split(".")
    if parts[0] == "constraints":
        c = scene_constraints(scene)[int(parts[1])]
        return c.indices.numpy().reshape(c.count, -1)
    if parts[1].startswith("spring_"):
        return scene.model.spring_indices.numpy().reshape(-1, 2)
    if parts[1].startswith("bending_"):
        return scene.model.bending_indices.numpy().reshape(-1, 4)
    return scene.model.tet_indices.numpy().reshape(-1, 4)


def per_element_arrays(scene: Scene, name: str) -> dict[str, Any]:
    """The arrays of per-element parameter ``name`` in a built scene (``model.<array>`` /
    ``constraints.<i>.<array>`` → Warp array); raises FitError when unknown or absent."""
    if name in PER_ELEMENT:
        return PER_ELEMENT[name][0](scene)
    p = _element_parameter(name)
    if p is None:
        raise FitError(
            f"--per-element: unknown parameter {name!r}; choose one of {', '.join(PER_ELEMENT)} or a "
            f"per-element parameter of the registry ({', '.join(_element_parameters())})"
        )
    out = registry_arrays(scene, (name,))
    if not out:
        raise FitError(f"--per-element: this scene has no {p.per} holding {name!r} ({p.doc})")
    return out


def _element_parameters() -> list[str]:
    from ..diff import parameters as registry

    return [n for n, (p, _) in registry().items() if _element_parameter(n) is not None]


def _element_parameter(name: str) -> Parameter | None:
    """The registry declaration of ``name`` when it can be a per-element fit parameter: differentiable, a
    positive magnitude (log-scale factors) held per spring, tet, bending element or constraint."""
    from ..diff import parameters as registry

    entry = registry().get(name)
    if entry is None:
        return None
    p = entry[0]
    ok = (
        p.differentiable
        and p.log
        and p.bounds is not None
        and p.per in ("spring", "tet", "bending", "constraint")
    )
    return p if ok else None


__all__ = [
    "DEFAULTS",
    "GLOBAL",
    "MASS",
    "MASS_REACH",
    "PER_ELEMENT",
    "Bound",
    "FitError",
    "GlobalParam",
    "apply_globals",
    "default_params",
    "auto_per_element",
    "default_reasons",
    "ground_contact",
    "lumped_spread",
    "contact_start",
    "seed_contact",
    "sink_threshold",
    "sinks_into_ground",
    "track_noise",
    "widen_bounds",
    "per_element_arrays",
    "per_element_incidence",
    "registry_arrays",
    "resolve_globals",
    "tracks_cover",
]
