"""Shared test helpers: the integrator registry, small float64 models, the energy finite-difference check."""

from __future__ import annotations

import copy

import numpy as np
import warp as wp

import pliant as pl

I = pl.integrators


def _default_instance(cls: type[pl.integrators.Integrator]) -> pl.integrators.Integrator:
    """An instance to test: implicit ones converged to 1e-12 so that their order shows."""
    return cls() if cls.explicit else cls(newton_tol=1e-12)


#: One instance of every registered integrator (``pl.integrators.ALL_INTEGRATORS``, so a new one is
#: tested without editing this list), plus Ralston's RK2 as a second point of the two-stage family.
ALL_INTEGRATORS: list[pl.integrators.Integrator] = [
    *(_default_instance(c) for c in I.ALL_INTEGRATORS),
    I.RK2(alpha=0.25, beta=0.75, a=0.0, b=2.0 / 3.0),  # Ralston
]

#: Those that also step physical models (DormandPrince is ODE-only).
SYSTEM_INTEGRATORS = [i for i in ALL_INTEGRATORS if getattr(i, "supports_system", True)]


def _oscillator_errors(integ, t_end=8.0, ks=range(2, 10), floor=1e-11):
    """(dt, error) on x'' = −x, x(0)=1, v(0)=0, refining until the error reaches ``floor`` (round-off)."""
    osc = I.harmonic_oscillator()
    out = []
    for k in ks:
        dt = 2.0**-k
        sol = integ.solve(osc, (1.0, 0.0), t_end, dt)
        err = max(abs(sol.x[-1, 0] - np.cos(t_end)), abs(sol.v[-1, 0] + np.sin(t_end)))
        if err < floor:
            break
        out.append((dt, err))
    return np.array(out)


def check_ode_order(integ: pl.integrators.Integrator) -> float:
    """Assert that the global error at T = 8 on the oscillator shrinks like dt**order (±0.15 over the last
    4 refinements above round-off); returns the measured order."""
    d = _oscillator_errors(integ)
    assert d.shape[0] >= 3, f"{integ.name}: too few points above round-off: {d}"
    d = d[-4:]
    slope = float(np.polyfit(np.log(d[:, 0]), np.log(d[:, 1]), 1)[0])
    assert abs(slope - integ.order) <= 0.15, (
        f"{integ.name}: measured order {slope:.3f}, declared {integ.order}"
    )
    return slope


def integrator_id(integ: pl.integrators.Integrator) -> str:
    """Readable pytest id (RK2 gets its coefficients)."""
    if type(integ) is I.RK2:
        return f"RK2({integ.alpha:g},{integ.beta:g},{integ.b_:.3g})"
    return integ.name


def fresh(integ: pl.integrators.Integrator) -> pl.integrators.Integrator:
    """An independent copy (multistep history and work buffers not shared between tests)."""
    return copy.deepcopy(integ)


def axial_spring_model(
    *,
    k: float = 1.0,
    m: float = 1.0,
    rest: float = 1.0,
    offset: float = 0.1,
    damping: float = 0.0,
    dtype: str = "float64",
) -> pl.Model:
    """Particle 0 pinned at the origin, particle 1 at (rest + offset, 0, 0) on a spring, no gravity.

    The motion stays on the x axis, where the spring is linear in u = x₁ − rest: an exact harmonic
    oscillator with ω² = k/m and energy ½mv² + ½ku².
    """
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles([[0.0, 0.0, 0.0], [rest + offset, 0.0, 0.0]], mass=m)
    b.pin([0])
    b.add_springs([[0, 1]], stiffness=k, damping=damping, rest_length=rest)
    return b.finalize(device="cpu", dtype=dtype)


def run_steps(solver, model, dt: float, steps: int, state=None, callback=None):
    """Ping-pong ``steps`` solver steps of ``dt`` from ``state`` (default the model's); returns the state."""
    s0 = model.state() if state is None else state
    s1 = model.state()
    for n in range(steps):
        solver.step(s0, s1, None, dt)
        s0, s1 = s1, s0
        if callback is not None:
            callback(n, s0)
    return s0


