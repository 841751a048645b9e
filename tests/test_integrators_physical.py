"""Integrators on the physical path (Warp arrays, float64 models, ForceSolver)."""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl
from tests.helpers import (
    SYSTEM_INTEGRATORS,
    axial_spring_model,
    free_mass_spring_body,
    fresh,
    integrator_id,
    oscillator_energy,
    run_steps,
)

I = pl.integrators


def _oscillator_solver(integ, **kw):
    model = axial_spring_model(**kw)
    return model, pl.solvers.ForceSolver(model, energies=[pl.energies.Springs()], integrator=integ)


@pytest.mark.parametrize(
    ("integ", "power"), [(I.ForwardEuler(), 1), (I.BackwardEuler(newton_tol=1e-12), -1)], ids=["FE", "BE"]
)
def test_energy_factor_physical(integ, power):
    """On a pinned spring, forward/backward Euler multiply/divide the energy by exactly 1 + ω²h² per step."""
    k, m, rest, h = 4.0, 0.5, 1.0, 0.05
    model, solver = _oscillator_solver(integ, k=k, m=m, rest=rest, offset=0.1)
    energies = []
    run_steps(
        solver, model, h, 20, callback=lambda n, s: energies.append(oscillator_energy(s, k=k, m=m, rest=rest))
    )
    e = np.array([oscillator_energy(model.state(), k=k, m=m, rest=rest), *energies])
    np.testing.assert_allclose(e[1:] / e[:-1], (1.0 + k / m * h * h) ** power, rtol=1e-12, atol=0)


def test_implicit_midpoint_conserves_energy_physical():
    """Implicit midpoint on the pinned spring keeps the energy to 1e-12 even at ωh = 2."""
    k, m, rest = 4.0, 1.0, 1.0
    model, solver = _oscillator_solver(I.ImplicitMidpoint(newton_tol=1e-12), k=k, m=m, rest=rest, offset=0.1)
    e0 = oscillator_energy(model.state(), k=k, m=m, rest=rest)
    s = run_steps(solver, model, 1.0, 30)
    assert abs(oscillator_energy(s, k=k, m=m, rest=rest) / e0 - 1.0) < 1e-12


PHYSICAL_ORDER = SYSTEM_INTEGRATORS


@pytest.mark.parametrize("integ", PHYSICAL_ORDER, ids=integrator_id)
def test_order_physical(integ):
    """On a 2-particle spring (Warp, float64) the error at T = 2 shrinks like dt**order (±0.15)."""
    t_end, amp = 2.0, 0.1
    out = []
    for k in range(2, 8):
        dt = 2.0**-k
        model, solver = _oscillator_solver(fresh(integ), offset=amp)
        s = run_steps(solver, model, dt, int(round(t_end / dt)))
        u = s.particle_q.numpy()[1, 0] - 1.0
        v = s.particle_qd.numpy()[1, 0]
        err = max(abs(u - amp * np.cos(t_end)), abs(v + amp * np.sin(t_end)))
        if err < 1e-11:
            break
        out.append((dt, err))
    d = np.array(out[-4:])
    slope = np.polyfit(np.log(d[:, 0]), np.log(d[:, 1]), 1)[0]
    assert abs(slope - integ.order) <= 0.15, (
        f"{integ.name}: measured order {slope:.3f}, declared {integ.order}"
    )


def test_rk2_heun_identical_physical():
    """RK2(alpha=0.5, beta=0.5, a=0, b=1) reproduces Heun bit for bit on a damped mass-spring body."""
    model, state = free_mass_spring_body()
    outs = []
    for integ in (I.RK2(alpha=0.5, beta=0.5, a=0.0, b=1.0), I.Heun()):
        solver = pl.solvers.ForceSolver(
            model, energies=pl.energies.mass_spring(gravity=False), integrator=integ
        )
        s = model.state()
        s.assign(state)
        s = run_steps(solver, model, 1e-3, 20, state=s)
        outs.append((s.particle_q.numpy().copy(), s.particle_qd.numpy().copy()))
    assert np.array_equal(outs[0][0], outs[1][0]) and np.array_equal(outs[0][1], outs[1][1])


def _momentum(model, s):
    return (model.particle_mass_np[:, None] * s.particle_qd.numpy()).sum(axis=0)


