"""Runs ``pliant/examples/cloth_drop.py``: the examples ship inside the package
(``python -m pliant.examples cloth_drop``); this wrapper keeps ``python examples/cloth_drop.py`` working."""

import runpy

runpy.run_module("pliant.examples.cloth_drop", run_name="__main__", alter_sys=True)
