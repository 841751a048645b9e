"""Identifiability of the fitted global parameters (issue 38, item 4): which ones the data constrain, and
which trade against each other, from the training loss's curvature at the optimum.

The curvature is a central finite-difference Hessian of the open-loop training loss in the search's own
coordinates: CMA-ES's unit box, log-scaled for magnitudes (``Knob.to_unit``), so that one unit is the whole
search box whatever the parameter's scale. All ``1 + 2d²`` points of the stencil (the centre, ±h on each axis,
the four corners of each pair) are evaluated at once, as copies of the object in one simulation where the
problem allows it (:func:`pliant.fit._cmaes.evaluate_batch`). CMA-ES's own covariance is not used: it is the
search's step distribution, shrunk by its step-size rule and shaped by the population, not the loss's
curvature, and it says nothing where the search stopped on its generation cap.

From the Hessian H (unit box) and the loss L₀ at the optimum, the parameters' joint "1σ" region is where the
quadratic model rises by at most :data:`RISE` · L₀: the covariance C = 2 ΔL · H⁻¹ with ΔL = RISE · L₀. A
direction along which a whole unit of the box raises the loss by less than ΔL (an eigenvalue of H below
2 ΔL, or below :data:`FLAT` of the largest, which is the finite differences' noise) is flat: it gets the
whole box as its band. A parameter is *constrained* when its band (the others re-adjusting: √C_ii) is
narrower than :data:`CONSTRAINED` of the box; two parameters *trade against each other* when
|C_ij| / √(C_ii C_jj) > :data:`TRADE`. Where H has a direction along which the loss falls by more than ΔL
per unit and more steeply than :data:`NEGATIVE` of the strongest upward curvature, the point is no minimum
at the step's scale (a rugged loss) and nothing is said.

A parameter within a step of its bound is differentiated one step inside it (the stencil's centre moves;
``Knob.from_unit`` clamps), where the loss may still fall towards the bound: then the point is no minimum of
the unconstrained loss, and its Hessian says so, although it is the optimum in the box. Such a parameter is
treated as bound-constrained optimisation does: its one-sided slope ∂L/∂u at the bound (the three stencil
points on its axis, exact on a quadratic) is measured, and where the loss falls towards the bound by more
than ΔL per unit of the box, the data push it beyond the search box: it is reported *at its bound*, held
there, and the curvature analysis above runs on the remaining free parameters only (the reduced Hessian, a
second stencil centred with the bound ones at their bound). On MuJoCo's own-mass cloth
(tests/data/foreign/mujoco_cloth_own) the dashpot γ ends at its upper bound (the critical damping of a
typical spring) with the loss falling towards it at 0.020 per unit of the box (90 ΔL); the whole Hessian one
step inside had eigenvalues −0.68, −0.31, 0.33, 1.40 (no minimum: nothing was said), while the reduced one
of E·t, the damping rate and α with γ at its bound has 0.71, 1.03, 2.64: all three constrained. A gentler
slope is flat there (the parameter stays free); a reduced Hessian that is itself no minimum leaves the free
ones not measured. The gate (:mod:`pliant.fit._gate`) puts no parameter at a bound back (its
``constrained`` is None): the data pull at it, so it is not one they leave free.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from ._params import Bound
    from ._problem import Problem

#: Finite-difference step in the unit box (2 % of the search box: ×1.1 on a log-scaled ×/÷ 10 box). Smaller
#: steps resolve sharper minima but let the solver's round-off into the differences of flat directions.
STEP = 0.02
#: The loss rise, as a fraction of the loss at the optimum, that defines a parameter's band.
RISE = 0.1
#: A parameter whose band (unit box, the others re-adjusting) is narrower than this is constrained: ±10 % of
#: the box is ×/÷ 1.6 on a log-scaled ×/÷ 10 box.
CONSTRAINED = 0.1
#: |correlation| above which two parameters are said to trade against each other.
TRADE = 0.9
#: Eigenvalues of H below this fraction of the largest are the finite differences' noise: flat.
FLAT = 1e-6
#: Negative eigenvalues weaker than this fraction of the largest are noise (flat); stronger ones (and beyond
#: 2ΔL) mean the point is no minimum at the step's scale. On Newton's thrown box (tests/data/foreign) the
#: fitted values' Hessian had −0.13 against 14.7 (0.9 %); on MuJoCo's folding cloth all three were negative.
NEGATIVE = 0.1


def stencil(u0: np.ndarray, h: float = STEP) -> tuple[np.ndarray, np.ndarray]:
    """The points of the central-difference Hessian stencil around ``u0`` (unit box), and its centre.

    The centre is ``u0`` moved at least ``h`` inside the box (a value at a bound is differentiated beside
    it, since ``Knob.from_unit`` clamps).

    Args:
        u0: The point [d] in the unit box.
        h: The step (unit box).

    Returns:
        (points [1 + 2d + 4·d(d−1)/2, d]: the centre, +h and −h on each axis in turn, then for each pair
        i < j the corners (+,+), (+,−), (−,+), (−,−); the centre [d]).
    """
    d = u0.size
    c = np.clip(np.asarray(u0, dtype=np.float64), h, 1.0 - h)
    eye = h * np.eye(d)
    axes = np.stack([c + eye, c - eye], axis=1).reshape(2 * d, d)  # +e0, −e0, +e1, −e1, ...
    i, j = np.triu_indices(d, 1)
    signs = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], dtype=np.float64)
    unit = np.eye(d)
    corners = c + h * (signs[None, :, :1] * unit[i][:, None] + signs[None, :, 1:] * unit[j][:, None])
    return np.concatenate([c[None], axes, corners.reshape(-1, d)]), c


def hessian(f: np.ndarray, d: int, h: float = STEP) -> np.ndarray:
    """The Hessian [d, d] from the losses ``f`` at :func:`stencil`'s points (in its order)."""
    f0, ax = f[0], f[1 : 1 + 2 * d].reshape(d, 2)
    H = np.diag((ax[:, 0] - 2.0 * f0 + ax[:, 1]) / h**2)
    i, j = np.triu_indices(d, 1)
    cor = f[1 + 2 * d :].reshape(i.size, 4)
    off = (cor[:, 0] - cor[:, 1] - cor[:, 2] + cor[:, 3]) / (4.0 * h**2)
    H[i, j] = H[j, i] = off
    return H


