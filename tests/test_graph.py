"""Frames replayed as captured graphs (pliant.sim._graph) are the direct launches, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import pliant as pl
import pliant.scene
from pliant.scene import builtin_scenes
from pliant.sim._graph import FrameGraphs, fingerprint


def _cloth(substeps: int = 16, device: str = "cpu", **solver_kw):
    b = pl.ModelBuilder()
    b.add_cloth_grid(
        nx=6, ny=6, size=0.5, mass=0.1, stiffness=20.0, damping=0.001, origin=(-0.25, 0.5, -0.25)
    )
    b.add_ground(friction=0.5)
    model = b.finalize(device=device)
    solver = pl.solvers.ForceSolver(
        model, pl.energies.mass_spring(), pl.integrators.SymplecticEuler(), **solver_kw
    )
    return pl.Simulator(model, solver, frame_dt=1 / 30, substeps=substeps)


def _run(sim: pl.Simulator, frames: int) -> np.ndarray:
    for _ in range(frames):
        sim.step_frame()
    return sim.state_0.particle_q.numpy()


@pytest.mark.parametrize("name", builtin_scenes())
def test_builtin_scenes_replay_bit_for_bit(name):
    """Every built-in scene: graph replay (the default) equals launch-by-launch stepping exactly, and a
    replayable scene captures at most once per starting state (its fingerprint does not flap)."""
    cfg = pl.scene.load_scene(name)
    graphed = pl.scene.build_scene(cfg).simulator()
    if graphed.graph_reason is not None:
        # Blocked solvers say why, and step directly (nothing to compare).
        assert isinstance(graphed.graph_reason, str) and graphed.graph_reason
        return
    direct = pl.scene.build_scene(cfg).simulator()
    direct.set_graph(False)
    frames = 6
    x = _run(graphed, frames)
    assert np.isfinite(x).all()
    np.testing.assert_array_equal(x, _run(direct, frames))
    np.testing.assert_array_equal(graphed.state_0.particle_qd.numpy(), direct.state_0.particle_qd.numpy())
    assert graphed._graphs.captures <= 2
    assert graphed._graphs.replays >= frames - 2


def _same(device: str, a: np.ndarray, b: np.ndarray) -> None:
    """Bit for bit on the CPU (serial kernels); on CUDA atomics may sum in another order."""
    if device == "cpu":
        np.testing.assert_array_equal(a, b)
    else:
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("substeps", [15, 16])
def test_odd_and_even_substeps(substeps, device):
    """An odd substep count leaves a frame in the other buffer: a graph per starting state keeps the
    references where the direct loop leaves them."""
    a, b = _cloth(substeps, device), _cloth(substeps, device)
    b.set_graph(False)
    a0, b0 = a.state_0, b.state_0
    x = _run(a, 9)
    assert np.isfinite(x).all()
    _same(device, x, _run(b, 9))
    assert a.graph_reason is None and a._graphs.replays >= 6
    # the frame ends in the same buffer as the direct loop's
    assert (a.state_0 is a0) == (b.state_0 is b0) == (substeps % 2 == 0)


def test_changed_scalar_takes_effect():
    """A Python scalar baked into the graph (the damping rate) changed between frames is captured again."""
    a, b = _cloth(damping_rate=0.5), _cloth(damping_rate=0.5)
    b.set_graph(False)
    _run(a, 4), _run(b, 4)
    captures = a._graphs.captures
    a.solver.damping_rate = b.solver.damping_rate = 5.0
    np.testing.assert_array_equal(_run(a, 4), _run(b, 4))
    assert a._graphs.captures == captures + 1


def test_in_place_write_is_read_by_replays():
    """assign() keeps the address: the replayed graph reads the new stiffness without a new capture."""
    a, b = _cloth(), _cloth()
    b.set_graph(False)
    _run(a, 4), _run(b, 4)
    captures = a._graphs.captures
    for sim in (a, b):
        k = sim.model.spring_stiffness.numpy()
        sim.model.spring_stiffness.assign(k * 3.0)
    np.testing.assert_array_equal(_run(a, 4), _run(b, 4))
    assert a._graphs.captures == captures


def test_fingerprint_sees_replaced_arrays_and_scalars():
    sim = _cloth()
    f0 = fingerprint(sim.solver, sim.control)
    assert fingerprint(sim.solver, sim.control) == f0
    sim.solver.velocity_damping_factor = 0.5
    f1 = fingerprint(sim.solver, sim.control)
    assert f1 != f0
    sim.model.spring_stiffness = wp.clone(sim.model.spring_stiffness)
    assert fingerprint(sim.solver, sim.control) != f1


def test_blocked_solver_reasons():
    b = pl.ModelBuilder()
    b.add_soft_box(
        cells=(2, 2, 2), size=(0.2, 0.2, 0.2), origin=(0.0, 0.3, 0.0), density=500.0, E=1e4, nu=0.3
    )
    model = b.finalize(device="cpu", dtype="float64")
    solver = pl.solvers.ForceSolver(
        model, [pl.energies.NeoHookean(), pl.energies.Gravity()], pl.integrators.BackwardEuler()
    )
    sim = pl.Simulator(model, solver, frame_dt=1 / 30, substeps=2)
    assert "BackwardEuler" in sim.graph_reason
    with pytest.raises(ValueError, match="graph=True.*BackwardEuler"):
        pl.Simulator(model, solver, frame_dt=1 / 30, substeps=2, graph=True)
    with pytest.raises(TypeError, match="graph must be"):
        pl.Simulator(model, solver, frame_dt=1 / 30, substeps=2, graph="yes")
    xpbd_model = pl.ModelBuilder()
    xpbd_model.add_cloth_grid(nx=3, ny=3, size=0.2, mass=0.05, stiffness=100.0, origin=(0, 0.5, 0))
    m = xpbd_model.finalize(device="cpu")
    # A tolerance is tested on the device (wp.capture_while): no reason to run directly.
    assert (
        pl.Simulator(m, pl.solvers.XPBD(m, tolerance=1e-6), frame_dt=1 / 30, substeps=2).graph_reason is None
    )
    assert pl.Simulator(m, pl.solvers.XPBD(m), frame_dt=1 / 30, substeps=2).graph_reason is None


def test_xpbd_tolerance_without_conditional_cuda_graphs_says_why(monkeypatch):
    """On a CUDA device without conditional graph nodes (driver or toolkit older than 12.4) an XPBD
    tolerance cannot loop inside a graph: graph_blocker names the cause and the fix (the Simulator then
    warns once and runs the frames directly); with them, or on the CPU, nothing blocks."""
    b = pl.ModelBuilder()
    b.add_cloth_grid(nx=3, ny=3, size=0.2, mass=0.05, stiffness=100.0, origin=(0, 0.5, 0))
    m = b.finalize(device="cpu")
    solver = pl.solvers.XPBD(m, tolerance=1e-6)
    cuda = type("FakeCuda", (), {"is_cuda": True})()
    monkeypatch.setattr(wp, "get_device", lambda d=None: cuda)
    monkeypatch.setattr(wp, "is_conditional_graph_supported", lambda: False)
    why = solver.graph_blocker()
    monkeypatch.setattr(wp, "is_conditional_graph_supported", lambda: True)
    assert solver.graph_blocker() is None
    monkeypatch.undo()
    assert why is not None and "12.4" in why and "tolerance" in why
    solver.tolerance = None
    assert solver.graph_blocker() is None


@pytest.mark.parametrize("schedule", ["coloring", "jacobi"])
def test_xpbd_tolerance_replays_bit_for_bit(schedule):
    """An XPBD step with a tolerance, captured with its device-side loop, replays the direct frames bit for
    bit, with the same sweep counts per step (read from the device once, at the end) although they vary
    from step to step (the loop does stop early, and not always at the same sweep)."""
    sims = []
    for graph in (None, False):
        b = pl.ModelBuilder()
        b.add_cloth_grid(
            nx=8, ny=8, size=0.4, mass=0.05, stiffness=100.0, origin=(-0.2, 0.5, -0.2), plane="xz",
            pin="top-corners",
        )  # fmt: skip
        b.add_ground(friction=0.5)
        m = b.finalize(device="cpu")
        solver = pl.solvers.XPBD(m, iterations=21, schedule=schedule, tolerance=2e-5, check_every=2)
        sims.append(pl.Simulator(m, solver, frame_dt=1 / 30, substeps=4, graph=graph))
    graphed, direct = sims
    assert graphed.graph_reason is None
    for _ in range(8):
        _run(graphed, 1)
        _run(direct, 1)
        np.testing.assert_array_equal(graphed.state_0.particle_q.numpy(), direct.state_0.particle_q.numpy())
        assert graphed.solver.last_iterations == direct.solver.last_iterations
    np.testing.assert_array_equal(graphed.state_0.particle_qd.numpy(), direct.state_0.particle_qd.numpy())
    assert graphed._graphs.replays >= 6
    steps, sweeps = graphed.solver.sweep_counts()
    assert (steps, sweeps) == direct.solver.sweep_counts() and steps == 8 * 4
    assert 2 * steps < sweeps < 21 * steps, "the tolerance never (or always) stopped the sweeps early"


def test_failed_capture_falls_back_once(monkeypatch):
    """A capture that raises (an older Warp without CPU graphs) warns once and the run goes on directly,
    with the same result."""
    a, b = _cloth(), _cloth()
    b.set_graph(False)

    class Broken:
        def __init__(self, *args, **kwargs):
            pass

        def __enter__(self):
            raise RuntimeError("no graphs here")

        def __exit__(self, *exc):
            return False

    monkeypatch.setattr(wp, "ScopedCapture", Broken)
    with pytest.warns(RuntimeWarning, match="graph capture failed.*no graphs here"):
        xa = _run(a, 5)
    assert a._graphs is None and "no graphs here" in a.graph_reason
    np.testing.assert_array_equal(xa, _run(b, 5))


def test_frame_graphs_warm_then_capture():
    """The first frame under a key runs directly, the second is captured, later ones replay."""
    calls = []
    arr = wp.zeros(1, dtype=float, device="cpu")
    graphs = FrameGraphs("cpu")
    states = (object(), object())

    def frame(st):
        calls.append(1)
        arr.fill_(float(len(calls)))
        return st

    for _ in range(4):
        graphs.run(frame, states, ())
    # direct, captured (the Python body ran once more while recording), then replays only
    assert len(calls) == 2 and graphs.captures == 1 and graphs.replays == 3
    assert arr.numpy()[0] == 2.0  # the replays repeat the captured fill


def test_implicit_fast_mass_spring_replays_with_device_side_cg_stop(device):
    """FastMassSpring's implicit step in a graph launches every CG iteration with no host read (converged
    iterations skip their work on the device) and lands on the host-stopped run's positions bit for bit."""
    from pliant.bench._mass_spring import cloth_drape_model

    sims = []
    for graph in (None, False):
        model = cloth_drape_model(8, device=device, dtype="float64")
        solver = pl.solvers.FastMassSpring(model, method="implicit", cg_iterations=200, cg_tol=1e-6)
        assert solver.graph_blocker() is None
        sims.append(pl.Simulator(model, solver, frame_dt=1 / 60, substeps=3, graph=graph))
    graphed, direct = sims
    x = _run(graphed, 6)
    assert np.isfinite(x).all()
    _same(device, x, _run(direct, 6))
    assert graphed._graphs.replays >= 4
    # the direct run stopped CG early, so the comparison is against the early stop
    assert 0 < direct.solver.last_cg_iterations < 200


