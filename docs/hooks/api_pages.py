"""mkdocs hook: API reference pages for packages that only some branches have yet (pl.diff, pl.fit,
pl.gaussians). A page, and its nav entry, exist exactly when the package does, so the site builds strictly
before and after those branches merge."""

from __future__ import annotations

from pathlib import Path

from mkdocs.structure.files import File

OPTIONAL = ("diff", "fit", "gaussians")
SECTION = "API reference"


def _present(config) -> list[str]:
    root = Path(config.config_file_path).parent
    return [n for n in OPTIONAL if (root / "pliant" / n / "__init__.py").is_file()]


def on_config(config):
    for entry in config.nav or []:
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
