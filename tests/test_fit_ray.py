"""CMA-ES on Ray actors (issue 42 item 2, pliant/fit/_ray.py): ``pl.fit.fit(ray=True)`` writes the fitted.toml
of one process byte for byte, a search saved by one process resumes on Ray to the same end, every loss is
equal (==); Ray missing, an actor's exception and more actors than the cluster's CPUs are one-line
FitErrors. One local Ray cluster of 2 CPUs for the module (a few seconds to start)."""

from __future__ import annotations

import sys

import pytest
from helpers import FIT_ROPE
from test_fit_workers import _Hook, _problem

import pliant as pl
from pliant.fit import FitError, observe
from pliant.fit._cmaes import cmaes
from pliant.fit._ray import RayActors, use_ray
from pliant.fit._resume import FitCheckpoint
from pliant.fit._workers import close_workers, pool_for

#: Three generations, the validation gate's searches (held back, then all frames: the pool kept across
#: the stages), no gradient stage.
KW = dict(per_element="none", generations=3, epochs=0, progress=False, video=False)


@pytest.fixture(scope="module")
def cluster():
    ray = pytest.importorskip("ray", reason="the ray extra: pip install 'pliant[ray]'")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def rope():
    """The tiny rope observed at k = 50 N/m, and the scene to fit at k = 80 N/m."""
    cfg = pl.scene.parse_scene(FIT_ROPE)
    obs = observe(pl.scene.build_scene(cfg), tracks=7)
    return pl.fit.apply_globals(cfg, {"stiffness": 80.0}), obs


@pytest.fixture
def actors(monkeypatch):
    """The actor count of every Ray pool started (and so proof that Ray evaluated the search)."""
    made: list[int] = []
    init = RayActors.__init__

    def spy(self, recipe, n, *args):
        made.append(n)
        init(self, recipe, n, *args)

    monkeypatch.setattr(RayActors, "__init__", spy)
    return made


def test_a_fit_on_ray_writes_the_fitted_toml_of_one_process(cluster, rope, actors, tmp_path, monkeypatch):
    """fitted.toml byte for byte and every stage's history equal (==) on one process and on 2 Ray actors
    ("auto": the cluster's 2 CPUs); a search stopped after generation 2 on one process and resumed on Ray
    ends the same too."""
    one = pl.fit.fit(*rope, tmp_path / "one", workers=1, **KW)
    two = pl.fit.fit(*rope, tmp_path / "ray", ray=True, **KW)
    assert actors == [2]  # one pool for every CMA-ES stage of the fit
    assert (tmp_path / "ray" / "fitted.toml").read_bytes() == (tmp_path / "one" / "fitted.toml").read_bytes()
    assert two["loss_history"] == one["loss_history"] and len(one["loss_history"]) >= 2

    def stop(self, name, it):
        if (name, it) == ("cmaes", 2):
            raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(FitCheckpoint, "saved", stop)
        with pytest.raises(KeyboardInterrupt):
            pl.fit.fit(*rope, tmp_path / "cut", workers=1, **KW)
    pl.fit.fit(*rope, tmp_path / "cut", ray=True, workers=2, resume=True, **KW)
    assert (tmp_path / "cut" / "fitted.toml").read_bytes() == (tmp_path / "one" / "fitted.toml").read_bytes()


@pytest.mark.parametrize("params", [["E", "nu"], ["E", "damping_rate"]], ids=["batched", "one_by_one"])
def test_ray_search_loss_for_loss(cluster, actors, params):
    """Every candidate's loss equal (==) on one process and on Ray actors, batched (explicit steps: one
    contiguous share per actor) or one rollout per candidate; one actor too."""
    p = _problem(params)
    one, two = _Hook(), _Hook()
    a = cmaes(p, generations=2, checkpoint=one)
    use_ray(p)
    try:
        b = cmaes(p, generations=2, checkpoint=two, workers=2)
        c = cmaes(p, generations=2, workers=1)
    finally:
        close_workers(p)
    assert actors == [2, 1]
    assert [g["losses"] for g in two.saved[-1]["generations"]] == [
        g["losses"] for g in one.saved[-1]["generations"]
    ]
    assert (b.values, b.loss, b.history, b.evaluations) == (a.values, a.loss, a.history, a.evaluations)
    assert (c.values, c.history) == (a.values, a.history)


def test_an_actor_error_is_a_fit_error_naming_it(cluster):
    """An actor that cannot build its problem: a FitError naming the actor and the exception, the actors
    stopped; more actors than the cluster's CPUs: refused before any is started; an actor that dies: a
    FitError naming it."""
    p = _problem(["E", "nu"])
    good = p.recipe
    p.recipe = (good[0], good[1], {**good[2], "params": ["no_such_parameter"]})
    use_ray(p)
    with pytest.raises(FitError, match=r"CMA-ES Ray actor [12] of 2 failed: FitError: .*no_such_parameter"):
        cmaes(p, generations=2, workers=2)
    assert "_worker_pool" not in p.__dict__
    p.recipe = good
    with pytest.raises(FitError, match=r"--workers 3: the Ray cluster \(local\) has 2 CPUs"):
        cmaes(p, generations=2, workers=3)
    pool = pool_for(p, 2, False, True)
    try:
        cluster.kill(pool.backend.actors[1])  # a node lost, an actor killed for its memory
        with pytest.raises(FitError, match=r"^CMA-ES Ray actor 2 of 2 died: "):
            pool.evaluate(p, [p.nominal] * 4)
    finally:
        close_workers(p)
    assert cluster.is_initialized()  # not started here: not shut down here


def test_missing_ray_is_one_line_before_any_work(rope, tmp_path, monkeypatch):
    """Without Ray: one line naming the pip command, before the output folder exists; --address alone is
    refused too."""
    from pliant._extras import pip_install

    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    with pytest.raises(FitError, match="pip install") as err:
        pl.fit.fit(*rope, tmp_path / "out", ray=True, **KW)
    assert str(err.value) == f"--ray needs Ray, an optional extra: {pip_install('ray')}"
    with pytest.raises(FitError, match="--address goes with --ray"):
        pl.fit.fit(*rope, tmp_path / "out", address="10.0.0.1:6379", **KW)
    assert not (tmp_path / "out").exists()


def test_cli_refuses_ray_misuse_in_one_line(tmp_path, capsys, monkeypatch):
    """`pliant fit` and `pliant twin`: --address without --ray, and --ray without Ray, exit 1 with one line
    before reading the scene or the observations (neither file exists here)."""
    from pliant.cli import main

    missing = str(tmp_path / "missing.npz")
    for cmd in (["fit", "rope", missing], ["twin", missing]):
        assert main([*cmd, "--out", str(tmp_path / "out"), "--address", "10.0.0.1:6379"]) == 1
        assert capsys.readouterr().err.strip().splitlines()[-1].endswith("--address goes with --ray")
        with monkeypatch.context() as m:
            m.setitem(sys.modules, "ray", None)
            assert main([*cmd, "--out", str(tmp_path / "out"), "--ray"]) == 1
        assert "--ray needs Ray, an optional extra: pip install" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
