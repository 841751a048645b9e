"""What a new user meets on the command line (issue 27): suggestions for misspelled options, integrators
that are listed are accepted, --out checked before simulating, a quiet Ctrl-C in `pliant view`, no CUDA
driver warning on a CPU-only machine, help examples that name the files the command writes, ropes as
lines in OBJ, install advice that fits a checkout, plural agreement, and commands quoted for every shell."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import pliant as pl
from pliant.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def _rope_trajectory(tmp_path: Path) -> Path:
    assert (
        main(["run", "rope", "--frames", "2", "--no-video", "-q", "--device", "cpu", "--out", str(tmp_path)])
        == 0
    )
    return tmp_path / "rope.npz"


def test_misspelled_option_and_command_get_a_suggestion(capsys):
    with pytest.raises(SystemExit) as e:
        main(["run", "rope", "--frmes", "3"])
    assert e.value.code == 1
    err = capsys.readouterr().err
    assert "usage: pliant run" in err and "--frmes: did you mean --frames?" in err
    with pytest.raises(SystemExit):
        main(["rn", "rope"])
    assert "did you mean 'run'?" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["run", "rope", "--xyzzy"])
    err = capsys.readouterr().err
    assert "unrecognized arguments: --xyzzy" in err and "did you mean" not in err


def test_listed_integrators_are_the_accepted_ones(tmp_path, capsys):
    """The list --integrator prints holds exactly the integrators a scene can step with."""
    from pliant.scene import integrator_names

    code = main(["run", "rope", "--integrator", "DormandPrince", "--no-video", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 1 and "DormandPrince integrates ODEs only" in err
    listed = err.split("available: ")[1].strip().split(", ")
    assert "DormandPrince" not in listed and "RK4" in listed
    assert listed == integrator_names(system_only=True)
    assert all(getattr(getattr(pl.integrators, n), "supports_system", True) for n in listed)


def test_unwritable_out_fails_before_the_simulation(tmp_path, capsys, monkeypatch):
    def never(*a, **k):
        raise AssertionError("simulated before checking --out")

    monkeypatch.setattr(pl.Simulator, "run", never)
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    code = main(["run", "rope", "--frames", "1", "--no-video", "-q", "--out", str(blocker / "sub")])
    assert code == 1
    assert f"--out {blocker / 'sub'}: cannot write there" in capsys.readouterr().err


def test_ctrl_c_in_view_exits_quietly(tmp_path, capsys, monkeypatch):
    import time

    import pliant.render as viewer_mod  # where `pliant view` finds serve_viewer (its public name)

    traj = _rope_trajectory(tmp_path)
    capsys.readouterr()
    stopped = []

    class FakeViewer:
        url = "http://127.0.0.1:0"

        def stop(self):
            stopped.append(True)

    monkeypatch.setattr(viewer_mod, "serve_viewer", lambda *a, **k: FakeViewer())

    def interrupt(_):
        raise KeyboardInterrupt

    monkeypatch.setattr(time, "sleep", interrupt)
    assert main(["view", str(traj)]) == 130
    assert capsys.readouterr().err == "" and stopped == [True]


def test_no_cuda_driver_warning_on_a_cpu_only_machine():
    from pliant._warp import _cuda_driver_present

    if _cuda_driver_present():
        pytest.skip("this machine has the CUDA driver")
    r = subprocess.run(
        [sys.executable, "-m", "pliant.cli", "info"], capture_output=True, text=True, env=ENV, timeout=300
    )
    assert r.returncode == 0 and "not available (CPU only)" in r.stdout
    assert "CUDA driver" not in r.stderr, r.stderr


def test_stderr_filter_keeps_other_native_lines(capfd):
    from pliant._warp import _without_line_on_stderr

    with _without_line_on_stderr(b"NOISE"):
        os.write(2, b"keep me\nsome NOISE here\nand me\n")
    assert capfd.readouterr().err == "keep me\nand me\n"


def test_export_help_names_the_pvd_it_writes(tmp_path, capsys):
    """The --help example's `open vtu/X.pvd` is the file that exact command writes."""
    traj = _rope_trajectory(tmp_path)
    epilog = build_parser()._subparsers._group_actions[0].choices["export"].epilog
    m = re.search(r"--format vtu --out vtu/\s+# ParaView: open vtu/(\S+\.pvd)", epilog)
    assert m, epilog
    assert main(["export", str(traj), "--format", "vtu", "--out", str(tmp_path / "vtu")]) == 0
    assert (tmp_path / "vtu" / m.group(1)).is_file()
    assert m.group(1) in capsys.readouterr().out


