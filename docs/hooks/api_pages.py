"""mkdocs hook: pages that only some branches have yet, and the docstrings' Sphinx markup.

Sphinx roles in docstrings (``:func:`rollout```, ``:class:`~pliant.sim.Simulator```) become cross-references
(mkdocs-autorefs resolves them to the object's entry), and ``Example::`` loses its reST double colon.

Pages that only some branches have yet. API reference pages for pl.diff, pl.fit and
pl.gaussians exist (with their nav entries) exactly when the package does, and the guide pages other
branches write (``docs/gaussians.md``, ``docs/fit.md``) join the nav when present, so the site builds
strictly before and after those branches merge."""

from __future__ import annotations

import html as _html
import importlib
import re
from functools import cache
from pathlib import Path

from mkdocs.structure.files import File

OPTIONAL = ("diff", "fit", "gaussians", "sweep")
SECTION = "API reference"
#: Guide pages written on other branches: file -> nav title, placed before the API reference.
OPTIONAL_PAGES = {"fit.md": "Fitting", "gaussians.md": "Gaussian splats", "sweep.md": "Parameter sweeps"}


def _present(config) -> list[str]:
    root = Path(config.config_file_path).parent
    return [n for n in OPTIONAL if (root / "pliant" / n / "__init__.py").is_file()]


def on_config(config):
    docs = Path(config.docs_dir)
    nav = config.nav or []
    listed = {v for entry in nav if isinstance(entry, dict) for v in entry.values() if isinstance(v, str)}
    at = next((i for i, e in enumerate(nav) if isinstance(e, dict) and SECTION in e), len(nav))
    for page, title in OPTIONAL_PAGES.items():
        if (docs / page).is_file() and page not in listed:
            nav.insert(at, {title: page})
            at += 1
    for entry in nav:
        if isinstance(entry, dict) and SECTION in entry:
            pages = entry[SECTION]
            listed = {p for item in pages for p in item.values()}
            pages += [{f"pliant.{n}": f"api/{n}.md"} for n in _present(config) if f"api/{n}.md" not in listed]
    return config


#: What MathJax 3's tex-mml-chtml component loads, relative to the package's es5/ folder (the speech rule
#: engine, 3.9 MB, is left out: it loads only when a reader turns on the explorer in MathJax's menu).
MATHJAX_PARTS = ("tex-mml-chtml.js", "output/chtml/fonts", "input/tex/extensions", "ui", "a11y")


def mathjax_files() -> list[tuple[str, Path]]:
    """(site path, file) for the MathJax files the site serves, from the ``django-static-mathjax`` package
    (static files only; install the docs extra). No CDN: formulas render offline."""
    try:
        import mathjax
    except ImportError:
        raise RuntimeError(
            "the docs need MathJax from the django-static-mathjax package: pip install -e '.[docs]'"
        ) from None
    es5 = Path(mathjax.__file__).parent / "static" / "mathjax" / "es5"
    out = []
    for part in MATHJAX_PARTS:
        base = es5 / part
        for f in sorted([base] if base.is_file() else base.rglob("*")):
            if f.is_file():
                out.append((f"assets/mathjax/{f.relative_to(es5).as_posix()}", f))
    return out


def on_files(files, config):
    for uri, path in mathjax_files():
        if files.get_file_from_path(uri) is None:
            files.append(File.generated(config, uri, abs_src_path=str(path)))
    for n in _present(config):
        if files.get_file_from_path(f"api/{n}.md") is None:
            files.append(File.generated(config, f"api/{n}.md", content=f"# pliant.{n}\n\n::: pliant.{n}\n"))
    return files


#: A Sphinx role as Markdown renders it: ``:func:`name``` → ``:func:<code>name</code>``.
ROLE = re.compile(r":(?:py:)?(func|class|meth|attr|mod|data|exc|obj|const|ref):<code>([^<]+)</code>")
#: reST's "paragraph ending in ::" (a literal block follows): Markdown shows both colons.
DOUBLE_COLON = re.compile(r"::</p>")


@cache
def _exists(path: str) -> bool:
    """Whether ``path`` (``pliant.sim.Simulator.run``) names an importable module or attribute."""
    parts = path.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for name in parts[cut:]:
            if not hasattr(obj, name):
                return False
            obj = getattr(obj, name)
        return True
    return False


def _identifier(target: str, module: str | None) -> str | None:
    """The full dotted path of a role's target as written in a docstring of ``module``'s page."""
    name = target.lstrip("~.").strip()
    if name.startswith("pl."):
        name = "pliant." + name[3:]
    candidates = [name] if name.startswith("pliant") else []
    if module:
        candidates.append(f"{module}.{name}")
    candidates += [f"pliant.{pkg}.{name}" for pkg in _PACKAGES] + [f"pliant.{name}"]
    return next((c for c in candidates if _exists(c)), None)


_PACKAGES = (
    "model",
    "integrators",
    "energies",
    "constraints",
    "collision",
    "solvers",
    "sim",
    "io",
    "scene",
    "render",
    "geometry",
    "diff",
    "fit",
    "gaussians",
    "sweep",
)


def convert_roles(html: str, module: str | None = None) -> str:
    """Sphinx roles → autorefs cross-references (``optional``: an object without an entry of its own is
    shown as code, not a warning); ``Example::`` → ``Example:``."""

    def ref(m: re.Match) -> str:
        role, target = m.group(1), _html.unescape(m.group(2))
        shown = target.lstrip("~").split(".")[-1] if target.startswith("~") else target.lstrip(".")
        shown += "()" if role in ("func", "meth") and not shown.endswith(")") else ""
        full = _identifier(target, module)
        code = f"<code>{_html.escape(shown)}</code>"
        if full is None:
            return code
        return f'<autoref identifier="{full}" optional>{code}</autoref>'

    return DOUBLE_COLON.sub(":</p>", ROLE.sub(ref, html))


def on_page_content(html, page, config, files):
    src = page.file.src_uri
    module = f"pliant.{src[4:-3]}" if src.startswith("api/") and src.endswith(".md") else None
    return convert_roles(html, module)
