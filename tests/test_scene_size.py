"""Issue 31, item 2: a scene's size (particles, springs, tets, memory of the model and of the implicit
solver's matrices) is estimated from its file before anything is built, refused above the available memory
with one line naming both, built anyway with ``--force``, and printed by ``pliant info SCENE``."""

from __future__ import annotations

import re
import time

import numpy as np
import pytest
import warp as wp

from pliant.cli import main
from pliant.scene import SceneError, available_memory, build_scene, load_scene, parse_scene, scene_size
from pliant.scene._size import MAX_COUNT

HUGE = ["objects[0].cells=1000"]  # soft_box: 1001³ ≈ 1e9 particles, 7e9 tet-edge springs


def test_huge_scene_is_refused_in_under_a_second():
    """soft_box with cells = 1000 is a SceneError naming what it needs and what the machine has, raised in
    well under a second (closed forms: nothing is allocated)."""
    load_scene("soft_box")  # imports and the registry warm
    t0 = time.perf_counter()
    with pytest.raises(SceneError) as info:
        load_scene("soft_box", HUGE)
    elapsed = time.perf_counter() - t0
    msg = str(info.value)
    assert elapsed < 1.0, f"refusal took {elapsed:.2f} s"
    assert len(msg.splitlines()) == 1, msg
    # 1001³ particles × 36 float32 scalars + 7.009e9 springs × 20 bytes = 284.6 GB.
    assert "soft_box.toml:8: objects: this scene needs 285 GB (1e+09 particles, 7.01e+09 springs" in msg, msg
    assert "GB available; make it coarser, or pass --force to go on" in msg, msg


def test_huge_scene_through_the_cli(capsys, monkeypatch):
    """`pliant run soft_box --set objects[0].cells=1000`: exit 1, one error line, in under a second."""
    monkeypatch.setenv("PLIANT_PREBUILD", "0")
    load_scene("soft_box")
    t0 = time.perf_counter()
    rc = main(["run", "soft_box", "--set", HUGE[0], "--out", "unused_out", "--no-video", "-q"])
    elapsed = time.perf_counter() - t0
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and elapsed < 1.0, (rc, elapsed)
    assert len(err) == 1 and "this scene needs 285 GB" in err[0] and "--force" in err[0], err


def test_force_builds_a_scene_above_the_memory(tmp_path, capsys, monkeypatch):
    """PLIANT_MEMORY_GB = 1e-6 (1 kB) refuses the rope (5.6 kB); --force runs it."""
    monkeypatch.setenv("PLIANT_PREBUILD", "0")
    monkeypatch.setenv("PLIANT_MEMORY_GB", "1e-6")
    assert available_memory() == pytest.approx(1e3)
    args = ["run", "rope", "--frames", "1", "--out", str(tmp_path), "--no-video", "-q", "--device", "cpu"]
    assert main(args) == 1
    assert "this scene needs 5.64 kB" in capsys.readouterr().err
    assert not (tmp_path / "rope.npz").exists()
    assert main([*args, "--force"]) == 0
    assert (tmp_path / "rope.npz").exists()


def test_sweep_refuses_a_scene_above_the_memory_unless_forced(tmp_path, capsys, monkeypatch):
    """`pliant sweep` checks the size like `run`: with PLIANT_MEMORY_GB = 1e-6 (1 kB) a rope sweep (5.6 kB a
    run) exits 1 with the one-line estimate in well under a few seconds and writes nothing; --force runs
    both grid points."""
    monkeypatch.setenv("PLIANT_PREBUILD", "0")
    monkeypatch.setenv("PLIANT_MEMORY_GB", "1e-6")
    load_scene("rope", force=True)  # imports and the registry warm
    out = tmp_path / "sweep"
    args = ["sweep", "rope", "--set", "objects[0].material.stiffness=50,100", "--frames", "2", "-q"]
    t0 = time.perf_counter()
    rc = main([*args, "--out", str(out)])
    elapsed = time.perf_counter() - t0
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and elapsed < 3.0, (rc, elapsed)
    assert len(err) == 1 and "this scene needs 5.64 kB" in err[0] and "--force" in err[0], err
    assert not out.exists()
    assert main([*args, "--out", str(out), "--force"]) == 0
    assert "2 ok, 0 diverged, 0 failed" in capsys.readouterr().out


def test_info_prints_the_estimate(capsys):
    """`pliant info SCENE` prints the counts and memory, and says whether `pliant run` would refuse it."""
    assert main(["info", "soft_box", "--set", HUGE[0]]) == 0
    out = capsys.readouterr().out
    assert "particles      1003003001" in out and "springs        7009003000" in out, out
    assert "total          285 GB" in out and "fits           no" in out, out
    assert main(["info", "soft_box_fem"]) == 0
    out = capsys.readouterr().out
    assert "tets           384" in out and "implicit" in out and "fits           yes" in out, out


def _array_bytes(obj, seen: set, depth: int = 0) -> int:
    """Bytes of the Warp arrays reachable from ``obj``'s attributes (lists, dicts, pliant objects)."""
    if id(obj) in seen or depth > 4:
        return 0
    seen.add(id(obj))
    if isinstance(obj, wp.array):
        return int(obj.capacity or 0)
    items = list(obj.values()) if isinstance(obj, dict) else []
    items += list(obj) if isinstance(obj, (list, tuple)) else []
    items += list(getattr(obj, "__dict__", {}).values())
    return sum(
        _array_bytes(v, seen, depth + 1)
        for v in items
        if isinstance(v, (wp.array, list, tuple, dict)) or type(v).__module__.startswith("pliant")
    )