def test_environment_switch_turns_graphs_off(monkeypatch):
    monkeypatch.setenv("PLIANT_GRAPH", "0")
    sim = _cloth()
    assert sim.graph_reason == "graph=False" and sim._graphs is None
    monkeypatch.setenv("PLIANT_GRAPH", "1")
    assert _cloth().graph_reason is None


def test_a_key_that_changes_every_frame_runs_directly_and_does_not_pile_up():
    """A drag target that moves every frame (a live drag) changes the fingerprint each frame: those frames
    run directly, the motion is the direct run's, and the remembered keys stay bounded."""
    from pliant.sim._graph import _MAX_WARM

    a, b = _cloth(), _cloth()
    b.set_graph(False)
    for f in range(3 * _MAX_WARM):
        for sim in (a, b):
            sim.control.set_drag(0, (0.1 * np.sin(f), 0.6, 0.0), stiffness=5.0)
            sim.step_frame()
    np.testing.assert_array_equal(a.state_0.particle_q.numpy(), b.state_0.particle_q.numpy())
    assert np.isfinite(a.state_0.particle_q.numpy()).all()
    assert len(a._graphs._warm) <= _MAX_WARM and a._graphs.replays == 0


class _HostHandler:
    """A contact handler that does host work each step (so it cannot be replayed) and nothing else."""

    def graph_blocker(self) -> str:
        return "it reads on the host"

    def apply(self, model, state_in, state_out, dt) -> None:
        pass


