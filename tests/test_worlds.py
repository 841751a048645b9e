"""Worlds (ModelBuilder.replicate): W copies stepped together equal W runs alone — bit for bit under
explicit solvers and XPBD, to the solver tolerance under implicit ones — with per-world parameters, reset,
trajectories and divergence."""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl
from pliant.io import Trajectory

W = 3
STIFF = [150.0, 300.0, 600.0]


def _cloth(worlds: int | None, *, ground: bool = True):
    b = pl.ModelBuilder()
    b.add_cloth_grid(nx=5, ny=5, size=0.4, mass=0.05, stiffness=300.0, damping=0.01, origin=(0, 0.3, 0))
    b.pin([0])
    if ground:
        b.add_ground(0.0, friction=0.5)
    if worlds is not None:
        b.replicate(worlds)
    return b.finalize(device="cpu", dtype="float64")


def _force_solver(model):
    return pl.solvers.ForceSolver(
        model, energies=pl.energies.mass_spring(), integrator=pl.integrators.SymplecticEuler()
    )


def _run(model, solver, frames=6, substeps=20, **kw):
    sim = pl.Simulator(model, solver, frame_dt=1 / 60, substeps=substeps, **kw)
    return sim, sim.run(frames, progress=False)


def _solo(k: float, make_solver, **kw) -> Trajectory:
    model = _cloth(None, **kw)
    model.set_world_parameter("spring_stiffness", 0, k)
    return _run(model, make_solver(model))[1]


@pytest.mark.parametrize(
    "make_solver",
    [
        _force_solver,
        lambda m: pl.solvers.FastMassSpring(m, method="symplectic"),
        lambda m: pl.solvers.XPBD(m, iterations=2, schedule="coloring"),
        lambda m: pl.solvers.XPBD(m, iterations=2, schedule="jacobi"),
    ],
    ids=["force", "fast_symplectic", "xpbd_coloring", "xpbd_jacobi"],
)
def test_explicit_worlds_equal_runs_alone_bit_for_bit(make_solver):
    model = _cloth(W)
    for w, k in enumerate(STIFF):
        model.set_world_parameter("spring_stiffness", w, k)
    solver = make_solver(model)
    if hasattr(solver, "update_parameters"):
        solver.update_parameters()
    _, traj = _run(model, solver)
    assert traj.world_count == W
    finals = []
    for w, k in enumerate(STIFF):
        alone = _solo(k, make_solver)
        mine = traj.world(w)
        np.testing.assert_array_equal(mine.x, alone.x)
        finals.append(mine.x[-1])
    assert not np.array_equal(finals[0], finals[2])  # the stiffnesses do differ


def test_implicit_worlds_equal_runs_alone_to_the_tolerance():
    def make(model):
        return pl.solvers.ForceSolver(
            model,
            energies=[pl.energies.NeoHookean(), pl.energies.Gravity()],
            integrator=pl.integrators.BackwardEuler(newton_tol=1e-9),
        )

    def box(worlds):
        b = pl.ModelBuilder()
        b.add_soft_box(cells=(2, 2, 2), size=(0.2, 0.2, 0.2), origin=(0, 0.3, 0), E=2e4, nu=0.3, density=500)
        b.add_ground(0.0)
        if worlds:
            b.replicate(worlds)
        return b.finalize(device="cpu", dtype="float64")

    youngs = [1e4, 3e4]
    model = box(2)
    for w, e in enumerate(youngs):
        model.set_world_material(w, e, 0.3)
    _, traj = _run(model, make(model), frames=8, substeps=2)
    for w, e in enumerate(youngs):
        solo = box(None)
        solo.set_world_material(0, e, 0.3)
        _, alone = _run(solo, make(solo), frames=8, substeps=2)
        np.testing.assert_allclose(traj.world(w).x, alone.x, rtol=0, atol=1e-7)


