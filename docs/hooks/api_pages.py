"""mkdocs hook: pages that only some branches have yet. API reference pages for pl.diff, pl.fit and
pl.gaussians exist (with their nav entries) exactly when the package does, and the guide pages other
branches write (``docs/gaussians.md``, ``docs/fit.md``) join the nav when present, so the site builds
strictly before and after those branches merge."""

from __future__ import annotations

from pathlib import Path

from mkdocs.structure.files import File

OPTIONAL = ("diff", "fit", "gaussians")
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


def on_files(files, config):
    for n in _present(config):
        if files.get_file_from_path(f"api/{n}.md") is None:
            files.append(File.generated(config, f"api/{n}.md", content=f"# pliant.{n}\n\n::: pliant.{n}\n"))
    return files
