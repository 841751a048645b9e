"""The documentation: every public building call documents every parameter (with a unit where it has
one), every tutorial/how-to page's Python code runs and checks its physics, and the site builds strictly."""

from __future__ import annotations

import importlib.util
import inspect
import os
import re
import runpy
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

import pliant as pl

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
EXECUTED_PAGES = sorted((DOCS / "tutorials").glob("*.md")) + [DOCS / "howto.md"]

_SECTION = re.compile(r"^(\s*)(Args|Arguments|Parameters|Attributes):\s*$")
_ENTRY = re.compile(r"^(\*{0,2}\w+)(?:\s*\([^)]*\))?:\s*(.*)$")


def documented_parameters(doc: str) -> dict[str, str]:
    """Google-style ``Args:``/``Parameters:``/``Attributes:`` entries: name -> description (joined lines)."""
    out: dict[str, str] = {}
    lines = (doc or "").splitlines()
    i = 0
    while i < len(lines):
        m = _SECTION.match(lines[i])
        i += 1
        if not m:
            continue
        base = len(m.group(1))
        entry_indent = None
        name = None
        while i < len(lines):
            line = lines[i]
            if line.strip() == "":
                i += 1
                continue
            indent = len(line) - len(line.lstrip())
            if indent <= base:
                break
            if entry_indent is None:
                entry_indent = indent
            e = _ENTRY.match(line.strip()) if indent == entry_indent else None
            if e:
                name = e.group(1).lstrip("*")
                out[name] = e.group(2)
            elif name is not None:
                out[name] += " " + line.strip()
            i += 1
    return out


def _needs_unit(annotation: object) -> bool:
    # Physical quantities are floats (or sequences of them); names, flags, counts and indices are not.
    text = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", str(annotation))
    return "float" in str(text)


def _undocumented(func, doc: str) -> list[str]:
    params = documented_parameters(doc)
    problems = []
    for p in inspect.signature(func).parameters.values():
        if p.name == "self":
            continue
        if p.name not in params:
            problems.append(f"{p.name}: not documented")
        elif _needs_unit(p.annotation) and not re.search(r"\[[^\]]+\]", params[p.name]):
            problems.append(f"{p.name}: no [unit] in {params[p.name]!r}")
    return problems


def _building_calls():
    B = pl.ModelBuilder
    calls = [("ModelBuilder", B.__init__, B.__doc__)]
    calls += [
        (f"ModelBuilder.{n}", f, f.__doc__)
        for n, f in inspect.getmembers(B, inspect.isfunction)
        if n.startswith("add_") or n in ("pin", "finalize", "register_object")
    ]
    calls += [
        (f"Colliders.{n}", f, f.__doc__)
        for n, f in inspect.getmembers(pl.collision.Colliders, inspect.isfunction)
        if n.startswith("add_")
    ]
    E = pl.energies
    for cls in (E.TetElasticity, E.LinearElastic, E.StVK, E.Corotated, E.NeoHookean):
        calls.append((cls.__name__, cls.__init__, cls.__doc__))
    return calls


def test_parameter_parser_catches_a_missing_parameter():
    def f(length: float, n: int, name: str) -> None:
        """Example.

        Args:
            length: a length.
            n: how many
                (continued).
        """

    assert documented_parameters(f.__doc__) == {"length": "a length.", "n": "how many (continued)."}
    assert _undocumented(f, f.__doc__) == ["length: no [unit] in 'a length.'", "name: not documented"]


def test_building_calls_are_covered():
    names = {n for n, _, _ in _building_calls()}
    for must in (
        "ModelBuilder.add_cloth_grid",
        "ModelBuilder.add_rope",
        "ModelBuilder.add_soft_box",
        "ModelBuilder.add_tet_mesh",
        "ModelBuilder.add_point_cloud",
        "NeoHookean",
    ):
        assert must in names


@pytest.mark.parametrize("name,func,doc", _building_calls(), ids=[c[0] for c in _building_calls()])
def test_building_call_documents_every_parameter(name, func, doc):
    """Each parameter of each public building call is in its Args section, with a [unit] if it is a float."""
    problems = _undocumented(func, doc)
    assert not problems, f"{name}: " + "; ".join(problems)


def test_material_record_documents_its_fields():
    import dataclasses

    fields = [f.name for f in dataclasses.fields(pl.energies.Material)]
    params = documented_parameters(pl.energies.Material.__doc__)
    assert set(fields) <= set(params)
    for f in ("E", "density"):
        assert re.search(r"\[[^\]]+\]", params[f])


def code_blocks(page: Path) -> list[tuple[str, str]]:
    """(language, code) of each fenced ```python / ```bash block, in page order."""
    return re.findall(r"^```(python|bash)\n(.*?)^```", page.read_text(encoding="utf-8"), re.S | re.M)