def test_rope_obj_has_line_records(tmp_path):
    traj = _rope_trajectory(tmp_path)
    assert main(["export", str(traj), "--out", str(tmp_path / "last.obj"), "--frame", "-1"]) == 0
    lines = (tmp_path / "last.obj").read_text().splitlines()
    verts = [ln for ln in lines if ln.startswith("v ")]
    links = np.array([[int(t) for t in ln.split()[1:]] for ln in lines if ln.startswith("l ")])
    n = pl.Trajectory.load(traj).x.shape[1]
    assert len(verts) == n and links.shape == (n - 1, 2)  # the rope's n - 1 links, 1-based, in order
    np.testing.assert_array_equal(links, np.stack([np.arange(1, n), np.arange(2, n + 1)], axis=1))


def test_install_advice_fits_a_checkout(monkeypatch):
    import pliant._extras as extras

    assert extras.checkout_root() == ROOT
    assert extras.pip_install("viewer") == f"pip install -e '.[viewer]' (in {ROOT})"
    monkeypatch.setattr(extras, "checkout_root", lambda: None)
    assert extras.pip_install("viewer") == "pip install 'pliant[viewer]'"


def test_index_out_of_range_agrees_in_number(tmp_path, capsys):
    code = main(["run", "rope", "--set", "objects[1].mass=1", "--no-video", "--out", str(tmp_path)])
    assert code == 1
    err = capsys.readouterr().err
    assert "the scene has 1 entry (0..0)" in err and "entries" not in err


# ------------------------------------------------------------------------------------------- shell quoting
_GLOB = re.compile(r"[\[\]*?]")


def _globs(word: str) -> bool:
    # Usage syntax brackets a whole word or group (`[--out DIR]`, `[--ray [--address A]]`): not a command.
    return bool(_GLOB.search(word.lstrip("[").rstrip("]")))


def unquoted_globs(line: str) -> list[str]:
    """Words of a `pliant ...` command line that a POSIX shell (zsh: an error) would glob: a `[`, `]`, `*`
    or `?` outside quotes, other than usage brackets around words. A `#` comment ends the command."""
    bad, word, quote = [], "", ""
    for ch in line:
        if quote:
            quote = "" if ch == quote else quote
            continue
        if ch in "'\"":
            quote = ch
        elif ch == "#" and not word:
            break
        elif ch.isspace():
            if _globs(word):
                bad.append(word)
            word = ""
            continue
        word += ch if ch not in "'\"" else ""
    if _globs(word):
        bad.append(word)
    return bad


def pliant_command_lines(text: str) -> list[str]:
    """Lines that run pliant (``pliant ...``, ``python -m pliant...``), from the first `pliant` word on."""
    out = []
    for line in text.splitlines():
        m = re.search(r"(?:^|[`\s])((?:pliant|python -m pliant\S*) [^`\n]*)", line)
        if m and not m.group(1).startswith("pliant:"):
            out.append(m.group(1).split("`")[0])
    return out


def test_glob_scan_catches_an_unquoted_override():
    assert unquoted_globs("pliant run rope --set objects[0].material.stiffness=480") == [
        "objects[0].material.stiffness=480"
    ]
    assert unquoted_globs("pliant run rope --set 'objects[0].material.stiffness=480'  # [N/m]") == []
    assert unquoted_globs("pliant view TRAJ.npz [--host H] [--ray [--address A]]") == []
    assert unquoted_globs("pliant export out/*.npz") == ["out/*.npz"]


