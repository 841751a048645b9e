"""Runs ``pliant/examples/rope_swing.py``: the examples ship inside the package
(``python -m pliant.examples rope_swing``); this wrapper keeps ``python examples/rope_swing.py`` working."""

import runpy

runpy.run_module("pliant.examples.rope_swing", run_name="__main__", alter_sys=True)
