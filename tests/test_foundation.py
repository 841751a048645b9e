"""Foundations: builder validation, trajectory/checkpoint files, resume, free fall, oscillator, divergence."""

from __future__ import annotations

import math

import numpy as np
import pytest

import pliant as pl
from pliant.io import load_checkpoint, save_checkpoint


# ------------------------------------------------------------------------------------------ builder
def _two_particles() -> pl.ModelBuilder:
    b = pl.ModelBuilder()
    b.add_particles([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], 1.0)
    return b


@pytest.mark.parametrize(
    ("mass", "message"),
    [
        (0.0, "zero or negative mass"),
        (-1.0, "zero or negative mass"),
        (float("nan"), "mass contains NaN/inf"),
    ],
    ids=["zero", "negative", "nan"],
)
def test_builder_rejects_bad_mass(mass, message):
    """Zero, negative and NaN particle masses each raise a ValueError that says what is wrong."""
    with pytest.raises(ValueError, match=message):
        pl.ModelBuilder().add_particles([[0.0, 0.0, 0.0]], mass)


def test_builder_rejects_nan_positions():
    """NaN positions raise a ValueError naming how many particles are affected."""
    with pytest.raises(ValueError, match=r"1 particle positions are NaN/inf"):
        pl.ModelBuilder().add_particles([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0]], 1.0)


def test_builder_rejects_out_of_range_indices():
    """A spring naming a particle that does not exist raises 'out of range'."""
    with pytest.raises(ValueError, match=r"out of range \[0, 2\)"):
        _two_particles().add_springs([[0, 5]], stiffness=1.0)


def test_builder_rejects_duplicate_springs():
    """Two springs on the same pair (in either order) are rejected at finalize."""
    b = _two_particles()
    b.add_springs([[0, 1], [1, 0]], stiffness=1.0)
    with pytest.raises(ValueError, match=r"1 duplicate springs \(first between particles \[0, 1\]\)"):
        b.finalize(device="cpu")


def test_builder_rejects_degenerate_triangle():
    """A triangle with collinear vertices raises 'degenerate (zero area'."""
    b = pl.ModelBuilder()
    b.add_particles([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]], 1.0)
    with pytest.raises(ValueError, match=r"1 triangles are degenerate \(zero area"):
        b.add_triangles([[0, 1, 2]])


def _tet_builder() -> pl.ModelBuilder:
    b = pl.ModelBuilder()
    b.add_particles([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]], 1.0)
    return b


def test_builder_rejects_inverted_tet():
    """A negatively oriented tetrahedron raises 'inverted' and suggests fix_orientation."""
    with pytest.raises(ValueError, match=r"inverted \(negative volume.*fix_orientation=True"):
        _tet_builder().add_tetrahedra([[0, 2, 1, 3]], E=1e5, nu=0.3)


def test_builder_rejects_degenerate_tet():
    """A flat tetrahedron (four coplanar vertices) raises 'degenerate (zero volume'."""
    with pytest.raises(ValueError, match=r"degenerate \(zero volume"):
        _tet_builder().add_tetrahedra([[0, 1, 2, 4]], E=1e5, nu=0.3)


# ------------------------------------------------------------------------------------------ files
def test_trajectory_npz_round_trip(tmp_path):
    """Every field of a Trajectory survives save/load exactly (loaded without pickle)."""
    rng = np.random.default_rng(0)
    traj = pl.Trajectory(
        x=rng.normal(size=(5, 7, 3)),
        t=np.linspace(0.0, 0.4, 5),
        v=rng.normal(size=(5, 7, 3)),
        faces=np.array([[0, 1, 2], [2, 3, 4]], np.int32),
        tets=np.array([[0, 1, 2, 3]], np.int32),
        meta={"scene": "test", "dt": 0.1, "objects": [{"name": "a"}]},
    )
    back = pl.Trajectory.load(traj.save(tmp_path / "t.npz"))
    for k in ("x", "t", "v", "faces", "tets"):
        np.testing.assert_array_equal(getattr(back, k), getattr(traj, k), err_msg=k)
    assert back.meta == traj.meta


def test_trajectory_frame_dt_is_stored_as_frame_dt_and_read_from_older_files_dt():
    """A Simulator's trajectory stores the frame duration as ``meta["frame_dt"]`` (``dt`` is a solver step
    everywhere, issue 26); ``Trajectory.frame_dt`` also reads the ``dt`` key of files written before."""
    b = pl.ModelBuilder()
    b.add_particles(np.zeros((1, 3)), mass=1.0)
    model = b.finalize(device="cpu")
    solver = pl.solvers.ForceSolver(model, [], pl.integrators.SymplecticEuler())
    traj = pl.Simulator(model, solver, frame_dt=0.04, substeps=4).run(2, progress=False)
    assert traj.meta["frame_dt"] == 0.04 and "dt" not in traj.meta
    assert traj.frame_dt == 0.04
    old = pl.Trajectory(x=np.zeros((2, 1, 3)), t=np.array([0.0, 0.1]), meta={"dt": 0.1})
    assert old.frame_dt == 0.1
    assert pl.Trajectory(x=np.zeros((1, 1, 3)), t=np.zeros(1)).frame_dt is None


