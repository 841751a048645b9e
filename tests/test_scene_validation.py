"""Issue 11, scene level: everything a scene file says is validated at load / build time, before any
simulation work, with ``file:line: field: what is wrong; what to do`` (one regression test per item)."""

from __future__ import annotations

import numpy as np
import pytest

from pliant.scene import SceneError, build_scene, parse_scene

HEAD = '[scene]\nname = "t"\nframes = 1\nsubsteps = 2\n'
ROPE = '[[objects]]\nkind = "rope"\nmaterial = {stiffness = 100.0}\n'
PBD_ROPE = '[[objects]]\nkind = "rope"\nmodel = "pbd"\n'


def _error(text: str, base=".") -> str:
    with pytest.raises(SceneError) as info:
        build_scene(parse_scene(text, "s.toml", base), device="cpu")
    return str(info.value)


@pytest.mark.parametrize(
    ("name", "why"),
    [
        ("../../x", "path separator"),
        ("/tmp/x", "path separator"),
        ("a\\\\b", "path separator"),
        ("", "is empty"),
        ("a" * 300, "300 characters long (at most 100)"),
        ("a\\u0000b", "NUL or control character"),
        (".hidden", "starts with '.'"),
    ],
)
def test_scene_name_is_one_safe_file_name(name, why):
    """Item 1: [scene] name names the outputs inside --out, so it must be one plain file-name component."""
    msg = _error(HEAD.replace('"t"', f'"{name}"') + ROPE)
    assert msg.startswith("s.toml:2: scene.name: ") and why in msg, msg


@pytest.mark.parametrize(
    ("solver", "field", "hint"),
    [
        ("options = { foo = 1 }", "solver.options.foo", "force has no option 'foo'; allowed: contact"),
        ("options = { contct = true }", "solver.options.contct", "did you mean 'contact'?"),
        ("options = { integrator = 1 }", "solver.options.integrator", "set by the scene itself"),
        ("options = { collisions = 1 }", "solver.options.collisions", "set by the scene itself"),
        ("options = { model = 1 }", "solver.options.model", "set by the scene itself"),
        ("options = { contact = 3 }", "solver.options.contact", "expected true or false"),
        ('integrator = "DormandPrince"', "solver.integrator", "integrates ODEs only"),
        (
            'integrator = "BDF2"\nintegrator_options = { newtn_tol = 1.0 }',
            "newtn_tol",
            "did you mean 'newton_tol'",
        ),
        ('integrator = "BackwardEuler"\nintegrator_options = { newton_tol = nan }', "newton_tol", "finite"),
        (
            'integrator = "BackwardEuler"\nintegrator_options = { max_newton_iteration = 5 }',
            "solver.integrator_options.max_newton_iteration",
            "did you mean 'max_newton_iterations'",
        ),
        ("iterations = 5", "solver.iterations", "does not apply to solver kind 'force'"),
    ],
)
def test_force_solver_options_are_checked_at_load(solver, field, hint):
    """Item 2 / 7: option names are checked against the constructor (did you mean), types where cheap, and
    keys the scene sets itself or that do not apply are rejected — at load time, by parse_scene."""
    with pytest.raises(SceneError) as info:
        parse_scene(HEAD + ROPE + "[solver]\n" + solver + "\n", "s.toml")
    assert field in str(info.value) and hint in str(info.value), str(info.value)


def test_implicit_option_values_are_checked_before_simulating():
    """Item 7: the implicit integrators' option values (one validated dataclass) fail at build time with
    the field and the allowed range, before any step."""
    msg = _error(
        HEAD + ROPE + '[solver]\nintegrator = "ImplicitMidpoint"\n'
        "integrator_options = { max_newton_iterations = 0 }\n"
    )
    assert "solver.integrator_options" in msg and "max_newton_iterations must be an integer >= 1" in msg, msg


