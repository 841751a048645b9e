"""Issue 41, item 1: `pliant fit --resume`. A fit writes OUT/fit_checkpoint.json after every CMA-ES generation
and gradient iteration; a fit stopped anywhere and resumed writes the same fitted.toml, byte for byte on the
CPU, as the uninterrupted one; a checkpoint of another scene, other observations, other options or another
version of the fit is refused in one line; every output is written through a temporary file and a rename."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import tomllib
from helpers import FIT_ROPE

import pliant as pl
from pliant.cli import main
from pliant.fit import FitError, observe
from pliant.fit._resume import CHECKPOINT_FILE, FIT_VERSION, FitCheckpoint

#: validation 0: the global search on every training frame, then per-spring values kept on the training loss
#: (with the default 0.2 the dashpot goes back to the scene's 0 on a validation tie, and the per-spring values
#: do not beat the global ones on the one validation frame, so there would be no per-spring file to compare);
#: the gate's own stages resume in test_the_search_on_all_training_frames_resumes.
KW = dict(per_element="stiffness", generations=6, epochs=4, validation=0.0, progress=False, video=False)


@pytest.fixture(scope="module")
def rope():
    """The tiny rope observed at k = 50 N/m, and the scene to fit at k = 80 N/m."""
    cfg = pl.scene.parse_scene(FIT_ROPE)
    obs = observe(pl.scene.build_scene(cfg), tracks=7)
    return pl.fit.apply_globals(cfg, {"stiffness": 80.0}), obs


@pytest.fixture(scope="module")
def reference(rope, tmp_path_factory):
    """The uninterrupted fit (6 generations, 4 Adam epochs of per-spring stiffness)."""
    out = tmp_path_factory.mktemp("ref")
    pl.fit.fit(*rope, out, **KW)
    return out


def _stop_at(monkeypatch, stage: str, iteration: int) -> None:
    """Raise KeyboardInterrupt (Ctrl-C) right after the checkpoint of ``stage``'s ``iteration`` is written."""

    def saved(self, name, it):
        if (name, it) == (stage, iteration):
            raise KeyboardInterrupt

    monkeypatch.setattr(FitCheckpoint, "saved", saved)


def _same_outputs(a: Path, b: Path) -> None:
    assert (a / "fitted.toml").read_bytes() == (b / "fitted.toml").read_bytes()
    pa, pb = np.load(a / "fitted_params.npz"), np.load(b / "fitted_params.npz")
    assert pa.files == pb.files and all(np.array_equal(pa[k], pb[k]) for k in pa.files)


@pytest.mark.parametrize(
    "stage, iteration",
    [("cmaes", 2), ("cmaes", 4), ("gradient", 1), ("gradient", 3)],  # ~30 % and ~60 % of each stage
)
def test_a_stopped_fit_resumes_to_the_same_fitted_toml(
    rope, reference, tmp_path, monkeypatch, stage, iteration
):
    """Ctrl-C after CMA-ES generation 2 or 4 of 6, or Adam epoch 1 or 3 of 4; then `resume=True`: the same
    fitted.toml bytes and per-spring values as the uninterrupted fit, which the stopped fit's own outputs
    (its best values so far) are not."""
    with monkeypatch.context() as m:
        _stop_at(m, stage, iteration)
        with pytest.raises(KeyboardInterrupt):
            pl.fit.fit(*rope, tmp_path, **KW)
    ck = json.loads((tmp_path / CHECKPOINT_FILE).read_text())
    assert ck["current"]["stage"] == stage and ck["current"]["iteration"] == iteration
    stopped = (tmp_path / "fitted.toml").read_bytes()
    assert stopped != (reference / "fitted.toml").read_bytes() or stage == "gradient"
    rep = pl.fit.fit(*rope, tmp_path, resume=True, **KW)
    _same_outputs(reference, tmp_path)
    ref = json.loads((reference / "fit.json").read_text())
    assert rep["loss_history"] == ref["loss_history"] and rep["evaluations"] == ref["evaluations"]


