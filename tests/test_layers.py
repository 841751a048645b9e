"""The package's layering (docs/design.md, "Layers"): every import inside pliant points down.

Walks every module's imports with ``ast``, function-level ones included, and fails on an import of a higher
layer. Layers, bottom to top:

    _warp → geometry → model → integrators / energies / constraints / collision → solvers → io → sim
    → render → scene → diff / fit / gaussians / sweep → studies / bench / cli / live → pliant/__init__.py
    → examples (user code on the public surface)

Modules of one layer may import each other.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent / "pliant"

LAYERS: list[tuple[str, ...]] = [
    ("_warp", "_prebuild", "_blas", "_extras", "_subclasses", "_time"),
    ("geometry",),
    ("model",),
    ("integrators", "energies", "constraints", "collision"),
    ("solvers",),
    ("io",),  # trajectory and checkpoint files: plain NumPy, written by the Simulator
    ("sim",),
    ("render",),
    ("scene",),
    ("diff", "fit", "gaussians", "sweep"),
    ("studies", "bench", "cli", "live"),  # live: the live viewer (uses fit's parameter arrays, splats)
    ("",),  # pliant/__init__.py: the public surface, on top of the library
    ("examples",),  # user code shipped with the package: it uses the public surface (`import pliant as pl`)
]
LEVEL = {name: i for i, names in enumerate(LAYERS) for name in names}

#: Known upward imports (importer module, imported subpackage), each with the reason it is tolerated.
ALLOWED = {
    # `pliant info` prints pliant.__version__ through `import pliant` (the package is loaded anyway when the
    # CLI runs; pliant/__init__.py never imports the CLI, so there is no cycle).
    ("pliant.cli._misc", ""),
}


def _top(module: str) -> str:
    """The subpackage (layer key) of a dotted ``pliant...`` module name; "" for the package itself."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, imported pliant module) of every import in ``path``, at any depth."""
    rel = path.relative_to(ROOT.parent).with_suffix("")
    module = ".".join(rel.parts)
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    package = package.removesuffix(".__init__")
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names if a.name.split(".")[0] == "pliant"]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != "pliant":
                continue
            if target == "pliant":  # from pliant import X: X is a subpackage or a top-level name
                for a in node.names:
                    sub = "pliant." + a.name
                    out.append((node.lineno, sub if _top(sub) in LEVEL else _top_name_home(a.name)))
            else:  # from P import a: the submodule P.a when there is one (the cycle test needs it), else P
                out += [(node.lineno, _submodule(target, a.name)) for a in node.names]
    return out


def _submodule(package: str, name: str) -> str:
    """``package.name`` when that is a module or subpackage of pliant, else ``package`` (a name in it)."""
    path = ROOT.parent.joinpath(*package.split("."), name)
    is_module = path.with_suffix(".py").exists() or (path / "__init__.py").exists()
    return f"{package}.{name}" if is_module else package


def _top_name_home(name: str) -> str:
    """Where ``pliant.<name>`` comes from: the subpackage ``pliant/__init__.py`` imports it from, or the
    base layer for a constant defined there (``__version__``), or ``pliant`` itself when unknown."""
    init = ROOT / "__init__.py"
    for node in ast.walk(ast.parse(init.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.level == 1 and node.module:
            if any((a.asname or a.name) == name for a in node.names):
                return "pliant." + node.module
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == name for t in node.targets):
            return "pliant._warp"
    return "pliant"


def _module_name(path: Path) -> str:
    return ".".join(path.relative_to(ROOT.parent).with_suffix("").parts).removesuffix(".__init__")


def upward_imports() -> list[str]:
    """Every import of a higher layer, as ``file:line: importer -> imported`` (allowed ones excluded)."""
    bad = []
    for path in sorted(ROOT.rglob("*.py")):
        me = _module_name(path)
        mine = _top(me)
        if mine not in LEVEL:
            bad.append(f"{path}: subpackage {mine!r} has no layer; add it to LAYERS and docs/design.md")
            continue
        for line, target in _imports(path):
            theirs = _top(target)
            if theirs not in LEVEL:
                bad.append(f"{path}:{line}: {target} is in no layer")
            elif LEVEL[theirs] > LEVEL[mine] and (me, theirs) not in ALLOWED:
                bad.append(f"{path}:{line}: {me} ({mine or 'pliant'}) imports {target} (a higher layer)")
    return bad


def test_no_upward_imports():
    """No module imports a module of a higher layer (docs/design.md), function-level imports included."""
    bad = upward_imports()
    assert not bad, "upward imports:\n" + "\n".join(bad)


def test_the_walk_sees_function_level_and_relative_imports(tmp_path, monkeypatch):
    """The checker is not vacuous: a function-level relative import of ``sim`` from ``model`` is reported."""
    fake = tmp_path / "pliant"
    (fake / "model").mkdir(parents=True)
    (fake / "__init__.py").write_text("")
    (fake / "model" / "__init__.py").write_text("")
    (fake / "model" / "_x.py").write_text("def f():\n    from ..sim import Simulator\n    return Simulator\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", fake)
    bad = upward_imports()
    assert len(bad) == 1 and "_x.py:2: pliant.model._x (model) imports pliant.sim" in bad[0], bad


def test_allowed_exceptions_are_still_needed():
    """Each tolerated upward import still exists (a stale exception would hide a new one)."""
    seen = set()
    for path in ROOT.rglob("*.py"):
        me = _module_name(path)
        for _, target in _imports(path):
            if (me, _top(target)) in ALLOWED:
                seen.add((me, _top(target)))
    assert seen == ALLOWED, f"no longer needed: {ALLOWED - seen}"


@pytest.mark.parametrize("sub", sorted(p.name for p in ROOT.iterdir() if (p / "__init__.py").exists()))
def test_every_subpackage_has_a_layer(sub):
    """Every subpackage of pliant is placed in a layer."""
    assert sub in LEVEL


def test_no_source_file_over_the_size_limit():
    """Issue 10: no source file over ~600 lines (a long file is usually two ideas)."""
    long = {
        str(p.relative_to(ROOT.parent)): n
        for p in ROOT.rglob("*.py")
        if (n := p.read_text(encoding="utf-8").count("\n")) > 620
    }
    assert not long, f"split these files: {long}"
