"""The per-vertex step bound (pl.collision.StepBound): a sheet thrown through another in one step is
stopped at the bound's closed form and never intersects (judged by ipctk, tests/intersections.py)."""

from __future__ import annotations

import numpy as np
import pytest

import pliant as pl

pytest.importorskip("ipctk")

from intersections import Part, intersecting_frames  # noqa: E402

GAP, DT, SPEED = 0.01, 1e-3, 20.0  # [m], [s], [m/s]


def _two_sheets(dtype: str = "float32"):
    """A fixed sheet at y = 0 and a free one GAP above, with v_y = −SPEED (x + ½): a step tilts it through."""
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    for y, pin in ((0.0, "all"), (GAP, "none")):
        kw = {"pin": list(range(25))} if pin == "all" else {}
        b.add_cloth_grid(nx=4, ny=4, size=1.0, mass=0.1, stiffness=10.0, origin=(-0.5, y, -0.5), **kw)
    model = b.finalize(device="cpu", dtype=dtype)
    state = model.state()
    x = model.particle_q.numpy()
    v = np.zeros_like(x)
    top = np.arange(25, 50)
    v[top, 1] = -SPEED * (x[top, 0] + 0.5)
    state.particle_qd.assign(v)
    return model, state, top


def _run(model, state, handlers, steps):
    solver = pl.solvers.ForceSolver(
        model, pl.energies.mass_spring(), pl.integrators.SymplecticEuler(), collisions=handlers
    )
    tris = model.tri_indices.numpy().reshape(-1, 3)
    frames = [state.particle_q.numpy().copy()]
    s0, s1 = state, model.state()
    for _ in range(steps):
        solver.step(s0, s1, None, DT)
        s0, s1 = s1, s0
        frames.append(s0.particle_q.numpy().copy())
    return np.array(frames), s0, tris


def test_without_a_bound_the_sheet_passes_through():
    model, state, _ = _two_sheets()
    frames, _, tris = _run(model, state, [], 1)
    assert intersecting_frames([Part(tris, frames)]) == [1]


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_the_bound_stops_each_vertex_at_gamma_times_its_distance(dtype):
    model, state, top = _two_sheets(dtype)
    x0 = state.particle_q.numpy()[top]
    bound = pl.collision.StepBound(model, fraction=0.4, reach=0.1)
    frames, last, tris = _run(model, state, [bound], 1)
    dx = frames[1][top] - x0
    free = SPEED * (x0[:, 0] + 0.5) * DT  # the unbounded drop of each vertex [m]
    # Each top vertex's nearest other primitive is the lower sheet, GAP below (its own sheet's non-adjacent
    # triangles and edges are a cell, 0.25 m, away; the reach 0.1 m is farther than GAP): b = 0.4 (GAP − δ).
    expected = np.minimum(free, 0.4 * (GAP - bound.floor))
    np.testing.assert_allclose(-dx[:, 1], expected, rtol=0, atol=1e-7)
    assert np.abs(dx[:, [0, 2]]).max() < 1e-9
    v = last.particle_qd.numpy()[top, 1]
    np.testing.assert_allclose(-v, expected / DT, rtol=1e-5, atol=1e-4)


def test_the_bound_keeps_every_frame_free_of_intersections():
    model, state, top = _two_sheets()
    bound = pl.collision.StepBound(model, fraction=0.4, reach=0.1)
    frames, _, tris = _run(model, state, [bound], 30)
    assert intersecting_frames([Part(tris, frames)]) == []
    # The gap closes geometrically (at most 2γ of what exceeds the floor δ per step): never below δ.
    assert frames[:, top, 1].min() >= bound.floor * (1 - 1e-3)


def test_bad_arguments_are_refused():
    model, _, _ = _two_sheets()
    with pytest.raises(ValueError, match="fraction must be in"):
        pl.collision.StepBound(model, fraction=0.5, reach=0.1)
    with pytest.raises(ValueError, match="reach must be"):
        pl.collision.StepBound(model, reach=0.0)


def test_a_scene_turns_the_bound_on_for_every_solver_family():
    from pathlib import Path

    from pliant.scene import SceneError, build_scene, parse_scene

    root = Path(pl.__file__).parent / "scenes"
    for name, kind in (("cloth_sphere", "SelfCollision"), ("xpbd_cloth_sphere", "StepBound")):
        text = (root / f"{name}.toml").read_text(encoding="utf-8")
        on = text.replace("self_collision = { thickness", "self_collision = { bound = 0.4, thickness")
        handlers = build_scene(parse_scene(on, overrides=["scene.frames=1"])).solver.collisions
        bound = [h for h in handlers if type(h).__name__ == kind]
        assert len(bound) == 1
        b = bound[0] if kind == "StepBound" else bound[0]._bound
        assert (b.fraction, b.reach) == (0.4, 0.012)
    with pytest.raises(SceneError, match="bound"):
        parse_scene(text.replace("self_collision = { thickness", "self_collision = { bound = 0.5, thickness"))


def test_edges_pressed_together_are_pushed_apart_within_the_bound():
    # Two triangles whose edges cross 1 mm apart (x axis at y = 0; z axis at y = d), everything at rest.
    d, h = 1e-3, 5e-3
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    pts = [(-0.5, 0, 0), (0.5, 0, 0), (0, 0, -1), (0, d, -0.5), (0, d, 0.5), (0, 1, 0)]
    b.add_particles(pts, 0.01)
    b.add_triangles([[0, 1, 2], [3, 4, 5]])
    model = b.finalize(device="cpu")
    bound = pl.collision.StepBound(model, fraction=0.4, reach=0.01, separation=h)
    frames, _, _ = _run(model, model.state(), [bound], 1)
    gap = frames[1][3:5, 1].mean() - frames[1][0:2, 1].mean()
    # Pushed apart, but by at most 2γ (d − δ): the bound holds for the push too.
    assert d < gap <= d + 2 * 0.4 * (d - bound.floor) + 1e-9


def test_a_triangle_moves_away_from_a_pinned_vertex_by_the_bound():
    # A free triangle 1 mm under a pinned vertex above its centroid: SelfCollision would move only the
    # vertex (it cannot); the triangle push moves the triangle by the gap to h, which the bound truncates
    # to γ (d − δ), straight down.
    d, h = 1e-3, 5e-3
    b = pl.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_particles([(0, 0, 0), (0.1, 0, 0), (0, 0, 0.1), (0.1 / 3, d, 0.1 / 3)], 0.01)
    b.add_triangles([[0, 1, 2]])
    b.pin([3])
    model = b.finalize(device="cpu")
    bound = pl.collision.StepBound(model, fraction=0.4, reach=0.01, separation=h)
    frames, _, _ = _run(model, model.state(), [bound], 1)
    dy = frames[1][:3] - frames[0][:3]
    np.testing.assert_allclose(dy[:, 1], -0.4 * (d - bound.floor), rtol=1e-4)
    assert np.abs(dy[:, [0, 2]]).max() < 1e-8
