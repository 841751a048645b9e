"""Runs ``pliant/examples/free_fall.py``: the examples ship inside the package
(``python -m pliant.examples free_fall``); this wrapper keeps ``python examples/free_fall.py`` working."""

import runpy

runpy.run_module("pliant.examples.free_fall", run_name="__main__", alter_sys=True)