@pytest.mark.parametrize(
    ("solver", "field", "hint"),
    [
        ("options = { constraints = 3 }", "solver.options.constraints", "set by the scene itself"),
        ("options = { volume_compliance = {} }", "solver.options.volume_compliance", "expected a number"),
        ('integrator = "__class__"', "solver.integrator", "does not apply to solver kind 'xpbd'"),
        ('options = { "__class__" = 1 }', "solver.options.__class__", "xpbd has no option '__class__'"),
        ("options = { iterations = 3 }", "solver.options.iterations", "set by the scene itself"),
    ],
)
def test_xpbd_solver_options_are_checked_at_load(solver, field, hint):
    """Item 2 / 7: the same for XPBD, where [solver] integrator does not apply."""
    with pytest.raises(SceneError) as info:
        parse_scene(HEAD + PBD_ROPE + "[solver]\n" + solver + "\n", "s.toml")
    assert field in str(info.value) and hint in str(info.value), str(info.value)


@pytest.mark.parametrize(
    ("text", "field", "hint"),
    [
        (
            HEAD + '[[objects]]\nkind = "cloth"\nny = 1000000000\nmaterial = {stiffness = 1.0}\n',
            "objects",
            "1.7e+10 particles, 6.5e+10 springs; model",
        ),
        (
            HEAD + '[[objects]]\nkind = "points"\nshape = "box"\nsize = 1000.0\nspacing = 0.03\n'
            "material = {stiffness = 1.0}\n",
            "objects[0].spacing",  # 33334³ = 3.7e13 points: above MAX_COUNT (issue 41), whatever the memory
            "gives 2.22e+14 particles or elements, beyond any machine",
        ),
        (
            HEAD + '[[objects]]\nkind = "soft_box"\ncells = 2000\nmaterial = {stiffness = 1.0}\n',
            "objects",
            "this scene needs",
        ),
        (
            HEAD.replace("substeps = 2", "substeps = 100000000") + ROPE,
            "scene.substeps",
            "less than or equal to 10000",
        ),
        (
            HEAD + PBD_ROPE + "[solver]\niterations = 100000000\n",
            "solver.iterations",
            "less than or equal to 10000",
        ),
        (
            HEAD.replace("frames = 1", "frames = 1000000000") + ROPE,
            "scene.frames",
            "less than or equal to 1000000",
        ),
    ],
)
def test_sizes_and_work_are_bounded_before_allocating(text, field, hint):
    """Item 4: huge sizes fail from the schema's estimate, before anything is allocated; huge substeps,
    iterations and frames have a stated maximum."""
    with pytest.raises(SceneError) as info:
        parse_scene(text, "s.toml")
    assert f": {field}: " in str(info.value) and hint in str(info.value), str(info.value)


def test_particle_budget_is_configurable(monkeypatch):
    """PLIANT_MAX_PARTICLES sets the budget: a 21-particle rope passes at 21 and fails at 20."""
    text = HEAD + '[[objects]]\nkind = "rope"\nn_segments = 20\nmaterial = {stiffness = 1.0}\n'
    monkeypatch.setenv("PLIANT_MAX_PARTICLES", "21")
    parse_scene(text)
    monkeypatch.setenv("PLIANT_MAX_PARTICLES", "20")
    with pytest.raises(SceneError, match="above the budget of 20"):
        parse_scene(text)


