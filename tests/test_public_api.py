"""``pliant.__all__`` (issue 26, item 4): it names everything ``pliant/__init__.py`` exposes, every name in
it resolves, and every public sub-package of ``pliant/`` is in it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pliant

ROOT = Path(pliant.__file__).resolve().parent

#: Public sub-packages left out of ``pliant.__all__``, each with its reason.
NOT_EXPORTED = {
    # User code shipped with the package, on top of the public surface (tests/test_layers.py puts it above
    # pliant/__init__.py): `python -m pliant.examples NAME`, never `pl.examples`.
    "examples": "above the public surface",
}


def _public_subpackages() -> set[str]:
    return {p.name for p in ROOT.iterdir() if (p / "__init__.py").exists() and not p.name.startswith("_")}


def test_all_lists_every_public_subpackage_and_exposed_name():
    """Every public sub-package on disk and every lazily exposed class is in ``__all__``, and nothing else."""
    subs = _public_subpackages() - set(NOT_EXPORTED)
    assert set(NOT_EXPORTED) <= _public_subpackages(), "a NOT_EXPORTED entry is no sub-package any more"
    assert subs <= set(pliant.__all__), f"missing from pliant.__all__: {sorted(subs - set(pliant.__all__))}"
    assert set(pliant._SUBMODULES) == subs, "pliant._SUBMODULES and the sub-packages on disk differ"
    exposed = {*pliant._LAZY, *pliant._SUBMODULES, "__version__"}
    assert set(pliant.__all__) == exposed, (
        f"not exposed: {sorted(set(pliant.__all__) - exposed)}; not in __all__: "
        f"{sorted(exposed - set(pliant.__all__))}"
    )
    assert len(pliant.__all__) == len(set(pliant.__all__)), "a name is listed twice"


def test_every_name_in_all_resolves():
    """``from pliant import *`` works in a fresh process: each name resolves (sub-packages to modules of
    that name, classes to the classes of their modules)."""
    code = (
        "import types, pliant\n"
        "ns = {}\n"
        "exec('from pliant import *', ns)\n"
        "for n in pliant.__all__:\n"
        "    v = ns[n]\n"
        "    if n in pliant._SUBMODULES:\n"
        "        assert isinstance(v, types.ModuleType) and v.__name__ == 'pliant.' + n, n\n"
        "    elif n in pliant._LAZY:\n"
        "        assert v.__name__ == n and v.__module__.startswith('pliant.' + pliant._LAZY[n]), n\n"
        "print(len(pliant.__all__))\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT.parent)
    assert res.returncode == 0, res.stderr
    assert int(res.stdout.strip().splitlines()[-1]) == len(pliant.__all__)