def summarise(
    H: np.ndarray, loss: float, bounds: list[Bound], values: dict[str, float], rise: float = RISE
) -> dict[str, Any]:
    """The identifiability report of Hessian ``H`` (unit box) at the optimum ``values`` with loss ``loss``
    (see the module docstring).

    Args:
        H: The training loss's Hessian [d, d] in the unit box (log-scaled where the parameter is).
        loss: The training loss at the optimum (the band is where it rises by ``rise`` · loss).
        bounds: The d parameters' bounds (``Problem.globals``, in H's order).
        values: The fitted values (name → value).
        rise: The loss rise (fraction) that defines the bands.

    Returns:
        ``{"params": {name: {"sigma_unit", "sigma_alone_unit", "band": [lo, hi], "relative", "constrained"}},
        "trade": [{"params": [a, b], "correlation": c}], "correlation": [[...]], "loss", "rise"}``:
        ``sigma_unit`` the 1σ band's half-width in the unit box with the others re-adjusting,
        ``sigma_alone_unit`` with the others held, ``band`` the values 1σ either side (clamped to the search
        box), ``relative`` its half-width relative to the value (the factor − 1 on a log scale; None at 0).
        ``minimum`` False where H has a direction of negative curvature beyond 2ΔL and :data:`NEGATIVE` of
        its largest eigenvalue (the point is no minimum at the step's scale): then ``constrained`` is None
        and ``trade`` empty.
    """
    d = len(bounds)
    dl = rise * max(float(loss), 1e-300)
    Hs = 0.5 * (H + H.T)
    w, V = np.linalg.eigh(Hs)
    # a direction along which a unit of the box lowers the loss by more than ΔL, and more steeply than
    # NEGATIVE of the strongest upward curvature: not a minimum at the step's scale (a rugged loss, e.g. a
    # cloth that folds, whose loss changes by 20 % with a dashpot of 2e-5 N s/m; or a search stopped
    # early), and no band can be read from it. Weaker negative curvature is the differences' noise (CMA-ES
    # stops within 0.1 % of the loss, not on the minimum): flat.
    minimum = bool(w.min(initial=0.0) >= -max(2.0 * dl, NEGATIVE * float(w.max(initial=0.0))))
    floor = max(2.0 * dl, FLAT * max(float(w.max(initial=0.0)), 0.0))
    w = np.where(w > floor, w, 2.0 * dl)  # flat: the whole box (unit) raises the loss by ΔL
    C = (V * (2.0 * dl / w)) @ V.T
    sigma = np.sqrt(np.clip(np.diag(C), 0.0, None))
    diag = np.diag(Hs)
    alone = np.where(diag > 2.0 * dl, np.sqrt(2.0 * dl / np.where(diag > 0, diag, 1.0)), 1.0)
    corr = C / np.outer(np.maximum(sigma, 1e-300), np.maximum(sigma, 1e-300))
    params: dict[str, Any] = {}
    for k, b in enumerate(bounds):
        v = float(values[b.name])
        s = float(sigma[k])
        rel: float | None  # None: no relative width about a value of 0
        if b.param.log:
            factor = math.exp(s * math.log(b.hi / b.lo))
            band, rel = [max(v / factor, b.lo), min(v * factor, b.hi)], factor - 1.0
        else:
            half = s * (b.hi - b.lo)
            band, rel = [max(v - half, b.lo), min(v + half, b.hi)], (half / abs(v) if v else None)
        params[b.name] = {
            "sigma_unit": s,
            "sigma_alone_unit": float(alone[k]),
            "band": band,
            "relative": rel,
            "constrained": bool(s < CONSTRAINED) if minimum else None,
        }
    i, j = np.triu_indices(d, 1)
    pick = np.abs(corr[i, j]) > TRADE
    trade = [
        {"params": [bounds[a].name, bounds[b].name], "correlation": float(corr[a, b])}
        for a, b in zip(i[pick], j[pick], strict=True)
    ]
    return {
        "minimum": minimum,
        "params": params,
        "trade": trade if minimum else [],
        "correlation": corr.tolist(),
        "loss": float(loss),
        "rise": rise,
    }


