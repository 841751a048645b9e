"""CMA-ES stops by convergence (a relative improvement threshold over a few generations), with
``generations`` as a cap: a toy problem that converges stops early, one whose loss keeps falling runs to the
cap. The toy problems are plain functions of the parameters (no simulation)."""

from __future__ import annotations

import math

import numpy as np

from pliant.fit._cmaes import cmaes
from pliant.fit._params import GLOBAL, Bound


class _Toy:
    """The interface cmaes() needs: globals, nominal, build/simulate/loss (here a function of the values)."""

    def __init__(self, f):
        self.globals = [
            Bound(GLOBAL["stiffness"], 10.0, 1.0, 100.0),
            Bound(GLOBAL["damping"], 1.0, 0.1, 10.0),
        ]
        self.nominal = {"stiffness": 10.0, "damping": 1.0}
        self.n_train = 2
        self.calls = 0
        self.f = f

    def build(self, values):
        return values

    def simulate(self, values, frames):
        return values

    def loss(self, values):
        self.calls += 1
        return self.f(self, values)


def _bowl(p, v):
    # 1 + a quadratic bowl in log space with its minimum at k = 30, γ = 2: converges to 1, where a
    # relative improvement soon falls under 1e-3 (an absolute one on the step would take longer).
    return 1.0 + (math.log(v["stiffness"] / 30.0)) ** 2 + (math.log(v["damping"] / 2.0)) ** 2


def test_cmaes_stops_when_converged():
    toy = _Toy(_bowl)
    r = cmaes(toy, generations=200, batch=False)
    assert r.stop == "converged"
    assert 5 < len(r.history) < 60
    h = r.history
    assert h[-6] - h[-1] <= 1e-3 * h[-6]  # the criterion that stopped it
    assert r.loss < 1.0 + 1e-3
    assert abs(math.log(r.values["stiffness"] / 30.0)) < 0.05


def test_cmaes_runs_to_the_cap_while_the_loss_keeps_falling():
    # A loss that falls by 2 % with every evaluation, whatever the parameters: never converged.
    toy = _Toy(lambda p, v: 0.98**p.calls)
    r = cmaes(toy, generations=12, batch=False)
    assert r.stop == "cap" and len(r.history) == 12
    assert np.all(np.diff(r.history) < 0)