@pytest.mark.parametrize(
    "name, sets",
    [
        ("cloth", []),
        ("cloth", ["objects[0].nx=7", "objects[0].ny=3", "objects[0].material.bend_stiffness=0.0"]),
        ("rope", []),
        ("soft_box", ["objects[0].cells=[3,4,5]"]),
        ("soft_box_fem", []),
        ("splat_cloth", []),
    ],
)
def test_estimate_matches_the_built_model(name, sets):
    """Closed-form kinds: the estimate's particles, springs, tets and triangles are the built model's exactly;
    the model-and-states memory is within 1.25x of the Warp arrays the model and a simulator hold."""
    cfg = load_scene(name, sets)
    size = scene_size(cfg)
    assert size.exact
    scene = build_scene(cfg, device="cpu")
    m = scene.model
    assert (size.particles, size.springs, size.tets) == (m.particle_count, m.spring_count, m.tet_count)
    assert size.triangles == m.tri_count
    seen: set = set()
    held = _array_bytes(m, seen)
    sim = scene.simulator()
    sim.run(1, progress=False)  # the integrator's scratch arrays exist after a step
    held += sum(_array_bytes(s, seen) for s in (sim.state_0, sim.state_1))
    held += _array_bytes(sim.solver, seen) if not size.implicit else 0  # implicit: in solver_bytes
    assert held / 1.25 <= size.model_bytes <= 1.25 * held, (size.model_bytes, held)


def test_estimate_of_tetgen_meshes_is_within_a_factor_of_two():
    """Estimated kinds (TetGen-filled spheres and meshes): particles and tets within 2x of the built ones."""
    for name in ("fem_drop", "fem_squeeze"):
        cfg = load_scene(name)
        size = scene_size(cfg)
        m = build_scene(cfg, device="cpu").model
        assert not size.exact
        assert m.particle_count / 2 <= size.particles <= 2 * m.particle_count, (name, size, m.particle_count)
        assert m.tet_count / 2 <= size.tets <= 2 * m.tet_count, (name, size, m.tet_count)
        assert size.implicit and size.solver_bytes > size.model_bytes


def test_implicit_solver_matrices_bound_the_hessian():
    """The implicit estimate covers the Hessian's blocks: nnz = particles + 2 × (unique coupled pairs)."""
    cfg = load_scene("soft_box_fem")
    size = scene_size(cfg)
    model = build_scene(cfg, device="cpu").model
    tets = np.asarray(model.tet_indices.numpy())
    pairs = {tuple(sorted((int(t[a]), int(t[b])))) for t in tets for a in range(4) for b in range(a + 1, 4)}
    assert size.pairs == len(pairs)  # the Kuhn split's edges, in closed form
    assert size.solver_bytes >= (model.particle_count + 2 * len(pairs)) * (9 * 4 + 12)


MESH = '[scene]\nname = "m"\nframes = 1\n[[objects]]\nkind = "mesh"\npath = "b.obj"\nmax_volume = {v}\n'
MESH += "material = {{stiffness = 1.0}}\n"


@pytest.mark.parametrize("force", [False, True])
def test_a_denormal_max_volume_is_refused_naming_the_field(tmp_path, force):
    """Issue 41, item 2 (found by the fuzz): a 0.2 m box with max_volume = 5e-324 m³ (a denormal) gives
    0.008 / 5e-324 / 5 = inf TetGen particles; scene_size used to crash on int(inf). It is one SceneError at
    the field's line, with or without --force (no machine holds more than MAX_COUNT = 1e12 particles)."""
    import trimesh

    trimesh.creation.box(extents=(0.2, 0.2, 0.2)).export(tmp_path / "b.obj")
    with pytest.raises(SceneError) as info:
        parse_scene(MESH.format(v="5e-324"), "m.toml", tmp_path, force=force)
    msg = str(info.value)
    assert len(msg.splitlines()) == 1, msg
    assert msg.startswith("m.toml:7: objects[0].max_volume: max_volume = 5e-324 gives inf particles"), msg
    assert "use a larger max_volume" in msg, msg
    # 1e-20 m³: 0.008 / 1e-20 / 5 = 1.6e17 particles, finite but above the bound; 3.5 x that in springs.
    with pytest.raises(SceneError, match=r"max_volume = 1e-20 gives 5.6e\+17 particles or elements"):
        parse_scene(MESH.format(v="1e-20"), "m.toml", tmp_path, force=force)
    cfg = parse_scene(MESH.format(v="1e-4"), "m.toml", tmp_path, force=force)
    assert 0 < scene_size(cfg).particles <= MAX_COUNT


@pytest.mark.parametrize(
    "name, sets, field",
    [
        ("cloth", ["objects[0].nx=2000000", "objects[0].ny=1000000"], "objects[0].nx"),  # 2e12 particles
        ("soft_box", ["objects[0].cells=[100000,100000,1000]"], "objects[0].cells"),  # 1e13 particles
        ("fem_drop", ["objects[1].max_volume=5e-324"], "objects[1].max_volume"),  # a soft_sphere: inf
    ],
)
def test_every_count_is_finite_and_bounded(name, sets, field):
    """Counts above 1e12 or beyond the double range (infinite) are refused naming the field that sets them."""
    with pytest.raises(SceneError, match=rf": {re.escape(field)}: .* beyond any machine") as info:
        load_scene(name, sets)
    assert len(str(info.value).splitlines()) == 1, str(info.value)