def test_reset_world_restores_one_world_only():
    model = _cloth(W)
    sim, _ = _run(model, _force_solver(model), frames=3)
    before = sim.state_0.particle_q.numpy().copy()
    model.reset_world(sim.state_0, 1)
    after = sim.state_0.particle_q.numpy()
    s0, s1, s2 = (model.world_slice("particle", w) for w in range(W))
    np.testing.assert_array_equal(after[s1], model.particle_q.numpy()[s1])
    np.testing.assert_array_equal(sim.state_0.particle_qd.numpy()[s1], model.particle_qd.numpy()[s1])
    np.testing.assert_array_equal(after[s0], before[s0])
    np.testing.assert_array_equal(after[s2], before[s2])
    assert not np.array_equal(before[s1], after[s1])


def test_set_world_state_moves_one_world_start():
    model = _cloth(2)
    sl = model.world_slice("particle", 1)
    x1 = model.particle_q.numpy()[sl] + np.array([1.0, 0.0, 0.0])
    model.set_world_state(1, x=x1)
    np.testing.assert_allclose(model.state().particle_q.numpy()[sl], x1)
    np.testing.assert_array_equal(
        model.state().particle_q.numpy()[model.world_slice("particle", 0)],
        _cloth(None).particle_q.numpy(),
    )


def test_a_diverging_world_is_frozen_and_the_others_run_on():
    model = _cloth(W)
    model.set_world_parameter("spring_stiffness", 1, 1e9)  # far past the explicit limit at this step
    with pytest.warns(RuntimeWarning, match="world 1 diverged"):
        sim, traj = _run(model, _force_solver(model), frames=6)
    assert list(sim.diverged_worlds) == [1]
    frozen = traj.world(1)
    assert np.all(np.isfinite(frozen.x)) and frozen.meta["diverged"]["frame"] >= 1
    np.testing.assert_array_equal(frozen.x[-1], frozen.x[-2])  # it stays where it last was good
    for w in (0, 2):
        solo = _cloth(None)
        solo.set_world_parameter("spring_stiffness", 0, 300.0)
        _, alone = _run(solo, _force_solver(solo), frames=6)
        np.testing.assert_array_equal(traj.world(w).x, alone.x)


def test_every_world_diverging_raises():
    model = _cloth(2)
    for w in range(2):
        model.set_world_parameter("spring_stiffness", w, 1e9)
    with pytest.raises(pl.sim.DivergenceError):
        _run(model, _force_solver(model), frames=6)


def test_world_trajectory_round_trips_through_a_file(tmp_path):
    model = _cloth(2)
    _, traj = _run(model, _force_solver(model), frames=2)
    back = Trajectory.load(traj.save(tmp_path / "worlds.npz"))
    w1 = back.world(1)
    assert back.world_count == 2 and w1.x.shape[1] == model.particle_count // 2
    np.testing.assert_array_equal(w1.x, traj.world(1).x)
    assert w1.faces.min() == 0 and w1.faces.max() < w1.x.shape[1]
    assert [o["world"] for o in w1.meta["objects"]] == [1] and w1.meta["objects"][0]["start"] == 0


def test_replicate_and_world_parameters_reject_bad_input():
    b = pl.ModelBuilder()
    with pytest.raises(ValueError, match="nothing to copy"):
        b.replicate(2)
    b.add_rope(n_segments=3, length=0.3, mass=0.01, stiffness=10.0)
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="positive number of worlds"):
            b.replicate(bad)
    b.replicate(2)
    with pytest.raises(ValueError, match="once"):
        b.replicate(2)
    b.add_particles([[0, 0, 0]], 0.1)
    with pytest.raises(ValueError, match="added after"):
        b.finalize(device="cpu")
    model = _cloth(2)
    with pytest.raises(ValueError, match="unknown parameter"):
        model.set_world_parameter("stiffness", 0, 1.0)
    with pytest.raises(ValueError, match="out of range"):
        model.set_world_parameter("spring_stiffness", 2, 1.0)
    with pytest.raises(ValueError, match="one per spring"):
        model.set_world_parameter("spring_stiffness", 0, [1.0, 2.0])
    with pytest.raises(ValueError, match=">= 0"):
        model.set_world_parameter("spring_stiffness", 0, -1.0)
    with pytest.raises(ValueError, match="> 0"):
        model.set_world_parameter("particle_mass", 0, 0.0)


