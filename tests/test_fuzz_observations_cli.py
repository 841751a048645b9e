"""The CLI half of the observation fuzz (issue 41, item 5; counts and classes in
tests/test_fuzz_observations.py's docstring): mutated observation files through ``pliant fit`` and
``pliant twin`` in-process (exit 1, one ``pliant: error:`` line naming the file, nothing in ``--out``), and
fuzzed ``pliant observe`` options (a clean refusal, or a file that loads back with finite data)."""

from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
import warnings
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pliant.io import Observations

sys.path.insert(0, str(Path(__file__).parent))
from test_fuzz_observations import _check_loaded, _no_files, apply, base  # noqa: E402


def _cli(args: list[str], out: Path) -> tuple[int, list[str]]:
    """``pliant ARGS`` in-process: (exit code, its ``pliant: error:`` lines); no traceback, and nothing
    written outside ``out`` but into the case's folder."""
    from pliant.cli import main

    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        try:
            rc = main(args)
        except SystemExit as exc:  # argparse's usage errors (pliant's exit code 1)
            rc = exc.code
    text = err.getvalue()
    assert "Traceback" not in text, text
    assert rc in (0, 1, 2), (rc, text)
    return rc, [line for line in text.splitlines() if line.startswith("pliant: error:")]


CLI_CASES = [
    ("tracks", [("drop", "t")]),
    ("tracks", [("times", "reverse", 1.0)]),
    ("tracks", [("pickle", "points")]),
    ("images", [("huge", "images")]),
    ("images", [("K", "fx0", 1)]),
    ("images", [("masks", "empty", 0)]),
    ("images", [("truncate", 0.5)]),
]


@pytest.mark.parametrize(("kind", "ops"), CLI_CASES)
def test_fit_and_twin_refuse_bad_files_in_one_line(tmp_path, monkeypatch, kind, ops):
    """``pliant fit`` and (images) ``pliant twin``: exit 1, one ``pliant: error:`` line naming the file,
    nothing in ``--out``; the first expensive stage is never reached."""
    from pliant.fit import _explain
    from pliant.fit._toml import scene_toml
    from pliant.twin import _pipeline

    def reached(*args, **kwargs):
        raise AssertionError("the expensive stage was reached")

    monkeypatch.setattr(_explain, "before_physics", reached)
    monkeypatch.setattr(_pipeline, "_splats", reached)
    data, cfg = base(kind)
    obs, scene = tmp_path / "obs.npz", tmp_path / "scene.toml"
    obs.write_bytes(apply(data, ops))
    scene_toml(cfg, scene)
    commands = [["fit", str(scene), str(obs), "-q", "--no-video"]]
    if kind == "images":
        commands.append(["twin", str(obs), "-q"])
    for i, command in enumerate(commands):
        out = tmp_path / f"out{i}"
        rc, errors = _cli([*command, "--out", str(out)], out)
        assert rc == 1 and len(errors) == 1 and str(obs) in errors[0], (command[0], rc, errors)
        _no_files(out)


@st.composite
def observe_args(draw) -> list[str]:
    """``pliant observe`` options: counts, noise, dropout, frames, cameras and image sizes, sane or not."""
    args = ["--frames", str(draw(st.sampled_from([0, 1, 2, 3])))]
    if draw(st.booleans()):
        args += ["--tracks", str(draw(st.sampled_from([0, 1, 3, 7, 100000])))]
    args += ["--noise", draw(st.sampled_from(["0", "1e-3", "-1", "nan", "inf", "1e300"]))]
    args += ["--dropout", draw(st.sampled_from(["0", "0.5", "0.999", "1", "-0.1", "nan"]))]
    args += ["--seed", str(draw(st.sampled_from([0, -1, 2**40])))]
    args += [f for f in ("--cloud", "--unbound") if draw(st.booleans())]
    if draw(st.booleans()):
        args += ["--cameras", str(draw(st.sampled_from([0, 1, 2])))]
        size = ["16x12", "1x1", "0x0", "x", "16x12x3", "-16x12", "100000x100000", "8X6"]
        args += [f"--image-size={draw(st.sampled_from(size))}"]  # "=": "-16x12" is not an option
        args += ["--image-noise", draw(st.sampled_from(["0", "0.1", "nan", "-1"]))]
        args += [f for f in ("--masks", "--uint8") if draw(st.booleans())]
    return args


def observe_case(args: list[str]) -> str:
    """``pliant observe fit_rope ARGS``: exit 1 or 2 with one error line and no file, or a file that loads
    back with finite data."""
    root = Path(tempfile.mkdtemp(prefix="pliant_fuzz_observe_"))
    out = root / "obs.npz"
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            cmd = ["observe", "fit_rope", "--out", str(out), "-q", "--device", "cpu", *args]
            rc, errors = _cli(cmd, root)
        written = sorted(p.name for p in root.iterdir())
        if rc != 0:
            assert len(errors) == 1 and not written, (rc, errors, written)
            return f"exit {rc}"
        assert written == ["obs.npz"], written
        _check_loaded(Observations.load(out))
        return "written"
    finally:
        import shutil

        shutil.rmtree(root, ignore_errors=True)


def _observe_fuzz(examples: int, derandomize: bool) -> dict[str, int]:
    seen: dict[str, int] = {}

    @settings(
        max_examples=examples,
        deadline=None,
        derandomize=derandomize,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(args=observe_args())
    def one(args):
        try:
            outcome = observe_case(args)
        except AssertionError as exc:
            raise AssertionError(f"{exc}\n--- args --- {args}") from None
        seen[outcome] = seen.get(outcome, 0) + 1

    one()
    print(f"observe fuzz: {sum(seen.values())} cases, outcomes {seen}")
    return seen


def test_observe_fuzz():
    """Fuzzed ``pliant observe`` options: a clean refusal, or a file that loads back finite."""
    seen = _observe_fuzz(12, derandomize=True)
    assert seen.get("exit 1", 0) > 0, seen


def test_observe_refuses_videos_larger_than_the_memory():
    """Found by the fuzz: ``--image-size 100000x100000`` raised NumPy's MemoryError (a traceback)."""
    assert observe_case(["--cameras", "1", "--image-size", "100000x100000", "--frames", "2"]) == "exit 1"


@pytest.mark.slow
def test_observe_fuzz_long():
    """The long random search of ``pliant observe``'s options (``-m slow``)."""
    _observe_fuzz(int(os.environ.get("PLIANT_FUZZ_CASES", "300")), derandomize=False)