def _run_command(line: str, cwd: Path) -> str:
    # `pliant ...` lines run this checkout's CLI as written (the console script is `python -m pliant.cli`);
    # returns what it printed.
    args = shlex.split(line, comments=True)
    assert args[0] == "pliant", f"only pliant commands are run from pages: {line!r}"
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    r = subprocess.run(
        [sys.executable, "-m", "pliant.cli", *args[1:]],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, f"{line!r} exited {r.returncode}:\n{r.stdout[-2000:]}{r.stderr[-2000:]}"
    return r.stdout


@pytest.mark.parametrize("page", EXECUTED_PAGES, ids=lambda p: p.stem)
def test_page_code_runs(page, tmp_path, monkeypatch):
    """Every ```python block of the page runs, in order, in one namespace, and every `pliant` command of its
    ```bash blocks runs and exits 0; tutorials check their own physics with assertions."""
    blocks = code_blocks(page)
    python = [code for lang, code in blocks if lang == "python"]
    assert python, f"{page.name} has no python blocks"
    if page.parent.name == "tutorials":
        assert sum(b.count("assert") for b in python) >= 3, f"{page.name}: a tutorial must check its physics"
    monkeypatch.chdir(tmp_path)  # pages write files (scenes, exports, trajectories)
    ns: dict = {"__name__": f"docs_{page.stem}"}
    for i, (lang, code) in enumerate(blocks):
        if lang == "python":
            exec(compile(code, f"{page.relative_to(ROOT)} [block {i + 1}]", "exec"), ns)
        else:
            for line in code.splitlines():
                if line.strip() and not line.lstrip().startswith("#"):
                    _run_command(line, tmp_path)
    check_page_figures(page, tmp_path)


#: Tutorials whose figures come from elsewhere (tutorial 1: `pliant study integrators`; tutorial 5: its
#: `pliant fit` writes fit.png).
FIGURES_ELSEWHERE = {"01_time_integration", "05_fitting"}


def check_page_figures(page: Path, ran_in: Path) -> None:
    """A tutorial shows a figure of its result, and each ``figures/tutorials/NAME`` it shows is written by
    its own code (as ``NAME`` in the folder it ran in). ``PLIANT_UPDATE_FIGURES=1`` copies them into
    docs/figures/tutorials/ (what the site shows); otherwise the committed copy must exist."""
    import shutil

    shown = re.findall(r"!\[[^\]]*\]\(\.\./figures/tutorials/([^)]+)\)", page.read_text(encoding="utf-8"))
    if page.parent.name == "tutorials" and page.stem not in FIGURES_ELSEWHERE:
        assert shown, f"{page.name}: a tutorial shows a figure of its result, made by its own code"
    for name in shown:
        made = ran_in / name
        assert made.is_file() and made.stat().st_size > 1000, f"{page.name}: its code did not write {name}"
        committed = DOCS / "figures" / "tutorials" / name
        if os.environ.get("PLIANT_UPDATE_FIGURES"):
            committed.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(made, committed)
        assert committed.is_file(), f"{committed} missing: run this test with PLIANT_UPDATE_FIGURES=1"


@pytest.mark.slow
def test_readme_python_runs_as_written(tmp_path, monkeypatch):
    """README.md's ```python blocks run in order in one namespace, exactly as written (the first simulates
    the demo cloth and renders it; the Gradients block checks its gradient against finite differences)."""
    blocks = [code for lang, code in code_blocks(ROOT / "README.md") if lang == "python"]
    assert len(blocks) >= 4 and any("import warp as wp" in b and "assert" in b for b in blocks)
    monkeypatch.chdir(tmp_path)
    # One file of the blocks in order (Warp reads a kernel's source from its file: exec() of a string
    # cannot define one), each headed by its block number for tracebacks.
    script = tmp_path / "readme_blocks.py"
    script.write_text("".join(f"# README.md python block {i + 1}\n{code}" for i, code in enumerate(blocks)))
    runpy.run_path(str(script), run_name="docs_readme")
    assert (tmp_path / "cloth.mp4").stat().st_size > 0


@pytest.mark.slow
def test_readme_fit_figures_are_what_the_commands_print(tmp_path):
    """The README's fitting commands, run as written, print the figures the README quotes."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    block = next(
        c for lang, c in code_blocks(ROOT / "README.md") if lang == "bash" and "pliant fit fit_rope" in c
    )
    printed = ""
    for line in block.splitlines():
        if line.startswith(("pliant observe", "pliant fit")):
            printed += _run_command(line, tmp_path)
    flat = " ".join(readme.split())  # the README wraps long quotes over lines
    for prefix in ("stiffness:", "damping_rate:", "track error:"):
        quoted = next(ln for ln in printed.splitlines() if ln.startswith(prefix))
        assert f"`{quoted}`" in flat, f"README does not quote {quoted!r}"


def test_every_page_is_in_the_nav():
    """Every page is in mkdocs.yml (nav or not_in_nav) or added by docs/hooks/api_pages.py."""
    text = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    hook = (DOCS / "hooks" / "api_pages.py").read_text(encoding="utf-8")
    optional = re.search(r"OPTIONAL_PAGES = \{(.*?)\}", hook).group(1)
    for page in DOCS.rglob("*.md"):
        rel = page.relative_to(DOCS).as_posix()
        assert rel in text or f'"{rel}"' in optional, f"docs/{rel} is neither in mkdocs.yml nor in the hook"


def test_site_builds_strict(tmp_path):
    """``mkdocs build --strict``: any warning (a broken link, a docstring griffe cannot parse) fails."""
    pytest.importorskip("mkdocs", reason="install the test extra: pip install -e '.[test]'")
    site = tmp_path / "site"
    r = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
        timeout=300,
    )
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    api = (site / "api" / "model" / "index.html").read_text(encoding="utf-8")
    assert "add_cloth_grid" in api and "youngs_modulus_thickness" in api
    for t in ("01_time_integration", "02_mass_spring", "03_pbd", "04_fem"):
        assert (site / "tutorials" / t / "index.html").exists()
    for pkg in ("diff", "fit", "gaussians", "sweep"):  # reference pages for packages from other branches
        assert (site / "api" / pkg / "index.html").exists() == (ROOT / "pliant" / pkg).is_dir()
    check_rendered_site(site)


RAW_ROLE = re.compile(r":(?:py:)?(?:func|class|meth|attr|mod|data|exc|obj|const|ref):(?:`|<code>)")


def check_rendered_site(site: Path) -> None:
    """No docstring markup shown raw (Sphinx roles, reST's ``Example::``), cross-references that resolve,
    and no script loaded from the network (MathJax is served by the site itself)."""
    pages = sorted(site.rglob("*.html"))
    problems, resolved = [], 0
    for page in pages:
        text = page.read_text(encoding="utf-8")
        rel = page.relative_to(site).as_posix()
        problems += [f"{rel}: raw role {m.group(0)!r}" for m in RAW_ROLE.finditer(text)]
        problems += [f"{rel}: reST '::'" for _ in re.finditer(r"::</p>", text)]
        problems += [
            f"{rel}: remote script {m}" for m in re.findall(r"<script[^>]*src=\"(?:https?:)?//[^\"]*", text)
        ]
        if rel.startswith("api/"):
            resolved += text.count("autorefs-internal")
    assert not problems, "\n".join(problems[:40])
    assert resolved > 150, f"only {resolved} cross-references in the API pages resolve"
    index = (site / "index.html").read_text(encoding="utf-8")
    assert "assets/mathjax/tex-mml-chtml.js" in index
    assert (site / "assets" / "mathjax" / "tex-mml-chtml.js").stat().st_size > 500_000
    assert list((site / "assets" / "mathjax" / "output" / "chtml" / "fonts" / "woff-v2").glob("*.woff"))


def test_role_conversion_of_the_hook():
    """docs/hooks/api_pages.py turns a rendered Sphinx role into an autorefs reference to the full path."""
    spec = importlib.util.spec_from_file_location("api_pages", DOCS / "hooks" / "api_pages.py")
    hook = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hook)
    out = hook.convert_roles(
        "<p>see :class:<code>~pliant.sim.Simulator</code> and :func:<code>rollout</code>::</p>", "pliant.diff"
    )
    assert out == (
        '<p>see <autoref identifier="pliant.sim.Simulator" optional><code>Simulator</code></autoref> and '
        '<autoref identifier="pliant.diff.rollout" optional><code>rollout()</code></autoref>:</p>'
    )
    assert not RAW_ROLE.search(out)


def test_home_page_links_every_tutorial_and_guide():
    home = (DOCS / "index.md").read_text(encoding="utf-8")
    for page in sorted((DOCS / "tutorials").glob("*.md")) + [
        DOCS / n for n in ("fit.md", "gaussians.md", "sweep.md")
    ]:
        if page.exists():
            assert f"({page.relative_to(DOCS).as_posix()})" in home, page.name


def test_no_garbled_formulas():
    """Subscript parentheses (U+208D, U+208E) are what a ``_(j<i)`` became once: write maths as $...$."""
    for page in sorted(DOCS.rglob("*.md")) + [ROOT / "README.md"]:
        text = page.read_text(encoding="utf-8")
        assert "\u208d" not in text and "\u208e" not in text, page.name