@pytest.mark.parametrize(
    ("extra", "field", "hint"),
    [
        ("[camera]\neye = [1.0, 1.0, 1.0]\ntarget = [1.0, 1.0, 1.0]\n", "camera.target", "must differ"),
        ("[camera]\neye = [0.0, 1.0, 0.0]\ntarget = [0.0, 0.0, 0.0]\n", "camera.up", "parallel"),
        ("[camera]\neye = [1.0, 1.0, 1.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 5e-324\n", "camera.fov", ">= 1"),
        ("[output]\nfps = 5e-324\n", "output.fps", "greater than or equal to 1"),
        (
            '[[colliders]]\nkind = "sphere"\ncenter = [-1e308, 0.35, 0]\nradius = 0.1\n',
            "colliders[0].center[0]",
            "greater than or equal to -1000000",
        ),
        (
            '[[colliders]]\nkind = "sphere"\nradius = 1e9\n',
            "colliders[0].radius",
            "less than or equal to 1000000",
        ),
        (
            '[[colliders]]\nkind = "capsule"\na = [0, 0, 0]\nb = [0, 0, 0]\nradius = 0.1\n',
            "colliders[0]",
            "coincide",
        ),
        (
            '[[handles]]\nkind = "box"\ncenter = [0, 1, 0]\nhalf_extents = 0.01\nvelocity = [2000.0, 0, 0]\n',
            "handles[0].velocity",
            "above [scene] max_speed",
        ),
    ],
)
def test_view_colliders_and_handles_fail_early(extra, field, hint):
    """Item 4 / 5 / 6: camera, video rate, far or huge colliders and teleporting handles are load errors."""
    msg = _error(HEAD + ROPE + extra)
    assert f": {field}: " in msg and hint.replace(">= 1", "greater than or equal to 1") in msg, msg


@pytest.mark.parametrize(
    ("body", "field", "hint"),
    [
        (
            '[[objects]]\nkind = "rope"\norigin = [0, 1e39, 0]\nmaterial = {stiffness = 1.0}\n',
            "objects[0].origin[1]",
            "less than or equal to 1000000",
        ),
        (
            '[[objects]]\nkind = "soft_box"\nvelocity = [0, -1e31, 0]\nmaterial = {stiffness = 1.0}\n',
            "objects[0].velocity[1]",
            "greater than or equal to -1000000",
        ),
        (
            '[[objects]]\nkind = "rope"\nlength = nan\nmaterial = {stiffness = 1.0}\n',
            "objects[0].length",
            "finite",
        ),
        (
            '[[objects]]\nkind = "rope"\nlength = inf\nmaterial = {stiffness = 1.0}\n',
            "objects[0].length",
            "finite",
        ),
    ],
)
def test_numbers_are_finite_and_float32_safe(body, field, hint):
    """Item 5: origins / velocities beyond 1e6 (m, m/s) and NaN / inf are load errors, not inf frames."""
    with pytest.raises(SceneError) as info:
        parse_scene(HEAD + body, "s.toml")
    assert f": {field}: " in str(info.value) and hint in str(info.value), str(info.value)


def test_frame_dt_bounds():
    """Item 4 / 6: frame_dt = 1e-300 or 1e30 fail at load naming scene.frame_dt (no ZeroDivision, no
    singular factorisation later); the deprecated key is checked the same way."""
    for v in ("1e-300", "1e30"):
        with pytest.raises(SceneError, match=r"s.toml:2: scene.frame_dt: input should be"):
            parse_scene(HEAD.replace("[scene]\n", f"[scene]\nframe_dt = {v}\n") + ROPE, "s.toml")


def _npy_cases(tmp_path):
    import numpy.lib.format as fmt

    (tmp_path / "empty.npy").write_bytes(b"")
    (tmp_path / "garbage.npy").write_bytes(b"not an array " * 20)
    np.save(tmp_path / "flat.npy", np.zeros(6))
    np.save(tmp_path / "two.npy", np.zeros((5, 2)))
    np.save(tmp_path / "four.npy", np.zeros((5, 4)))
    np.save(tmp_path / "complex.npy", np.zeros((5, 3), complex))
    np.save(tmp_path / "nan.npy", np.full((5, 3), np.nan))
    np.save(tmp_path / "obj.npy", np.array([[1, 2, 3]], dtype=object), allow_pickle=True)
    with open(tmp_path / "huge.npy", "wb") as f:
        fmt.write_array_header_1_0(f, {"descr": "<f8", "fortran_order": False, "shape": (10**12, 3)})
    return {
        "empty.npy": "empty (0 bytes)",
        "garbage.npy": "not a readable .npy array",
        "flat.npy": "shape (6,)",
        "two.npy": "shape (5, 2)",
        "four.npy": "shape (5, 4)",
        "complex.npy": "complex128",
        "nan.npy": "NaN",
        "obj.npy": "object",
        "huge.npy": "claims 1000000000000 points",
    }