def test_a_blocker_set_after_construction_is_honoured():
    """A handler that blocks replay, added after the Simulator was made: those frames run directly
    (graph_reason says why), and graphs come back once it is removed."""
    b = pl.ModelBuilder()
    b.add_cloth_grid(nx=4, ny=4, size=0.3, mass=0.05, stiffness=100.0, origin=(0, 0.5, 0), pin="top-corners")
    m = b.finalize(device="cpu")
    sim = pl.Simulator(m, pl.solvers.XPBD(m, iterations=8), frame_dt=1 / 30, substeps=2)
    _run(sim, 3)
    replays = sim._graphs.replays
    assert replays >= 1 and sim.graph_reason is None
    sim.solver.collisions.append(_HostHandler())
    _run(sim, 3)
    assert "reads on the host" in sim.graph_reason and sim._graphs.replays == replays
    sim.solver.collisions.pop()
    _run(sim, 3)
    assert sim.graph_reason is None and sim._graphs.replays > replays


def test_a_tolerance_set_after_construction_is_captured_with_it():
    """An XPBD tolerance set between frames is a new fingerprint: the frame is captured again, with the
    device-side loop, and the run stays bit for bit the direct one given the same tolerance at the same
    frame (a stale graph, or the solver's recorded fixed-count launches, would ignore it)."""
    sims = []
    for graph in (None, False):
        b = pl.ModelBuilder()
        b.add_cloth_grid(
            nx=4, ny=4, size=0.3, mass=0.05, stiffness=100.0, origin=(0, 0.5, 0), pin="top-corners"
        )
        m = b.finalize(device="cpu")
        sims.append(
            pl.Simulator(m, pl.solvers.XPBD(m, iterations=40), frame_dt=1 / 30, substeps=2, graph=graph)
        )
    graphed, direct = sims
    for sim in sims:
        _run(sim, 3)
    captures = graphed._graphs.captures
    for sim in sims:
        sim.solver.tolerance = 3e-3
        _run(sim, 4)
    assert graphed.graph_reason is None and graphed._graphs.captures > captures
    assert graphed.solver.last_iterations == direct.solver.last_iterations
    assert graphed.solver.sweep_counts() == direct.solver.sweep_counts()
    assert graphed.solver.sweep_counts()[1] < 40 * 8, "the tolerance never stopped the sweeps early"
    np.testing.assert_array_equal(graphed.state_0.particle_q.numpy(), direct.state_0.particle_q.numpy())