def test_per_element_lbfgs_resumes_from_its_evaluations(rope, tmp_path, monkeypatch):
    """The L-BFGS-B per-element stage, stopped after iteration 2 of 4, continues from its recorded
    evaluations (replayed to SciPy in order) to the uninterrupted fitted.toml and per-spring values."""
    kw = {**KW, "generations": 2, "optimizer": "lbfgs"}
    pl.fit.fit(*rope, tmp_path / "ref", **kw)
    with monkeypatch.context() as m:
        _stop_at(m, "gradient", 2)
        with pytest.raises(KeyboardInterrupt):
            pl.fit.fit(*rope, tmp_path / "cut", **kw)
    assert (
        len(json.loads((tmp_path / "cut" / CHECKPOINT_FILE).read_text())["current"]["state"]["journal"]) >= 2
    )
    pl.fit.fit(*rope, tmp_path / "cut", resume=True, **kw)
    _same_outputs(tmp_path / "ref", tmp_path / "cut")


def test_an_image_fit_resumes_in_its_image_gradient_stage(tmp_path, monkeypatch):
    """From two camera videos: CMA-ES (2 generations), then the L-BFGS-B image-gradient stage stopped after
    its first iteration and resumed: the same fitted.toml (but for the folder its appearance PLY is in) and
    the same appearance PLY bytes as the uninterrupted fit."""
    from test_fit_memory import CLOTH

    from pliant.fit import observe_images

    cfg = pl.scene.parse_scene(CLOTH)
    obs = observe_images(pl.scene.build_scene(cfg), cameras=2, image_size=(24, 18))
    wrong = pl.fit.apply_globals(cfg, {"stiffness": 40.0})
    kw = dict(params=["stiffness"], generations=2, epochs=2, optimizer="lbfgs", progress=False, video=False)
    ref, cut = tmp_path / "ref", tmp_path / "cut"
    pl.fit.fit(wrong, obs, ref, **kw)
    with monkeypatch.context() as m:
        _stop_at(m, "image_gradient", 1)
        with pytest.raises(KeyboardInterrupt):
            pl.fit.fit(wrong, obs, cut, **kw)
    pl.fit.fit(wrong, obs, cut, resume=True, **kw)
    text = (cut / "fitted.toml").read_text().replace(str(cut.resolve()), str(ref.resolve()))
    assert text == (ref / "fitted.toml").read_text()
    assert (cut / "appearance.ply").read_bytes() == (ref / "appearance.ply").read_bytes()


def test_the_search_on_all_training_frames_resumes(rope, tmp_path, monkeypatch):
    """With the validation gate (the default 0.2): stopped in the search that follows the gate, on all the
    training frames, after its generation 2; resumed: the same fitted.toml and gate report as the
    uninterrupted fit."""
    kw = {**KW, "validation": 0.2, "per_element": None}
    ref = pl.fit.fit(*rope, tmp_path / "ref", **kw)
    assert ref["global_validation"]["refit"] == ["cmaes_all_frames"]
    with monkeypatch.context() as m:
        _stop_at(m, "cmaes_all_frames", 2)
        with pytest.raises(KeyboardInterrupt):
            pl.fit.fit(*rope, tmp_path / "cut", **kw)
    rep = pl.fit.fit(*rope, tmp_path / "cut", resume=True, **kw)
    assert (tmp_path / "cut" / "fitted.toml").read_bytes() == (tmp_path / "ref" / "fitted.toml").read_bytes()
    assert rep["global_validation"] == ref["global_validation"]
    assert rep["identifiability"] == ref["identifiability"]


def test_a_finished_fit_resumes_without_searching_again(rope, reference, tmp_path):
    """Resuming a fit whose stages all finished runs no stage (only the outputs are written again)."""
    pl.fit.fit(*rope, tmp_path, **KW)
    t0 = time.perf_counter()
    rep = pl.fit.fit(*rope, tmp_path, resume=True, **KW)
    _same_outputs(reference, tmp_path)
    assert rep["evaluations"] == json.loads((reference / "fit.json").read_text())["evaluations"]
    assert rep["stage_wall_time"] == json.loads((tmp_path / "fit.json").read_text())["stage_wall_time"]
    print(f"\nfinished fit resumed in {time.perf_counter() - t0:.2f} s")