def test_npy_point_files_are_checked_exactly(tmp_path):
    """Items 4 / 6 / 7: .npy point files: empty, garbage, wrong shape, complex, NaN, pickled objects and a
    header claiming 1e12 points are SceneErrors naming objects[0].path (read from the header first)."""
    for fname, hint in _npy_cases(tmp_path).items():
        body = f'[[objects]]\nkind = "points"\npath = "{fname}"\nmaterial = {{stiffness = 1.0}}\n'
        msg = _error(HEAD + body, tmp_path)
        assert msg.startswith("s.toml:7: objects[0].path: ") and hint in msg, (fname, msg)


@pytest.mark.parametrize("fname", ["empty.vtk", "empty.msh", "garbage.vtu", "empty.obj", "missing.obj"])
def test_unreadable_meshes_are_scene_errors(tmp_path, fname):
    """Item 3: an unreadable mesh (meshio used to sys.exit) is a SceneError naming objects[0].path."""
    if fname != "missing.obj":
        (tmp_path / fname).write_bytes(b"" if fname.startswith("empty") else b"\x00garbage\xff" * 10)
    body = f'[[objects]]\nkind = "mesh"\npath = "{fname}"\nmaterial = {{stiffness = 1.0}}\n'
    msg = _error(HEAD + body, tmp_path)
    assert msg.startswith("s.toml:7: objects[0].path: "), msg


def test_a_tetrahedral_mesh_where_a_surface_is_needed_is_a_scene_error(tmp_path):
    """A tet mesh file as a mesh collider or a render mesh (which need triangles) is a SceneError naming
    the field and the surface formats, not an AttributeError on .triangles."""
    import meshio

    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * 0.1
    meshio.write_points_cells(tmp_path / "t.vtk", points, [("tetra", np.array([[0, 1, 2, 3]]))])
    collider = '[[colliders]]\nkind = "mesh"\npath = "t.vtk"\n'
    msg = _error(HEAD + ROPE + collider, tmp_path)
    assert "colliders[0].path" in msg and "tetrahedral mesh" in msg and "OBJ" in msg, msg
    box = '[[objects]]\nkind = "soft_box"\nmodel = "fem"\nmaterial = {E = 1e4}\n'
    box += 'render_mesh = {path = "t.vtk"}\n'
    msg = _error(HEAD + box, tmp_path)
    assert "objects[0].render_mesh.path" in msg and "tetrahedral mesh" in msg, msg


def test_tetgen_bound_is_budgeted_before_tetgen_runs(tmp_path):
    """Item 4: a 0.2 m box filled with max_volume = 1e-12 m³ would ask TetGen for ~1e9 vertices: a load error
    naming the memory it needs (the same file with max_volume = 1e-4 builds)."""
    import trimesh

    trimesh.creation.box(extents=(0.2, 0.2, 0.2)).export(tmp_path / "b.obj")
    body = '[[objects]]\nkind = "mesh"\npath = "b.obj"\nmax_volume = {v}\nmaterial = {{stiffness = 1.0}}\n'
    with pytest.raises(
        SceneError, match=r"s.toml:5: objects: this scene needs .* GB \(about 1.6e\+09 particles"
    ):
        parse_scene(HEAD + body.format(v="1e-12"), "s.toml", tmp_path)
    assert build_scene(
        parse_scene(HEAD + body.format(v="1e-4"), "s.toml", tmp_path), device="cpu"
    ).model.particle_count


@pytest.mark.parametrize("cell", ["-1", "0.0", "nan"])
def test_constraint_entry_options_are_checked_before_building_the_solver(cell):
    """Found by the long fuzz: a [[constraints]] entry's bad value (a negative hash-grid cell) is a SceneError
    naming the entry, raised by the constraint's constructor rather than deep inside the solver's set-up."""
    text = HEAD + PBD_ROPE + f'[[constraints]]\nkind = "particle_collision"\ncell_size = {cell}\n'
    msg = _error(text)
    assert "constraints[0]" in msg and "cell_size" in msg, msg