def oscillator_energy(state, *, k: float, m: float, rest: float) -> float:
    """½mv² + ½k(|x₁ − x₀| − rest)² of :func:`axial_spring_model` [J]."""
    x = state.particle_q.numpy().astype(np.float64)
    v = state.particle_qd.numpy().astype(np.float64)
    u = np.linalg.norm(x[1] - x[0]) - rest
    return 0.5 * m * float(v[1] @ v[1]) + 0.5 * k * u * u


def free_mass_spring_body(*, dtype: str = "float64", seed: int = 0) -> tuple[pl.Model, pl.State]:
    """A 4×4 free cloth (springs, dashpots; no gravity, pins or ground), randomly deformed and moving."""
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_cloth_grid(nx=4, ny=4, size=1.0, mass=0.5, stiffness=50.0, damping=0.5, pin="none")
    model = b.finalize(device="cpu", dtype=dtype)
    rng = np.random.default_rng(seed)
    state = model.state()
    x = model.particle_q.numpy() + 0.05 * rng.standard_normal((model.particle_count, 3))
    v = rng.standard_normal((model.particle_count, 3))
    state.particle_q.assign(x)
    state.particle_qd.assign(v)
    return model, state


def energy_fd_check(model, energy, x, *, eps=1e-6, project=False, begin=None):
    """(∇E, central differences of E, ∇²E, central differences of ∇E) of ``energy`` at x, dense, float64.

    ``begin``: arguments of ``energy.begin_step`` (x, v, dt) for dissipative terms; ``project``: the
    Hessian projected to PSD per element (off for a finite-difference comparison); ``eps`` [m]: the step.
    """
    n = model.particle_count
    if begin is not None:
        energy.begin_step(model, *begin)

    def val(xx):
        out = wp.zeros(1, dtype=wp.float64, device=model.device)
        energy.value(model, wp.array(xx, dtype=wp.vec3d, device=model.device), out)
        return out.numpy()[0]

    def grad(xx):
        out = wp.zeros(n, dtype=wp.vec3d, device=model.device)
        energy.gradient(model, wp.array(xx, dtype=wp.vec3d, device=model.device), out)
        return out.numpy().ravel()

    rows, cols = energy.hessian_pattern(model)
    vals = wp.zeros(len(rows), dtype=wp.mat33d, device=model.device)
    slots = wp.array(np.arange(len(rows), dtype=np.int32), dtype=wp.int32, device=model.device)
    energy.hessian(model, wp.array(x, dtype=wp.vec3d, device=model.device), slots, vals, project_psd=project)
    H = np.zeros((3 * n, 3 * n))
    for r, c, b in zip(rows, cols, vals.numpy(), strict=True):
        H[3 * r : 3 * r + 3, 3 * c : 3 * c + 3] += b
    g = grad(x)
    g_fd = np.zeros(3 * n)
    H_fd = np.zeros((3 * n, 3 * n))
    flat = x.ravel()
    for k in range(3 * n):
        e = np.zeros(3 * n)
        e[k] = eps
        xp, xm = (flat + e).reshape(-1, 3), (flat - e).reshape(-1, 3)
        g_fd[k] = (val(xp) - val(xm)) / (2 * eps)
        H_fd[:, k] = (grad(xp) - grad(xm)) / (2 * eps)
    return g, g_fd, H, H_fd


#: A tiny float64 rope scene for the fitting tests (7 particles, 10 frames).
FIT_ROPE = """
[scene]
name = "tiny_rope"
frame_dt = 0.04
substeps = 10
frames = 10
dtype = "float64"
device = "cpu"
[[objects]]
kind = "rope"
n_segments = 6
length = 0.3
origin = [0.0, 0.5, 0.0]
direction = [1.0, 0.0, 0.0]
mass = 0.05
pin = "first"
[objects.material]
stiffness = 50.0
[solver]
integrator = "SymplecticEuler"
damping_rate = 0.5
"""