def test_checkpoint_round_trip(tmp_path):
    """A checkpoint returns frame, time, state, parameters and the trajectory so far bit for bit."""
    rng = np.random.default_rng(1)
    data = dict(
        frame=7,
        time=0.7,
        x=rng.normal(size=(4, 3)),
        v=rng.normal(size=(4, 3)),
        params={"spring_stiffness": rng.random(3)},
        traj_x=rng.normal(size=(8, 4, 3)),
        traj_t=np.arange(8) * 0.1,
        traj_v=None,
        meta={"dt": 0.1},
    )
    ck = load_checkpoint(save_checkpoint(tmp_path / "c.ckpt.npz", **data))
    assert (ck["frame"], ck["time"], ck["meta"]) == (7, 0.7, {"dt": 0.1})
    for k in ("x", "v", "traj_x", "traj_t"):
        np.testing.assert_array_equal(ck[k], data[k], err_msg=k)
    np.testing.assert_array_equal(ck["params"]["spring_stiffness"], data["params"]["spring_stiffness"])
    assert ck["traj_v"] is None


# ------------------------------------------------------------------------------------------ resume
def _rope_sim() -> pl.Simulator:
    b = pl.ModelBuilder()
    b.add_rope(n_segments=8, length=0.4, mass=0.05, stiffness=400.0, damping=0.01, start=(0.0, 0.5, 0.0))
    b.add_ground()
    model = b.finalize(device="cpu", dtype="float64")
    solver = pl.solvers.ForceSolver(model, pl.energies.mass_spring(), pl.integrators.SymplecticEuler())
    return pl.Simulator(model, solver, frame_dt=1 / 60, substeps=8)


def test_resume_after_interrupt_equals_uninterrupted_run(tmp_path):
    """Ctrl-C at frame 7, then resuming in a new Simulator, reproduces every frame bit for bit (CPU, f64)."""
    frames, stop = 20, 7
    reference = _rope_sim().run(frames, progress=False)

    def interrupt(sim: pl.Simulator) -> None:
        if sim.frame == stop:
            raise KeyboardInterrupt

    ckpt = tmp_path / "rope.ckpt.npz"
    with pytest.raises(KeyboardInterrupt):
        _rope_sim().run(frames, progress=False, checkpoint=ckpt, checkpoint_every=5, on_frame=interrupt)
    assert load_checkpoint(ckpt)["frame"] == stop
    resumed = _rope_sim().run(frames, progress=False, checkpoint=ckpt, resume=True)
    assert resumed.x.shape == reference.x.shape == (frames + 1, 9, 3)
    np.testing.assert_array_equal(resumed.t, reference.t)
    mismatch = [k for k in range(frames + 1) if not np.array_equal(resumed.x[k], reference.x[k])]
    assert not mismatch, f"frames differing after resume: {mismatch}"


# ------------------------------------------------------------------------------------------ physics
def test_free_fall_matches_discrete_closed_form():
    """Symplectic Euler free fall: x_n = x0 + v0 t_n + ½ g t_n² + ½ g Δt t_n to 1e-9 relative (f64)."""
    g = np.array([0.0, -9.81, 0.0])
    x0 = np.array([[0.1, 2.0, -0.2], [0.0, 1.0, 0.3]])
    v0 = np.array([[1.0, 2.0, 0.5], [-0.5, 0.0, 0.0]])
    b = pl.ModelBuilder(gravity=g)
    b.add_particles(x0, [0.5, 2.0], velocities=v0)
    model = b.finalize(device="cpu", dtype="float64")
    solver = pl.solvers.ForceSolver(model, [pl.energies.Gravity()], pl.integrators.SymplecticEuler())
    dt_frame, substeps = 0.02, 5
    traj = pl.Simulator(model, solver, frame_dt=dt_frame, substeps=substeps).run(25, progress=False)
    h = dt_frame / substeps  # the integrator's Δt
    t = np.arange(26)[:, None, None] * dt_frame
    exact = x0 + v0 * t + 0.5 * g * t**2 + 0.5 * g * h * t
    err = np.max(np.abs(traj.x - exact) / np.maximum(np.abs(exact), 1.0))
    assert err < 1e-9, f"max relative error {err:.3g} (expected < 1e-9)"