def _plain_fingerprint(*roots, depth: int = 4) -> tuple:
    """The fingerprint's walk as first written (no memos, no shortcuts): the reference for its speed-ups."""
    from pliant.sim._graph import _SCALARS, _SKIP

    out: list = []
    seen: set[int] = set()

    def walk(obj, path, d):
        if isinstance(obj, wp.array):
            out.append((path, obj.ptr, obj.shape))
        elif isinstance(obj, _SCALARS):
            out.append((path, obj))
        elif isinstance(obj, np.ndarray):
            out.append((path, obj.shape, obj.tobytes() if obj.size <= 64 else id(obj)))
        elif isinstance(obj, list | tuple):
            for i, x in enumerate(obj):
                walk(x, f"{path}[{i}]", d)
        elif isinstance(obj, dict):
            for k, v in obj.items():
                if isinstance(k, str) and not any(s in k for s in _SKIP):
                    walk(v, f"{path}.{k}", d)
        elif d > 0 and type(obj).__module__.startswith("pliant") and id(obj) not in seen:
            seen.add(id(obj))
            for k, v in vars(obj).items() if hasattr(obj, "__dict__") else ():
                if not any(s in k for s in _SKIP):
                    walk(v, f"{path}.{k}", d - 1)

    for i, r in enumerate(roots):
        walk(r, str(i), depth)
    return tuple(out)


@pytest.mark.parametrize("name", builtin_scenes())
def test_fingerprint_is_the_plain_walk(name):
    """The memoised walk gives the plain walk's tuple, entry for entry, on every built-in scene's solver and
    control (before and after a frame: solvers allocate on their first step), and at depth 2."""
    sim = pl.scene.build_scene(pl.scene.load_scene(name)).simulator()
    for _ in range(2):
        roots = (sim.solver, sim.control, 1 / 240, 4)
        assert fingerprint(*roots) == _plain_fingerprint(*roots)
        assert fingerprint(*roots, depth=2) == _plain_fingerprint(*roots, depth=2)
        sim.step_frame()
