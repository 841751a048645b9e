"""The integrator study: the lecture's oscillator and a pinned mass-spring cloth under every integrator.

(a) Oscillator m x'' = −k x (ω = 1), the lecture's system, on the ODE path (float64): phase portraits and
    energy against time, the global error against Δt with the fitted order, and the largest stable ωΔt,
    found by bisection on the growth of the energy over many steps.
(b) A cloth pinned at its two top corners (springs + gravity, no dashpots, so that every energy change is
    the integrator's) through ``ForceSolver``: the largest stable Δt (fewest substeps per 1/60 s frame that
    run without the Simulator's divergence detection firing), the wall time per simulated second at that
    Δt, and the energy drift over the run.

``run_integrator_study(out_dir, quick=False)`` writes PNG figures, ``integrators.md`` and
``integrators.json`` into ``out_dir`` and returns the JSON dict.
"""

from __future__ import annotations

import json
import math
import os
import platform
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import integrators as I  # noqa: N812

if TYPE_CHECKING:
    from ..model import Model, State
    from ..solvers import ForceSolver

#: Row order of the study's tables (a registered integrator not named here follows, by name).
_TABLE_ORDER = (
    "ForwardEuler",
    "Heun",
    "Midpoint",
    "RK4",
    "SymplecticEuler",
    "VelocityVerlet",
    "BackwardEuler",
    "ImplicitMidpoint",
    "BDF2",
    "DormandPrince",
)


def _table_key(cls: type) -> tuple[int, str]:
    name = cls.__name__
    return (_TABLE_ORDER.index(name) if name in _TABLE_ORDER else len(_TABLE_ORDER), name)


#: Integrators of the oscillator study: every registered one (pl.integrators.ALL_INTEGRATORS), so a new
#: integrator joins the study, except RK2, whose default coefficients are Heun's (a duplicate row).
OSCILLATOR_INTEGRATORS = tuple(sorted((c for c in I.ALL_INTEGRATORS if c is not I.RK2), key=_table_key))

#: Integrators of the cloth study: those that step physical models (DormandPrince is ODE-only).
CLOTH_INTEGRATORS = tuple(c for c in OSCILLATOR_INTEGRATORS if getattr(c, "supports_system", True))


def _make(cls: type) -> I.Integrator:
    return cls()


# ------------------------------------------------------------------------------------------- oscillator
def _oscillator_energy(sol: I.Solution) -> np.ndarray:
    return 0.5 * sol.v[:, 0] ** 2 + 0.5 * sol.x[:, 0] ** 2


def oscillator_orders(
    integrator: I.Integrator, *, t_end: float = 8.0, ks: range = range(2, 11), floor: float = 1e-11
) -> dict[str, Any]:
    """Global error at ``t_end`` of x'' = −x, x(0) = 1, v(0) = 0 for Δt = 2^-k, and the fitted order.

    Refinement stops when the error falls below ``floor`` (round-off), as diffrax's order tests do; the
    order is the least-squares slope of log error against log Δt over the last four points.
    """
    osc = I.harmonic_oscillator()
    dts, errs = [], []
    for k in ks:
        dt = 2.0**-k
        sol = integrator.solve(osc, (1.0, 0.0), t_end, dt)
        err = max(abs(sol.x[-1, 0] - math.cos(t_end)), abs(sol.v[-1, 0] + math.sin(t_end)))
        if err < floor:
            break
        dts.append(dt)
        errs.append(float(err))
    d, e = np.array(dts[-4:]), np.array(errs[-4:])
    order = float(np.polyfit(np.log(d), np.log(e), 1)[0]) if d.size >= 2 else float("nan")
    return {"dt": dts, "error": errs, "order": order}


