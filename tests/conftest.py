"""Shared fixtures: the devices to test on (CPU always, CUDA when present), as Newton's tests do."""

from __future__ import annotations

import os

import pytest
import warp as wp

import pliant  # noqa: F401  (initialises Warp quietly)

# Tests that do not ask for a device run on the CPU everywhere, so a helper's bare wp.zeros(...) never lands
# on a GPU next to a CPU model; the `device` fixture below is how a test runs on CUDA too.
wp.set_device("cpu")

# No background compilation in the suite (tests/test_prebuild.py turns it on where it is the subject): a
# module built on a background thread would take whatever Warp config a test has set at that moment (the
# gradient tests' read-after-write checks), and the set of overloads compiled together would depend on
# which scenes ran before.
os.environ["PLIANT_PREBUILD"] = "0"

DEVICES = ["cpu"] + (["cuda:0"] if wp.is_cuda_available() else [])


@pytest.fixture(params=DEVICES)
def device(request: pytest.FixtureRequest) -> str:
    """Each available device in turn."""
    return request.param