def test_spring_oscillator_period():
    """A mass on a spring to a pinned anchor oscillates with period 2π√(m/k) within 1 %."""
    m, k, rest, amp = 0.25, 100.0, 0.5, 0.05
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles([[0.0, 0.0, 0.0], [rest + amp, 0.0, 0.0]], [1.0, m])
    b.pin([0])
    b.add_springs([[0, 1]], stiffness=k, rest_length=rest)
    model = b.finalize(device="cpu", dtype="float64")
    solver = pl.solvers.ForceSolver(model, pl.energies.mass_spring(), pl.integrators.SymplecticEuler())
    dt = 0.004  # recording interval; the integrator's step is dt / 4 (ωΔt = 0.02)
    traj = pl.Simulator(model, solver, frame_dt=dt, substeps=4).run(350, progress=False)
    u = traj.x[:, 1, 0] - rest
    i = np.flatnonzero((u[:-1] > 0) & (u[1:] <= 0))  # downward zero crossings
    crossings = traj.t[i] + dt * u[i] / (u[i] - u[i + 1])
    assert len(crossings) >= 4, f"only {len(crossings)} periods observed"
    period = float(np.mean(np.diff(crossings)))
    expected = 2 * math.pi * math.sqrt(m / k)
    assert abs(period / expected - 1) < 0.01, f"period {period:.5f} s, expected {expected:.5f} s"
    assert np.all(traj.x[:, 0] == 0.0), "the pinned anchor moved"


def test_divergence_raises_naming_the_frame():
    """An unstable explicit step raises DivergenceError whose message names the frame and the fix."""
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles([[0.0, 0.0, 0.0], [1.1, 0.0, 0.0]], [1.0, 1e-3])
    b.pin([0])
    b.add_springs([[0, 1]], stiffness=1e6, rest_length=1.0)
    model = b.finalize(device="cpu", dtype="float64")
    solver = pl.solvers.ForceSolver(model, pl.energies.mass_spring(), pl.integrators.SymplecticEuler())
    sim = pl.Simulator(model, solver, frame_dt=0.01, substeps=1)
    with pytest.raises(pl.DivergenceError) as info:
        sim.run(50, progress=False)
    err = info.value
    assert 1 <= err.frame <= 50
    assert f"diverged at frame {err.frame}" in str(err)
    assert "substeps" in str(err)


def test_simulator_frame_dt_and_its_deprecated_name():
    """Issue 10: the frame duration is ``frame_dt``; ``dt`` (the solver's step everywhere else) still works
    for the Simulator with a DeprecationWarning naming frame_dt, and giving both is an error."""
    import warnings

    b = pl.ModelBuilder()
    b.add_particles([[0.0, 1.0, 0.0]], mass=1.0)
    model = b.finalize(device="cpu", dtype="float64")
    solver = pl.solvers.ForceSolver(model)
    sim = pl.Simulator(model, solver, frame_dt=0.05, substeps=5)
    assert sim.frame_dt == 0.05 and sim.substep_dt == 0.01
    with pytest.warns(DeprecationWarning, match="Simulator.frame_dt"):
        assert sim.dt == 0.05  # the old name of the frame duration, not the step
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        old = pl.Simulator(model, solver, dt=0.05, substeps=5)
    assert old.frame_dt == 0.05
    assert any(issubclass(w.category, DeprecationWarning) and "frame_dt" in str(w.message) for w in caught)
    with pytest.raises(TypeError, match="frame_dt only"):
        pl.Simulator(model, solver, frame_dt=0.05, dt=0.05)
    a = pl.Simulator(model, solver, frame_dt=0.05, substeps=5).run(3, progress=False).x
    assert np.array_equal(a, old.run(3, progress=False).x)


def test_substep_dt_is_the_one_division_of_a_frame():
    """Issue 26: ``substep_dt`` is frame_dt / substeps bit for bit (the float every caller used to compute
    itself), rejects a step count that is not an integer >= 1 and a non-positive frame, and the Simulator
    and Scene properties are that function."""
    from pliant._time import substep_dt

    for frame_dt, n in ((1 / 60, 16), (1 / 30, 3), (0.05, 7), (1e-3, 1)):
        assert substep_dt(frame_dt, n) == frame_dt / n  # exact: the same IEEE division
    assert substep_dt(1 / 60, 16) * 16 == pytest.approx(1 / 60, rel=1e-15)
    for bad in (0, -2, 2.5, True):
        with pytest.raises(ValueError, match="substeps must be an integer >= 1"):
            substep_dt(1 / 60, bad)
    with pytest.raises(ValueError, match="frame_dt must be a positive"):
        substep_dt(0.0, 4)
    scene = pl.scene.build_scene(pl.scene.load_scene("rope"), device="cpu")
    assert scene.substep_dt == scene.frame_dt / scene.substeps
    assert scene.simulator().substep_dt == scene.substep_dt