def test_world_mass_keeps_pins_fixed():
    model = _cloth(2)
    sl = model.world_slice("particle", 1)
    model.set_world_parameter("particle_mass", 1, 0.5)
    inv = model.particle_inv_mass.numpy()[sl]
    assert inv[0] == 0.0 and np.allclose(inv[1:], 2.0)
    assert np.all(model.particle_inv_mass.numpy()[model.world_slice("particle", 0)][1:] != 2.0)


@pytest.mark.parametrize(
    "make_solver",
    [_force_solver, lambda m: pl.solvers.XPBD(m, iterations=2, schedule="coloring")],
    ids=["force", "xpbd"],
)
def test_simulator_reset_world_restarts_one_world_exactly(make_solver):
    model = _cloth(W)
    for w, k in enumerate(STIFF):
        model.set_world_parameter("spring_stiffness", w, k)
    sim = pl.Simulator(model, make_solver(model), frame_dt=1 / 60, substeps=20)
    sim.run(3, progress=False)
    sim.reset_world(1)
    traj = sim.run(6, progress=False)
    assert sim.world_resets == [(3, 1)] and traj.meta["worlds"]["resets"] == [[3, 1]]
    for w, k in enumerate(STIFF):
        alone = _solo(k, make_solver)
        if w == 1:  # frames 0-3 as alone, then it starts over: frames 4-6 are frames 1-3 alone
            np.testing.assert_array_equal(traj.world(w).x[:4], alone.x[:4])
            np.testing.assert_array_equal(traj.world(w).x[4:], alone.x[1:4])
        else:  # the others never notice
            np.testing.assert_array_equal(traj.world(w).x, alone.x)


def test_reset_world_thaws_a_diverged_world_with_new_parameters():
    model = _cloth(2)
    model.set_world_parameter("spring_stiffness", 1, 1e9)
    sim = pl.Simulator(model, _force_solver(model), frame_dt=1 / 60, substeps=20)
    with pytest.warns(RuntimeWarning, match="world 1 diverged"):
        sim.run(3, progress=False)
    assert list(sim.diverged_worlds) == [1]
    model.set_world_parameter("spring_stiffness", 1, 300.0)
    sim.reset_world(1)
    assert sim.diverged_worlds == {}
    np.testing.assert_array_equal(
        model.particle_inv_mass.numpy()[model.world_slice("particle", 1)],
        model.particle_inv_mass.numpy()[model.world_slice("particle", 0)],
    )
    traj = sim.run(6, progress=False)
    alone = _solo(300.0, _force_solver)
    np.testing.assert_array_equal(traj.world(1).x[4:], alone.x[1:4])
    np.testing.assert_array_equal(traj.world(0).x, alone.x)
    with pytest.raises(ValueError, match="out of range"):
        sim.reset_world(2)


def test_sweep_of_material_values_runs_as_worlds_equal_to_runs_alone(tmp_path, monkeypatch):
    import pliant.sweep._sweep as sw

    def no_copies(*a, **k):
        raise AssertionError("material-only runs must be batched as worlds, not as object copies")

    monkeypatch.setattr(sw, "_as_copies", no_copies)
    sets = ["objects[0].material.stiffness=100,400", "objects[0].material.damping=0,0.05"]
    batched = sw.run_sweep("rope", sets, tmp_path / "a", worlds=4, frames=6)
    alone = sw.run_sweep("rope", sets, tmp_path / "b", worlds=1, frames=6)
    assert [r["batched"] for r in batched] == [4] * 4
    for a, b in zip(batched, alone, strict=True):
        assert {k: a[k] for k in sw.FIGURES} == {k: b[k] for k in sw.FIGURES}  # bit for bit (explicit)
    assert len({r["sag"] for r in batched}) == 4


def test_build_worlds_rejects_configs_that_differ_beyond_materials():
    from pliant.scene import SceneError, build_scene, build_worlds, load_scene

    with pytest.raises(SceneError, match="differs from world 0"):
        build_worlds([load_scene("rope"), load_scene("rope", ["objects[0].n_segments=20"])], device="cpu")
    with pytest.raises(SceneError, match="cannot build 2 worlds of this scene: handles"):
        build_scene(load_scene("cantilever"), device="cpu", worlds=2)
    from pliant.scene._worlds import material_only

    assert material_only(["objects[0].material.E=1e5", "objects[1].material.nu=0.2"])
    assert not material_only(["objects[0].material.law=stvk"]) and not material_only(["scene.substeps=4"])


