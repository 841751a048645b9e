"""Runs ``pliant/examples/gradients.py``: the examples ship inside the package
(``python -m pliant.examples gradients``); this wrapper keeps ``python examples/gradients.py`` working."""

import runpy

runpy.run_module("pliant.examples.gradients", run_name="__main__", alter_sys=True)