def _energy_grows(integrator: I.Integrator, omega_dt: float, steps: int) -> bool:
    """Whether the oscillator's energy grows over ``steps`` steps of ωΔt (last 10% vs first half, by 1e-3)."""
    osc = I.harmonic_oscillator()
    integrator.reset()
    y = np.array([0.0, 1.0])
    e = np.empty(steps + 1)
    e[0] = 0.5
    with np.errstate(over="ignore", invalid="ignore"):
        for n in range(steps):
            y = integrator.step_ode(osc, n * omega_dt, omega_dt, y)
            e[n + 1] = 0.5 * (y[0] ** 2 + y[1] ** 2)
            if not np.isfinite(e[n + 1]) or e[n + 1] > 1e6:
                return True
    # Bounded oscillations (symplectic methods) sample their peaks alike in both windows to ~1e-5 when the
    # first window holds half the run; a growth of 1e-3 over the run is exponential growth.
    w = max(steps // 10, 1)
    return bool(e[-w:].max() > e[: steps // 2 + 1].max() * (1.0 + 1e-3))


def oscillator_stability_limit(
    integrator: I.Integrator,
    *,
    lo: float = 0.1,
    hi: float = 20.0,
    steps: int = 2000,
    iterations: int = 40,
) -> float:
    """Largest stable ωΔt on the undamped oscillator, by bisection on energy growth over ``steps`` steps.

    Returns 0.0 when the energy grows already at ωΔt = ``lo`` (no stable step: forward Euler, Heun) and
    ``inf`` when it does not grow at ``hi`` (A-stable implicit methods).
    """
    if _energy_grows(integrator, lo, steps):
        return 0.0
    if not _energy_grows(integrator, hi, steps):
        return math.inf
    a, b = lo, hi
    for _ in range(iterations):
        mid = 0.5 * (a + b)
        if _energy_grows(integrator, mid, steps):
            b = mid
        else:
            a = mid
        if b - a < 1e-9:
            break
    return a


def _oscillator_part(out: Path, quick: bool) -> dict[str, Any]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    osc = I.harmonic_oscillator()
    h, t_end = 0.2, 20.0
    runs = {}
    for cls in OSCILLATOR_INTEGRATORS:
        integ = _make(cls)
        runs[integ.name] = integ.solve(osc, (1.0, 0.0), t_end, h)

    cols = 5
    rows = math.ceil(len(runs) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 3.2 * rows), squeeze=False)
    circle = np.linspace(0, 2 * np.pi, 200)
    for ax, (name, sol) in zip(axes.ravel(), runs.items(), strict=False):
        ax.plot(np.cos(circle), -np.sin(circle), "k:", lw=0.8, label="exact")
        ax.plot(sol.x[:, 0], sol.v[:, 0], lw=1.0)
        ax.set_title(name, fontsize=9)
        lim = min(3.0, max(1.2, float(np.nanmax(np.abs(sol.y))) * 1.05))
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_aspect("equal")
        ax.set_xlabel("x")
        ax.set_ylabel("v")
    for ax in axes.ravel()[len(runs) :]:
        ax.axis("off")
    fig.suptitle(f"Phase portraits, x'' = -x, ωΔt = {h}, t ≤ {t_end:g}")
    fig.tight_layout()
    fig.savefig(out / "oscillator_phase.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(8, 5))
    for name, sol in runs.items():
        ax.semilogy(sol.t, _oscillator_energy(sol) / 0.5, label=name, lw=1.0)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("E / E₀")
    ax.set_title(f"Energy, undamped oscillator, ωΔt = {h}")
    ax.legend(fontsize=8, ncol=2)
    fig.tight_layout()
    fig.savefig(out / "oscillator_energy.png", dpi=110)
    plt.close(fig)

    orders = {}
    fig, ax = plt.subplots(figsize=(7, 5))
    for cls in OSCILLATOR_INTEGRATORS:
        integ = _make(cls)
        r = oscillator_orders(integ, ks=range(2, 9) if quick else range(2, 11))
        orders[integ.name] = {"declared": integ.order, **r}
        ax.loglog(r["dt"], r["error"], "o-", ms=3, label=f"{integ.name} ({r['order']:.2f})")
    ax.set_xlabel("Δt [s]")
    ax.set_ylabel("|error| at t = 8")
    ax.set_title("Global error vs Δt (fitted order)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "oscillator_error.png", dpi=110)
    plt.close(fig)

    limits = {}
    for cls in OSCILLATOR_INTEGRATORS:
        integ = _make(cls)
        lim = oscillator_stability_limit(integ, steps=600 if quick else 2000, iterations=20 if quick else 40)
        limits[integ.name] = lim
    return {
        "problem": "m x'' = -k x, m = k = 1 (the lecture's oscillator), x0 = 1, v0 = 0, float64 ODE path",
        "phase_dt": h,
        "orders": orders,
        "stability_omega_dt": {k: (None if math.isinf(v) else v) for k, v in limits.items()},
        "stability_unbounded": [k for k, v in limits.items() if math.isinf(v)],
    }


# ------------------------------------------------------------------------------------------- cloth
#: Total mass × g × size of the study cloth [J]: the energy scale of the divergence test and the drift.
ENERGY_SCALE_J = 0.2 * 9.81 * 1.0


def _cloth_model(n: int, stiffness: float, dtype: str) -> Model:
    from ..model import ModelBuilder

    b = ModelBuilder()
    b.add_cloth_grid(nx=n, ny=n, size=1.0, mass=0.2, stiffness=stiffness, damping=0.0, pin="top-corners")
    return b.finalize(device="cpu", dtype=dtype)


def _total_energy(solver: ForceSolver, state: State) -> float:
    return float(sum(solver.energy(state).values()))


def _cloth_run(
    model: Model, integ: I.Integrator, substeps: int, frames: int, *, measure: bool = False
) -> dict:
    """Run ``frames`` frames of 1/60 s with ``substeps`` substeps; raises DivergenceError if it blows up."""
    from ..energies import Gravity, Springs
    from ..sim import DivergenceError, Simulator
    from ..solvers import ForceSolver

    solver = ForceSolver(model, energies=[Springs(), Gravity()], integrator=integ, contact=False)
    sim = Simulator(model, solver, frame_dt=1.0 / 60.0, substeps=substeps)
    e0 = _total_energy(solver, sim.state_0)
    iters: list[int] = []
    wall = 0.0
    for _ in range(frames):
        t0 = time.perf_counter()
        sim.step_frame()
        sim.check()
        wall += time.perf_counter() - t0
        st = getattr(solver, "last_stats", None)
        if st is not None:
            iters.append(st.iterations)
        if not measure:
            # A slow instability that has not yet reached the Simulator's speed bound still creates energy:
            # more than M g L out of nothing counts as divergence too.
            e = _total_energy(solver, sim.state_0)
            if e - e0 > ENERGY_SCALE_J:
                raise DivergenceError(sim.frame, "energy gain (J)", e - e0, "lower dt")
    out: dict[str, float | None] = {"wall_s": wall, "simulated_s": frames / 60.0}
    if measure:
        e1 = _total_energy(solver, sim.state_0)
        out.update(
            energy_start_J=e0,
            energy_end_J=e1,
            energy_drift_J=e1 - e0,
            lowest_y_m=float(sim.state_0.particle_q.numpy()[:, 1].min()),
            newton_iterations_mean=float(np.mean(iters)) if iters else None,
        )
    return out


def cloth_stability(
    integrator_cls: type,
    *,
    n: int = 16,
    stiffness: float = 1e3,
    frames: int = 60,
    max_substeps: int = 512,
    dtype: str = "float64",
) -> dict[str, Any]:
    """Fewest substeps per 1/60 s frame at which the pinned cloth runs ``frames`` frames without divergence.

    Doubling search then bisection on the substep count (stability is assumed monotone in Δt). A trial fails
    when the Simulator's divergence detection fires or the total energy rises by more than M g L (a slow
    instability). Then one timed run at that Δt (after a warm-up frame, so kernel compilation is not
    counted; energies are evaluated only at the end) gives the wall time per simulated second and the
    energy drift [J] over ``frames`` frames.
    """
    from ..sim import DivergenceError

    model = _cloth_model(n, stiffness, dtype)

    def stable(s: int) -> bool:
        try:
            _cloth_run(model, integrator_cls(), s, frames)
            return True
        except DivergenceError:
            return False

    _warmup(model, integrator_cls)
    lo, hi = 0, 1  # unstable at lo (0 = unknown), stable at hi
    while not stable(hi):
        lo, hi = hi, hi * 2
        if hi > max_substeps:
            return {"stable": False, "max_substeps_tried": max_substeps}
    while hi - lo > 1 and lo > 0:
        mid = (lo + hi) // 2
        if stable(mid):
            hi = mid
        else:
            lo = mid
    res = _cloth_run(model, integrator_cls(), hi, frames, measure=True)
    return {
        "stable": True,
        "substeps": hi,
        "max_stable_dt_s": 1.0 / 60.0 / hi,
        "bounded_by_frame": hi == 1,
        "wall_s_per_simulated_s": res["wall_s"] / res["simulated_s"],
        **{k: v for k, v in res.items() if k not in ("wall_s", "simulated_s")},
    }


def _warmup(model: Model, integrator_cls: type) -> None:
    """Compile the kernels once (one frame, one substep), ignoring a blow-up."""
    from ..sim import DivergenceError

    try:
        _cloth_run(model, integrator_cls(), 1, 1)
    except DivergenceError:
        pass


# ------------------------------------------------------------------------------------------- report
def _fmt(v: Any, spec: str = ".3g") -> str:
    if v is None:
        return "—"
    if isinstance(v, float) and math.isinf(v):
        return "∞"
    return format(v, spec) if isinstance(v, (int, float)) else str(v)


def _markdown(result: dict) -> str:
    osc = result["oscillator"]
    lines = [
        "# Integrator study",
        "",
        f"Machine: {result['machine']['summary']}. Quick mode: {result['quick']}.",
        "",
        "## Oscillator (ODE path, float64, ω = 1)",
        "",
        "| integrator | declared order | measured order | largest stable ωΔt |",
        "|---|---|---|---|",
    ]
    for name, o in osc["orders"].items():
        lim = osc["stability_omega_dt"][name]
        lim_s = "unbounded" if name in osc["stability_unbounded"] else ("none" if lim == 0 else f"{lim:.4g}")
        lines.append(f"| {name} | {o['declared']} | {o['order']:.3f} | {lim_s} |")
    c = result["cloth"]
    lines += [
        "",
        f"## Cloth ({c['scene']})",
        "",
        "| integrator | substeps / frame | largest stable Δt [s] | wall s per simulated s | energy drift [J] "
        "| lowest y [m] | Newton its / step |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, r in c["rows"].items():
        if not r.get("stable"):
            lines.append(f"| {name} | > {r.get('max_substeps_tried')} | unstable | — | — | — | — |")
            continue
        dt_s = (
            f"≥ {r['max_stable_dt_s']:.4g} (frame)"
            if r["bounded_by_frame"]
            else f"{r['max_stable_dt_s']:.4g}"
        )
        lines.append(
            f"| {name} | {r['substeps']} | {dt_s} | {r['wall_s_per_simulated_s']:.3g} | "
            f"{r['energy_drift_J']:+.3g} | {r['lowest_y_m']:.4f} | "
            f"{_fmt(r['newton_iterations_mean'], '.2f')} |"
        )
    lines += [
        "",
        f"Energy scale: total mass × g × cloth size = {c['energy_scale_J']:.3g} J. A trial fails when the "
        "Simulator's divergence detection fires or the energy rises by more than this scale. Implicit "
        "integrators are only tried up to the frame step (1/60 s). Heun and the explicit midpoint rule "
        "have |R(iωΔt)| > 1 for every Δt: without damping they are never stable, and their row only says "
        "where the growth stays below the energy scale within the run. Implicit midpoint is A-stable on "
        "linear problems but gains energy with stiff nonlinear springs at large steps; backward Euler and "
        "BDF2 dissipate it.",
        "",
    ]
    return "\n".join(lines)


def _machine() -> dict[str, Any]:
    import warp as wp

    cpu = platform.processor() or platform.machine()
    return {
        "summary": f"{platform.system()} {cpu}, {os.cpu_count()} CPU cores, Warp {wp.__version__} on cpu",
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
    }


def run_integrator_study(out_dir: str | os.PathLike, quick: bool = False) -> dict:
    """Run the integrator study; write PNGs, ``integrators.md`` and ``integrators.json`` into ``out_dir``.

    Args:
        out_dir: output folder (created).
        quick: a reduced version (coarser sweeps, an 8×8 cloth over 1/6 s, at most 32 substeps) that
            finishes in well under a minute, for smoke tests.

    Returns:
        The dict written to ``integrators.json``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    result: dict[str, Any] = {"quick": bool(quick), "machine": _machine()}
    result["oscillator"] = _oscillator_part(out, quick)

    n, frames = (8, 10) if quick else (16, 60)
    stiffness = 1e3
    rows = {}
    for cls in CLOTH_INTEGRATORS:
        rows[cls.__name__] = cloth_stability(
            cls, n=n, stiffness=stiffness, frames=frames, max_substeps=32 if quick else 512
        )
    result["cloth"] = {
        "scene": f"{n}×{n} cells, 1 m, 0.2 kg, springs k = {stiffness:g} N/m, gravity, pinned top corners, "
        f"no dashpots, float64, {frames} frames of 1/60 s",
        "energy_scale_J": ENERGY_SCALE_J,
        "rows": rows,
    }

    names = [k for k, r in rows.items() if r.get("stable")]
    if names:
        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
        axes[0].bar(names, [rows[k]["max_stable_dt_s"] for k in names])
        axes[0].set_yscale("log")
        axes[0].set_ylabel("largest stable Δt [s]")
        axes[1].bar(names, [rows[k]["wall_s_per_simulated_s"] for k in names])
        axes[1].set_yscale("log")
        axes[1].set_ylabel("wall s per simulated s")
        for ax in axes:
            ax.tick_params(axis="x", rotation=60, labelsize=8)
        fig.suptitle("Pinned cloth: stability and cost at the largest stable Δt")
        fig.tight_layout()
        fig.savefig(out / "cloth_stability.png", dpi=110)
        plt.close(fig)

    result["wall_s"] = time.perf_counter() - t_start
    result["figures"] = sorted(p.name for p in out.glob("*.png"))
    (out / "integrators.md").write_text(_markdown(result), encoding="utf-8")
    (out / "integrators.json").write_text(json.dumps(result, indent=2), encoding="utf-8")
    return result