def identify(
    problem: Problem,
    values: dict[str, float],
    frames: int,
    losses: Callable[[list[dict[str, float]]], list[float]] | None = None,
    h: float = STEP,
) -> dict[str, Any]:
    """The identifiability report (:func:`summarise`) of ``problem``'s global parameters at ``values``: the
    open-loop training loss over frames 1 … ``frames`` − 1 differentiated twice on :func:`stencil`.

    Whole-number and topology parameters (a neighbour count, a spring radius: the loss is piecewise
    constant in them) are left out. A parameter the data push against its bound (:func:`bound_slopes`) is
    held there and reported as such; the others are then differentiated again with it at its bound
    (module docstring).

    Args:
        problem: The fitting problem.
        values: The fitted global values (name → value).
        frames: The frames the global stage trained on (its validation frames excluded).
        losses: The training losses of a list of candidates (None: open-loop runs of ``frames`` frames,
            batched as copies of the object where the problem allows).
        h: The finite-difference step in the unit box.

    Returns:
        :func:`summarise`'s report with ``method``, ``frames`` [1, frames], ``evaluations``, ``left_out``
        (the whole-number parameters) and ``hessian``; or ``{"skipped": why}`` when a point of a stencil
        diverged. With parameters at a bound, also ``at_bound`` and ``free`` (their names; ``correlation``
        and ``reduced_hessian`` are the free ones'), and each bound one's entry in ``params`` is
        ``{"at_bound": "lower" | "upper", "slope_unit", "value", "constrained": None}`` (the one-sided
        ∂L/∂u at the bound, per unit box; the bound's value).
    """
    # piecewise constant in whole numbers and topology (a spring appears when the radius passes a distance)
    bounds = [b for b in problem.globals if not (b.param.integer or b.param.topology)]
    left_out = [b.name for b in problem.globals if b.param.integer or b.param.topology]
    if not bounds:
        return {"skipped": "no continuous global parameter", "left_out": left_out}
    run = losses or _open_loop(problem, frames)
    u0 = np.array([b.param.to_unit(min(max(values[b.name], b.lo), b.hi), b.lo, b.hi) for b in bounds])
    pts, centre = stencil(u0, h)
    f = _losses(run, values, bounds, pts)
    if f is None:
        return {"skipped": "a value within the finite-difference step diverged", "left_out": left_out}
    H = hessian(f, len(bounds), h)
    side, slope = bound_slopes(f, u0, h)
    dl = RISE * max(float(f[0]), 1e-300)
    pushed = side * slope < -dl  # the loss falls towards the bound by more than ΔL per unit of the box
    evaluations = len(pts)
    if not pushed.any():
        rep = summarise(H, float(f[0]), bounds, values)
    else:
        free = np.flatnonzero(~pushed)
        centre = np.where(pushed, (side > 0).astype(np.float64), centre)
        if free.size:
            sub, _ = stencil(centre[free], h)
            pts = np.repeat(centre[None], len(sub), axis=0)
            pts[:, free] = sub
        else:
            pts = centre[None]
        f2 = _losses(run, values, bounds, pts)
        if f2 is None:
            return {"skipped": "a value within the finite-difference step diverged", "left_out": left_out}
        evaluations += len(pts)
        H2 = hessian(f2, free.size, h)
        rep = _with_bounds(H2, float(f2[0]), bounds, values, free, side, slope)
    moved = {b.name: float(b.param.from_unit(centre[k], b.lo, b.hi)) for k, b in enumerate(bounds)}
    rep.update(
        method=f"central finite differences of the open-loop training loss, step {h:g} of the unit box",
        frames=[1, int(frames)],
        evaluations=evaluations,
        left_out=left_out,
        hessian=H.tolist(),
    )
    if pushed.any():
        rep["method"] += "; the parameters pushed against a bound held there (one-sided slope at the bound)"
        rep["reduced_hessian"] = H2.tolist()
    if not np.allclose(centre, u0):  # at a bound: differentiated beside it
        rep["centre"] = moved
    return rep


