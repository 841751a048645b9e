"""Contracts every registered integrator meets (``pl.integrators.registered_integrators``).

The per-integrator tests parametrise over the registry, so a new integrator is tested without editing a
list: its declared order on the oscillator (tests/test_integrators_ode.py) and on a spring model, its
momentum on a free body (tests/test_integrators_physical.py), its gradient against finite differences
when explicit (tests/test_gradients.py). This file checks the registry itself and shows that a wrong
declaration is caught."""

from __future__ import annotations

import gc

import numpy as np
import pytest

import pliant as pl
from tests.helpers import ALL_INTEGRATORS, check_ode_order

I = pl.integrators


def test_registry_lists_every_public_integrator():
    """Every Integrator exported by pl.integrators that can be made without arguments is registered."""
    exported = {
        getattr(I, n)
        for n in I.__all__
        if isinstance(getattr(I, n), type) and issubclass(getattr(I, n), I.Integrator)
    }
    needs_args = {I.ExplicitRK, I.Integrator}
    assert exported - needs_args == set(I.ALL_INTEGRATORS)
    assert {type(i) for i in ALL_INTEGRATORS} == set(I.ALL_INTEGRATORS)


@pytest.mark.parametrize("cls", I.ALL_INTEGRATORS, ids=lambda c: c.__name__)
def test_flags(cls):
    """Order is a positive integer, ``explicit`` a bool, and only explicit integrators lack a minimiser."""
    integ = cls()
    assert isinstance(integ.order, int) and integ.order >= 1
    assert isinstance(cls.explicit, bool)
    assert isinstance(integ.name, str) and integ.name


def test_a_wrong_declared_order_is_caught():
    """An integrator that declares order 2 but is forward Euler is registered and fails the order
    contract; a correct declaration passes it."""

    class ClaimsSecondOrder(I.ForwardEuler):
        order = 2

    try:
        assert ClaimsSecondOrder in I.registered_integrators()
        with pytest.raises(AssertionError, match="measured order 1.0"):
            check_ode_order(ClaimsSecondOrder())
        assert abs(check_ode_order(I.ForwardEuler()) - 1.0) < 0.15
    finally:
        del ClaimsSecondOrder
        gc.collect()  # __subclasses__ holds weak references: the registry forgets it
    assert all(c.__name__ != "ClaimsSecondOrder" for c in I.registered_integrators())


def test_registry_sorted_and_unique():
    names = [c.__name__ for c in I.ALL_INTEGRATORS]
    assert names == sorted(names) and len(set(names)) == len(names)
    assert np.all([issubclass(c, I.Integrator) for c in I.ALL_INTEGRATORS])