def _help_texts() -> list[str]:
    p = build_parser()
    texts = [p.format_help()]
    for sub in p._subparsers._group_actions[0].choices.values():
        texts.append(sub.format_help())
    return texts


def test_commands_are_quoted_for_every_shell():
    """No `pliant` command in the README, the docs or any --help has an unquoted [ ] * ? (zsh, the macOS
    default shell, stops with `no matches found`; bash passes it through only while no file matches)."""
    sources = {"README.md": (ROOT / "README.md").read_text(encoding="utf-8")}
    for page in sorted((ROOT / "docs").rglob("*.md")):
        sources[str(page.relative_to(ROOT))] = page.read_text(encoding="utf-8")
    for i, text in enumerate(_help_texts()):
        sources[f"--help #{i}"] = text
    problems = []
    for name, text in sources.items():
        in_code = False
        for line in text.splitlines():
            if line.startswith("```"):
                in_code = not in_code
            # Commands in code blocks and in `inline code` (README's command table included).
            if not in_code and "`" not in line and not name.startswith("--help"):
                continue
            for cmd in pliant_command_lines(line):
                words = unquoted_globs(cmd)
                if words:
                    problems.append(f"{name}: {cmd.strip()}  ->  quote {words}")
    assert not problems, "\n".join(problems)


def test_quoted_override_runs(tmp_path):
    """The quoted form the docs show is what argparse receives after the shell removes the quotes."""
    args = shlex.split("pliant run rope --set 'objects[0].material.stiffness=480' --frames 1 --no-video -q")
    assert main([*args[1:], "--out", str(tmp_path), "--device", "cpu"]) == 0
    meta = pl.Trajectory.load(tmp_path / "rope.npz").meta
    assert meta["objects"][0]["kind"] == "rope"


# ------------------------------------------------------------------------------------------- fit videos
def test_tracking_fit_video_draws_a_rope_as_one_line():
    """fit.mp4 of a rope: beads along the links make the rope one connected shape in the picture (it was
    loose dots: one blob per particle)."""
    from types import SimpleNamespace

    from scipy import ndimage

    from pliant.fit._run import _with_rope_beads
    from pliant.render import Camera, Renderer

    n = 9
    x = np.zeros((1, n, 3))
    x[0, :, 0] = np.linspace(-0.4, 0.4, n)  # 10 cm links
    x[0, :, 1] = 0.5
    scene = SimpleNamespace(model=SimpleNamespace(objects=[{"kind": "rope", "start": 0, "count": n}]))
    colors = np.tile([0.91, 0.42, 0.16], (1, n, 1))
    r = 0.01
    pts, cols, rad = _with_rope_beads(scene, x, x, colors, np.full(n, r), r)
    assert pts.shape[1] == n + (n - 1) * 10 and cols.shape[:2] == pts.shape[:2] and len(rad) == pts.shape[1]
    cam = Camera.fit(x[0], width=320, height=120)
    blobs = []
    for p, c, rr in ((x[0], colors[0], np.full(n, r)), (pts[0], cols[0], rad)):
        img = Renderer(cam, ground=False).render(p, colors=c, point_radius=rr).astype(int)
        mask = (img.max(axis=2) - img.min(axis=2)) > 60  # the orange particles
        blobs.append(ndimage.label(mask)[1])
    assert blobs == [n, 1], blobs


def test_splat_fit_video_is_labelled():
    from pliant.fit._photometric import _label

    frame = np.full((72, 200, 3), 90, np.uint8)
    out = _label(frame, [(0, "observed, camera 0"), (102, "fitted (splats)")])
    white = np.all(out > 240, axis=2)
    assert white[:16, :100].sum() > 30 and white[:16, 102:].sum() > 30  # text on both halves
    assert not white[20:].any()  # and nothing below the label strip