def bound_slopes(f: np.ndarray, u0: np.ndarray, h: float = STEP) -> tuple[np.ndarray, np.ndarray]:
    """The one-sided slopes ∂L/∂u at the bound of the parameters within a step of one, from the losses
    ``f`` at :func:`stencil`'s points about ``u0`` (whose centre is one step inside: the three points on
    the parameter's axis reach the bound; second order, exact on a quadratic).

    Args:
        f: The losses at the stencil's points (its order).
        u0: The point [d] in the unit box.
        h: The step (unit box).

    Returns:
        (side [d]: +1 within a step of the upper bound, −1 of the lower, 0 neither; the slope [d] per unit
        box at that bound, 0 where neither). The loss falls towards the bound where side · slope < 0.
    """
    d = u0.size
    f0, ax = f[0], f[1 : 1 + 2 * d].reshape(d, 2)  # [:, 0] at +h, [:, 1] at −h
    side = np.where(u0 >= 1.0 - h, 1.0, np.where(u0 <= h, -1.0, 0.0))
    upper = (3.0 * ax[:, 0] - 4.0 * f0 + ax[:, 1]) / (2.0 * h)  # at c + h = 1
    lower = -(3.0 * ax[:, 1] - 4.0 * f0 + ax[:, 0]) / (2.0 * h)  # at c − h = 0
    return side, np.where(side > 0, upper, np.where(side < 0, lower, 0.0))


def _losses(
    run: Callable[[list[dict[str, float]]], list[float]],
    values: dict[str, float],
    bounds: list[Bound],
    pts: np.ndarray,
) -> np.ndarray | None:
    """The losses of the points ``pts`` [n, d] (unit box) of ``bounds``, the other values as ``values``;
    None when one diverged."""
    from ._cmaes import PENALTY

    cands = [
        {**values, **{b.name: b.param.from_unit(u[k], b.lo, b.hi) for k, b in enumerate(bounds)}} for u in pts
    ]
    f = np.asarray(run(cands), dtype=np.float64)
    return f if np.all(np.isfinite(f) & (f < PENALTY)) else None


