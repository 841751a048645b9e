"""FastMassSpring's fused CPU frame (``fused_frame``): one launch per frame gives the step-by-step frame
bit for bit, in the buffer ping-pong stepping ends in; setups it cannot run fall back (None) or raise
(True)."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl
from pliant.bench._drape_motion import reference_curve, solver_curve, trajectory_error
from pliant.bench._mass_spring import SYMPLECTIC_SUBSTEPS, cloth_drape_model


def _cloth(dtype: str, damping: float = 0.02, ground: bool = False) -> pl.Model:
    b = pl.ModelBuilder(gravity=(0.0, -9.81, 0.0))
    b.add_cloth_grid(nx=7, ny=5, size=0.5, mass=0.2, youngs_modulus_thickness=400.0, damping=damping,
                     origin=(-0.25, 0.0, -0.25), plane="xz", pin="top-corners")  # fmt: skip
    if ground:
        b.add_ground(height=-0.3)
    model = b.finalize(device="cpu", dtype=dtype)
    rng = np.random.default_rng(5)
    model.particle_qd.assign(rng.normal(scale=0.3, size=(model.particle_count, 3)))
    return model


def _frames(model, solver, control, substeps: int, frames: int = 4, dt: float = 1e-3):
    """x, v after ``frames`` frames of FrameStep, and whether each frame ended in its input buffer."""
    frame = pl.solvers.FrameStep(solver, dt, substeps)
    s0, s1 = model.state(), model.state()
    ends_in_input = []
    for _ in range(frames):
        first = s0
        s0, s1 = frame(s0, control, s1)
        ends_in_input.append(s0 is first)
    return s0.particle_q.numpy(), s0.particle_qd.numpy(), ends_in_input


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("substeps", [1, 6, 7])
@pytest.mark.parametrize("damping", [0.0, 0.02])
def test_fused_frame_equals_step_by_step_bit_for_bit(dtype, substeps, damping):
    """Springs with and without dashpots, pinned corners, external forces, δ damping, odd and even substep
    counts: the same positions and velocities, bit for bit, in the same buffer."""
    model = _cloth(dtype, damping)
    control = model.control()
    rng = np.random.default_rng(7)
    control.particle_f.assign(rng.normal(scale=0.01, size=(model.particle_count, 3)))
    fused = pl.solvers.FastMassSpring(model, velocity_damping=0.9995)
    plain = pl.solvers.FastMassSpring(model, velocity_damping=0.9995, fused_frame=False)
    assert fused.fused_frame_blocker is None and fused.describe()["fused_frame"]
    assert plain.fused_frame_blocker == "fused_frame=False"
    xf, vf, ef = _frames(model, fused, control, substeps)
    xp, vp, ep = _frames(model, plain, control, substeps)
    assert np.abs(xf - model.particle_q.numpy()).max() > 1e-3  # it moved: a comparison of motion
    assert np.array_equal(xf, xp) and np.array_equal(vf, vp)
    assert ef == ep == [substeps % 2 == 0] * 4


def test_fused_frame_takes_refreshed_parameters():
    """Stiffness and damping written in place and refreshed: the fused frame packs them again."""
    model = _cloth("float64", damping=0.0)
    fused = pl.solvers.FastMassSpring(model)
    plain = pl.solvers.FastMassSpring(model, fused_frame=False)
    _frames(model, fused, None, 4, frames=1)  # records the launch with the old parameters
    model.spring_stiffness.assign(model.spring_stiffness.numpy() * 1.7)
    model.spring_damping.assign(np.full(model.spring_count, 0.01))
    for s in (fused, plain):
        assert s.refresh_parameters() is None
    xf, vf, _ = _frames(model, fused, None, 4)
    xp, vp, _ = _frames(model, plain, None, 4)
    assert np.array_equal(xf, xp) and np.array_equal(vf, vp)


@pytest.mark.parametrize("fused", [None, False])
def test_damping_rate_set_between_frames_acts(fused):
    """δ = exp(−cΔt) is baked into the recorded launches (fused and per step): a ``damping_rate`` set between
    frames acts from the next frame, as on a solver whose recorded launches were dropped (``refresh``)."""
    out = []
    for refresh in (False, True):
        model = _cloth("float32")
        sim = pl.Simulator(model, pl.solvers.FastMassSpring(model, fused_frame=fused, damping_rate=0.5),
                           substeps=8, graph=False)  # fmt: skip
        for _ in range(3):
            sim.step_frame()
        sim.solver.damping_rate = 30.0
        if refresh:
            sim.solver.refresh_parameters()
        for _ in range(3):
            sim.step_frame()
        out.append(sim.state_0.particle_q.numpy())
    assert out[0].tobytes() == out[1].tobytes()


def test_fused_frame_falls_back_or_refuses_with_the_reason():
    model = _cloth("float32", ground=True)
    handlers = [pl.collision.Colliders()]
    auto = pl.solvers.FastMassSpring(model, collisions=handlers)
    assert auto.fused_frame_blocker == "contact handlers follow each step"
    assert not auto.step_frame(model.state(), model.state(), None, 1e-3, 4)
    with pytest.raises(ValueError, match="fused_frame=True.*contact handlers"):
        pl.solvers.FastMassSpring(model, collisions=handlers, fused_frame=True)
    with pytest.raises(ValueError, match="fused_frame=True.*method='implicit'"):
        pl.solvers.FastMassSpring(_cloth("float32"), method="implicit", fused_frame=True)


@pytest.mark.parametrize("max_force", [0.05, float("inf")])
def test_fused_frame_with_the_drag_handle(max_force):
    """The drag handle's force, at each substep's start position (capped or not), inside the frame: bit for
    bit, and the target moved between frames (a live session's cursor) is followed."""
    model = _cloth("float64")
    control = model.control()
    out = []
    for fused in (None, False):
        solver = pl.solvers.FastMassSpring(model, fused_frame=fused)
        frame = pl.solvers.FrameStep(solver, 1e-3, 7)
        s0, s1 = model.state(), model.state()
        for f in range(6):
            control.set_drag(3, (0.05 * f, 0.2, 0.0), 5.0, max_force=max_force)
            s0, s1 = frame(s0, control, s1)
        out.append((s0.particle_q.numpy().copy(), s0.particle_qd.numpy().copy()))
    assert np.array_equal(out[0][0], out[1][0]) and np.array_equal(out[0][1], out[1][1])
    free = _frames(model, pl.solvers.FastMassSpring(model), None, 7, frames=6)[0]
    assert out[0][0][3, 1] - free[3, 1] > 1e-3  # pulled up towards y = 0.2


def test_fused_drape_keeps_its_trajectory_error():
    """The 64² drape row's setting (80 substeps): the fused fall is the step-by-step fall, sag curve bit for
    bit, within 0.1 % of the converged float64 reference (0.04 % measured)."""
    n = 64
    model = cloth_drape_model(n)
    sub = SYMPLECTIC_SUBSTEPS[n]
    fused = solver_curve(model, pl.solvers.FastMassSpring(model), substeps=sub)
    plain = solver_curve(model, pl.solvers.FastMassSpring(model, fused_frame=False), substeps=sub)
    assert np.array_equal(fused, plain)
    assert trajectory_error(fused, reference_curve(n)) < 1e-3


@pytest.mark.parametrize("graph", [True, False])
def test_simulator_frames_fused_and_replayed_equal_step_by_step(graph):
    """The Simulator steps through FrameStep: the fused frame, captured as a CPU graph and replayed or
    launched directly, gives the step-by-step frames bit for bit."""
    xs = []
    for fused in (None, False):
        model = _cloth("float32")
        sim = pl.Simulator(
            model, pl.solvers.FastMassSpring(model, fused_frame=fused), substeps=8, graph=graph
        )
        sim.run(5, progress=False)
        xs.append(sim.state_0.particle_q.numpy())
        assert (sim.graph_reason is None) == graph
    assert np.array_equal(xs[0], xs[1])


def _set_particle_f(sim: pl.Simulator, replace: bool) -> None:
    """A constant push on every particle: written in place, or as a new array (a new address)."""
    f = np.tile([0.0, 0.5, 0.1], (sim.model.particle_count, 1)).astype(np.float32)
    if replace:
        sim.control.particle_f = wp.array(f, dtype=wp.vec3, device="cpu")
    else:
        sim.control.particle_f.assign(f)


def _refresh(sim: pl.Simulator, name: str, scale: float) -> None:
    """A model array written in place, then the solver's ``refresh_parameters``."""
    a = getattr(sim.model, name)
    a.assign(a.numpy() * scale)
    assert sim.solver.refresh_parameters() is None


#: Each public setter a fit uses, one change per entry.
CHANGES = {
    "damping_rate": lambda s: setattr(s.solver, "damping_rate", 3.0),
    "velocity_damping_factor": lambda s: setattr(s.solver, "velocity_damping_factor", 0.2),
    "stiffness": lambda s: _refresh(s, "spring_stiffness", 1.3),
    "rest_length": lambda s: _refresh(s, "spring_rest_length", 0.98),
    "spring_damping": lambda s: _refresh(s, "spring_damping", 0.0),
    "particle_f_in_place": lambda s: _set_particle_f(s, replace=False),
    "particle_f_replaced": lambda s: _set_particle_f(s, replace=True),
}


def test_simulator_launches_a_fused_frame_without_a_graph():
    """graph=None: a frame that is one fused launch runs directly (no capture, no per-frame fingerprint),
    and a change through each public setter a fit uses acts from the next frame as it does on a simulator
    launching every frame (graph=False) and on the unfused solver's replayed graph, bit for bit."""
    sims = []
    for fused, graph in ((None, None), (None, False), (False, None)):
        model = _cloth("float32")
        solver = pl.solvers.FastMassSpring(model, fused_frame=fused, damping_rate=0.5)
        sims.append(pl.Simulator(model, solver, substeps=8, graph=graph))
    one, _, unfused = sims
    assert one.solver.frame_is_one_launch() and not unfused.solver.frame_is_one_launch()

    def frames(n: int = 3) -> list[bytes]:
        for s in sims:
            for _ in range(n):
                s.step_frame()
        return [
            s.state_0.particle_q.numpy().tobytes() + s.state_0.particle_qd.numpy().tobytes() for s in sims
        ]

    xs = frames()
    assert xs[0] == xs[1] == xs[2]
    for name, change in CHANGES.items():
        for s in sims:
            change(s)
        xs = frames()
        assert xs[0] == xs[1] == xs[2], name
    assert one.graph_reason is not None and "one fused launch" in one.graph_reason
    assert one._graphs is not None and one._graphs.captures == one._graphs.replays == 0
    assert unfused.graph_reason is None and unfused._graphs is not None and unfused._graphs.replays > 0
