"""Runs ``pliant/examples/fit_rope.py``: the examples ship inside the package
(``python -m pliant.examples fit_rope``); this wrapper keeps ``python examples/fit_rope.py`` working."""

import runpy

runpy.run_module("pliant.examples.fit_rope", run_name="__main__", alter_sys=True)