def _with_bounds(
    H: np.ndarray,
    loss: float,
    bounds: list[Bound],
    values: dict[str, float],
    free: np.ndarray,
    side: np.ndarray,
    slope: np.ndarray,
) -> dict[str, Any]:
    """:func:`summarise` of the free parameters (reduced Hessian ``H``, ``loss`` with the others at their
    bound), the bound ones' entries put in ``bounds``' order."""
    fb = [bounds[k] for k in free]
    if fb:
        rep = summarise(H, loss, fb, values)
    else:
        rep = {"minimum": True, "params": {}, "trade": [], "correlation": [], "loss": loss, "rise": RISE}
    params: dict[str, Any] = {}
    for k, b in enumerate(bounds):
        if b.name in rep["params"]:
            params[b.name] = rep["params"][b.name]
        else:
            params[b.name] = {
                "at_bound": "upper" if side[k] > 0 else "lower",
                "slope_unit": float(slope[k]),
                "value": b.hi if side[k] > 0 else b.lo,
                "constrained": None,  # the box, not the data, holds it (the gate puts nothing back)
                "hint": _widen(b),
            }
    rep["params"] = params
    rep["at_bound"] = [b.name for k, b in enumerate(bounds) if k not in set(free.tolist())]
    rep["free"] = [b.name for b in fb]
    return rep


def _open_loop(problem: Problem, frames: int) -> Callable[[list[dict[str, float]]], list[float]]:
    """Open-loop training losses over frames 1 … ``frames`` − 1 of candidates, batched where allowed."""
    from ._cmaes import evaluate, evaluate_batch

    def run(cands: list[dict[str, float]]) -> list[float]:
        n, window = problem.n_train, problem.shooting
        problem.n_train, problem.shooting = frames, 0
        try:
            from ._cmaes import batchable

            if batchable(problem):
                return evaluate_batch(problem, cands)
            return [evaluate(problem, v) for v in cands]
        finally:
            problem.n_train, problem.shooting = n, window

    return run


def _widen(b: Bound) -> str:
    """How to search beyond bound ``b`` (``pliant fit`` has no bounds option: the box is the knob's policy
    around the scene's value, or its physical range; pliant/scene/_knobs.py)."""
    if b.param.search is None:
        return f"the box is its physical range {b.lo:g} .. {b.hi:g}: the model cannot go further"
    return (
        f"to search beyond it, --set its scene field ({b.param.field}) nearer the bound: the box is "
        "around the scene's value"
    )


def describe(rep: dict[str, Any]) -> list[str]:
    """The CLI's lines for an identifiability report (one per parameter, one per trading pair)."""
    if "skipped" in rep:
        return [f"identifiability: not measured ({rep['skipped']})"]
    at_bound = rep.get("at_bound", [])
    no_minimum = (
        "not measured: the training loss is no minimum at the finite-difference step (rugged, or the search "
        "stopped early)"
    )
    if not rep["minimum"] and not at_bound:
        return [f"identifiability: {no_minimum}"]
    lines = [f"identifiability (1 sigma for a {100 * rep['rise']:g} % rise of the training loss):"]
    for name in at_bound:
        p = rep["params"][name]
        lines.append(
            f"  {name}: at its {p['at_bound']} bound ({p['value']:.4g}): the data push it beyond the search "
            f"box (one-sided slope dL/du {p['slope_unit']:+.3g} per unit of the box); {p['hint']}"
        )
    if not rep["minimum"]:
        held = ", ".join(at_bound)
        lines.append(f"  {', '.join(rep['free'])}: not measured: with {held} at the bound, {no_minimum[14:]}")
        return lines + _left_out(rep)
    for name, p in rep["params"].items():
        if name in at_bound:
            continue
        lo, hi = sorted(p["band"])  # a value put back to 0 lies below a log box: its band reaches down to it
        what = "constrained by the data" if p["constrained"] else "NOT constrained by the data"
        lines.append(f"  {name}: {what}, {lo:.4g} .. {hi:.4g}")
    for t in rep["trade"]:
        a, b = t["params"]
        lines.append(f"  {a} and {b} trade against each other (correlation {t['correlation']:+.2f})")
    return lines + _left_out(rep)


def _left_out(rep: dict[str, Any]) -> list[str]:
    """The lines of the parameters identifiability leaves out."""
    return [
        f"  {name}: not measured (a whole number or the springs' topology)"
        for name in rep.get("left_out", [])
    ]


__all__ = [
    "CONSTRAINED",
    "RISE",
    "STEP",
    "TRADE",
    "bound_slopes",
    "describe",
    "hessian",
    "identify",
    "stencil",
    "summarise",
]