@pytest.mark.parametrize("integ", SYSTEM_INTEGRATORS, ids=integrator_id)
def test_momentum_conserved(integ):
    """With no external force, springs + dashpots keep the total momentum to 1e-10 (relative) for 40 steps."""
    model, state = free_mass_spring_body()
    solver = pl.solvers.ForceSolver(
        model, energies=pl.energies.mass_spring(gravity=False), integrator=fresh(integ), contact=False
    )
    p0 = _momentum(model, state)
    scale = float(np.sum(model.particle_mass_np * np.linalg.norm(state.particle_qd.numpy(), axis=1)))
    s = run_steps(solver, model, 5e-3, 40, state=state)
    dp = np.abs(_momentum(model, s) - p0).max() / scale
    assert dp < 1e-10, f"{integ.name}: momentum changed by {dp:.3g} (relative)"
    assert np.isfinite(s.particle_q.numpy()).all()


STIFF_EXPLICIT = [i for i in SYSTEM_INTEGRATORS if i.explicit]


def _stiff_sim(integ):
    # k/m = 1e8 (ω = 1e4 rad/s), Δt = 1/60: ωΔt ≈ 167, far beyond every explicit stability limit.
    model = axial_spring_model(k=1e8, m=1.0, rest=1.0, offset=0.01)
    solver = pl.solvers.ForceSolver(model, energies=[pl.energies.Springs()], integrator=integ)
    return model, pl.Simulator(model, solver, frame_dt=1.0 / 60.0, substeps=1)


def test_stiff_spring_backward_euler_bounded():
    """Backward Euler on a k/m = 1e8 spring at Δt = 1/60 stays bounded and loses energy every frame."""
    model, sim = _stiff_sim(I.BackwardEuler(newton_tol=1e-9))
    e0 = e_prev = oscillator_energy(sim.state_0, k=1e8, m=1.0, rest=1.0)
    for _ in range(30):
        sim.step_frame()
        sim.check()
        e = oscillator_energy(sim.state_0, k=1e8, m=1.0, rest=1.0)
        assert e <= max(e_prev, 1e-20 * e0) * (1 + 1e-9), f"energy rose {e_prev:.3g} -> {e:.3g} J"
        e_prev = e
    assert np.abs(sim.state_0.particle_q.numpy()[1, 0] - 1.0) <= 0.01


@pytest.mark.parametrize("integ", STIFF_EXPLICIT, ids=integrator_id)
def test_stiff_spring_explicit_diverges(integ):
    """Explicit integrators blow up on the stiff spring; the Simulator raises DivergenceError with advice."""
    _, sim = _stiff_sim(fresh(integ))
    with pytest.raises(pl.DivergenceError) as info:
        sim.run(frames=200, progress=False)
    msg = str(info.value)
    assert "frame" in msg and ("speed" in msg or "non-finite" in msg), msg
    assert "implicit" in msg and "dt" in msg, msg
    assert info.value.frame < 200


def test_integrator_study_quick(tmp_path):
    """The quick study writes its figures, table and JSON; implicit methods are stable at 1/60 s."""
    import json

    from pliant.studies import run_integrator_study

    result = run_integrator_study(tmp_path, quick=True)
    for name in (
        "oscillator_phase.png",
        "oscillator_energy.png",
        "oscillator_error.png",
        "cloth_stability.png",
    ):
        assert (tmp_path / name).stat().st_size > 1000, name
    assert json.loads((tmp_path / "integrators.json").read_text()) == json.loads(json.dumps(result))
    assert "| BackwardEuler |" in (tmp_path / "integrators.md").read_text()
    rows = result["cloth"]["rows"]
    for name in ("BackwardEuler", "ImplicitMidpoint", "BDF2"):
        assert rows[name]["stable"] and rows[name]["substeps"] == 1
    assert rows["SymplecticEuler"]["substeps"] > 1
    assert not rows["ForwardEuler"]["stable"]
    osc = result["oscillator"]
    assert set(osc["stability_unbounded"]) == {"BackwardEuler", "ImplicitMidpoint", "BDF2"}
    for name, o in osc["orders"].items():
        assert abs(o["order"] - o["declared"]) <= 0.15, (name, o["order"])


@pytest.mark.slow
def test_integrator_study_full(tmp_path):
    """The full study runs (16×16 cloth, 1 s) and RK4's measured stable Δt exceeds symplectic Euler's."""
    from pliant.studies import run_integrator_study

    result = run_integrator_study(tmp_path, quick=False)
    rows = result["cloth"]["rows"]
    assert rows["RK4"]["max_stable_dt_s"] > rows["SymplecticEuler"]["max_stable_dt_s"]