def test_fast_mass_spring_implicit_worlds_equal_runs_alone_to_the_cg_tolerance():
    def make(m):
        return pl.solvers.FastMassSpring(m, method="implicit")

    model = _cloth(W)
    for w, k in enumerate(STIFF):
        model.set_world_parameter("spring_stiffness", w, k)
    solver = make(model)
    solver.update_parameters()
    _, traj = _run(model, solver)
    for w, k in enumerate(STIFF):
        alone = _solo(k, make)
        moved = np.abs(alone.x[-1] - alone.x[0]).max()
        # one CG over all worlds stops on the residual of all of them: each within 1e-5 of its motion
        np.testing.assert_allclose(traj.world(w).x, alone.x, rtol=0, atol=1e-5 * moved)


def test_world_mass_rounds_like_the_builder():
    masses = np.random.default_rng(3).uniform(0.001, 0.1, 64)  # float64 masses, not float32 numbers
    pos = np.random.default_rng(4).uniform(-1, 1, (64, 3))
    b = pl.ModelBuilder()
    b.add_particles(pos, masses)
    b.pin([0])
    alone = b.finalize(device="cpu")  # float32: 1/m computed in float64 by the builder, then rounded
    b2 = pl.ModelBuilder()
    b2.add_particles(pos, 0.02)
    b2.pin([0])
    b2.replicate(2)
    model = b2.finalize(device="cpu")
    model.set_world_parameter("particle_mass", 1, masses)
    sl = model.world_slice("particle", 1)
    np.testing.assert_array_equal(model.particle_inv_mass.numpy()[sl], alone.particle_inv_mass.numpy())
    np.testing.assert_array_equal(model.particle_mass.numpy()[sl], alone.particle_mass.numpy())
    assert model.particle_inv_mass.numpy()[sl][0] == 0.0  # the pin holds


def test_a_resumed_run_keeps_its_frozen_world_frozen(tmp_path):
    def sim_of():
        model = _cloth(W)
        model.set_world_parameter("spring_stiffness", 1, 1e9)
        return pl.Simulator(model, _force_solver(model), frame_dt=1 / 60, substeps=20)

    with pytest.warns(RuntimeWarning, match="world 1 diverged"):
        whole = sim_of().run(6, progress=False)
    ck = tmp_path / "ck.npz"
    first = sim_of()
    with pytest.warns(RuntimeWarning, match="world 1 diverged"):
        first.run(3, progress=False, checkpoint=ck)
    resumed = sim_of()
    traj = resumed.run(6, progress=False, checkpoint=ck, resume=True)  # no new divergence: no warning
    assert list(resumed.diverged_worlds) == [1]
    assert resumed.diverged_worlds[1]["frame"] == whole.meta["worlds"]["diverged"]["1"]["frame"]
    np.testing.assert_array_equal(traj.x, whole.x)


def test_sweep_keeps_the_worlds_that_did_not_diverge(tmp_path):
    from pliant.sweep import run_sweep

    rows = run_sweep("rope", ["objects[0].material.stiffness=100,1e12"], tmp_path, worlds=2, frames=8)
    assert [r["status"] for r in rows] == ["ok", "diverged"]
    assert rows[0]["batched"] == 2 and rows[1]["batched"] == 1  # only the diverged run ran again alone
    assert "diverged at frame" in rows[1]["error"]


def test_sweep_where_every_world_diverges_runs_each_alone_once(tmp_path, monkeypatch):
    import pliant.sweep._sweep as sw

    monkeypatch.setattr(sw, "_as_copies", lambda *a, **k: pytest.fail("the copies would diverge as well"))
    rows = sw.run_sweep("rope", ["objects[0].material.stiffness=1e12,2e12"], tmp_path, worlds=2, frames=8)
    assert [(r["status"], r["batched"]) for r in rows] == [("diverged", 1), ("diverged", 1)]