def test_checkpoints_of_another_fit_are_refused_in_one_line(rope, reference, tmp_path):
    """Another scene, other observations, other options, another fit version, a truncated or missing file:
    one FitError line each, naming the file and what differs, before any work."""
    import shutil

    wrong, obs = rope
    shutil.copy(reference / CHECKPOINT_FILE, tmp_path / CHECKPOINT_FILE)
    path = tmp_path / CHECKPOINT_FILE

    def refused(match: str, cfg=wrong, o=obs, **kw) -> None:
        with pytest.raises(FitError) as info:
            pl.fit.fit(cfg, o, tmp_path, resume=True, **{**KW, **kw})
        msg = str(info.value)
        assert len(msg.splitlines()) == 1 and msg.startswith(str(path)) and match in msg, msg

    other_scene = pl.fit.apply_globals(wrong, {"stiffness": 81.0})
    refused("from another scene", cfg=other_scene)
    other_obs = observe(pl.scene.build_scene(pl.scene.parse_scene(FIT_ROPE)), tracks=7, noise=1e-4, seed=3)
    refused("from other observations", o=other_obs)
    refused("other options (seed 42, now 7)", seed=7)
    refused("other options (generations 6, now 8)", generations=8)
    data = json.loads(path.read_text())
    path.write_text(json.dumps({**data, "fit_version": 0}))
    refused(f"written by another version of the fit (0, this one {FIT_VERSION})")
    text = (reference / CHECKPOINT_FILE).read_text()
    path.write_text(text[: len(text) // 2])
    refused("not a readable fit checkpoint")
    path.unlink()
    with pytest.raises(FitError, match="--resume: no fit checkpoint at"):
        pl.fit.fit(wrong, obs, tmp_path, resume=True, **KW)


def test_an_edited_or_bit_flipped_checkpoint_is_refused_by_its_digest(rope, reference, tmp_path):
    """Found by tests/test_fuzz_checkpoints.py: a checkpoint whose header was intact but whose body had one
    bit flipped (a saved loss, a best value) resumed into other values, or crashed deep in a stage
    (KeyError, TypeError); its digest now refuses it in one line."""
    wrong, obs = rope
    data = json.loads((reference / CHECKPOINT_FILE).read_text())
    loss = data["stages"]["cmaes"]["loss"]
    data["stages"]["cmaes"]["loss"] = np.nextafter(loss, np.inf).item()  # the last bit of one float
    path = tmp_path / CHECKPOINT_FILE
    path.write_text(json.dumps(data))
    with pytest.raises(FitError) as info:
        pl.fit.fit(wrong, obs, tmp_path, resume=True, **KW)
    msg = str(info.value)
    assert msg.startswith(f"{path}: the checkpoint's contents do not match its digest"), msg
    assert sorted(p.name for p in tmp_path.iterdir()) == [CHECKPOINT_FILE]  # nothing written


@pytest.mark.slow
def test_kill_9_at_random_points_then_resume(rope, reference, tmp_path):
    """`pliant fit` in a subprocess, killed with SIGKILL once its checkpoint reaches a random generation or
    epoch: every file in OUT is then whole (the JSON and TOML parse, the NPZ loads), and `--resume` gives
    the uninterrupted fitted.toml."""
    wrong, obs = rope
    scene, obs_path = tmp_path / "rope.toml", tmp_path / "obs.npz"
    from pliant.fit._toml import scene_toml

    scene_toml(wrong, scene)
    obs.save(obs_path)
    ref = tmp_path / "ref"
    args = [
        "fit",
        str(scene),
        str(obs_path),
        "--params",
        "stiffness,damping_rate",
        "--per-element",
        "stiffness",
    ]
    args += ["--iterations", "5", "--no-video", "-q", "--seed", "3"]
    assert main([*args, "--out", str(ref)]) == 0
    rng = np.random.default_rng(0)
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    for trial in range(3):
        out = tmp_path / f"kill{trial}"
        target = int(rng.integers(1, 9))  # 5 generations, then 5 epochs: iterations 1 … 10 of both stages
        proc = subprocess.Popen([sys.executable, "-m", "pliant.cli", *args, "--out", str(out)], env=env)
        seen = 0
        while proc.poll() is None and seen < target:
            try:
                ck = json.loads((out / CHECKPOINT_FILE).read_text())
            except (OSError, ValueError):
                ck = None  # not written yet (never half-written: json.loads would fail on a torn file)
            if ck is not None:
                done = {"cmaes": 0, "gradient": 5}
                cur = ck["current"]
                seen = max([5 for s in ck["stages"] if s == "cmaes"] + [0])
                if cur is not None:
                    seen = max(seen, done.get(cur["stage"], 0) + cur["iteration"])
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
        assert proc.wait() == -signal.SIGKILL, (trial, target, seen)  # killed mid-fit, not finished
        print(f"trial {trial}: killed at iteration {seen} (target {target})")
        for f in out.iterdir():
            if f.suffix == ".json":
                json.loads(f.read_text())
            elif f.suffix == ".toml":
                tomllib.loads(f.read_text())
            elif f.suffix == ".npz":
                dict(np.load(f))
        assert main([*args, "--out", str(out), "--resume"]) == 0, trial
        assert (out / "fitted.toml").read_bytes() == (ref / "fitted.toml").read_bytes(), (trial, target)


def test_atomic_output_keeps_the_old_file_when_the_writer_fails(tmp_path):
    """A writer that fails half-way (a kill would too) leaves the previous file whole and no temporary file;
    one that finishes replaces it, with the permissions a plain open() gives."""
    from pliant.io import atomic_output, atomic_write_text

    path = atomic_write_text(tmp_path / "fitted.toml", "old = 1\n")
    with pytest.raises(RuntimeError), atomic_output(path) as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".toml" and tmp != path
        tmp.write_text("new = ")
        raise RuntimeError("killed")
    assert path.read_text() == "old = 1\n" and sorted(p.name for p in tmp_path.iterdir()) == ["fitted.toml"]
    atomic_write_text(path, "new = 2\n")
    umask = os.umask(0)
    os.umask(umask)
    assert path.read_text() == "new = 2\n" and (path.stat().st_mode & 0o777) == 0o666 & ~umask


def test_models_resume_the_stopped_fit_and_start_the_rest(rope, tmp_path, monkeypatch):
    """`--models mass_spring,pbd --resume`: stopped in the first model's CMA-ES (generation 1 of 2), the
    resume continues that model's checkpoint and starts the second's: models.json's fitted values are the
    uninterrupted comparison's."""
    wrong, obs = rope
    kw = dict(generations=2, epochs=0, progress=False, video=False)
    ref = pl.fit.compare_models(wrong, obs, ["mass_spring", "pbd"], tmp_path / "ref", **kw)
    assert all("values" in r for r in ref["models"].values()), ref  # both fitted, none failed
    with monkeypatch.context() as m:
        _stop_at(m, "cmaes", 1)
        with pytest.raises(KeyboardInterrupt):
            pl.fit.compare_models(wrong, obs, ["mass_spring", "pbd"], tmp_path / "cut", **kw)
    assert not (tmp_path / "cut" / "pbd").exists()
    rep = pl.fit.compare_models(wrong, obs, ["mass_spring", "pbd"], tmp_path / "cut", resume=True, **kw)
    assert {m: r.get("values") for m, r in rep["models"].items()} == {
        m: r.get("values") for m, r in ref["models"].items()
    }
    for m in ("mass_spring", "pbd"):
        assert (tmp_path / "cut" / m / "fitted.toml").read_bytes() == (
            tmp_path / "ref" / m / "fitted.toml"
        ).read_bytes()
