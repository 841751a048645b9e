"""The pip command that installs one of pliant's optional extras, as this installation needs it."""

from __future__ import annotations

from pathlib import Path


def checkout_root() -> Path | None:
    """The source checkout pliant runs from (its ``pyproject.toml`` beside the package), else None."""
    root = Path(__file__).resolve().parents[1]
    return root if (root / "pyproject.toml").is_file() and (root / ".git").exists() else None


def pip_install(extra: str) -> str:
    """``pip install 'pliant[extra]'``, or in a checkout ``pip install -e '.[extra]'`` (run in the checkout:
    ``pliant[extra]`` would fetch another pliant from the index instead of adding to this one).

    Args:
        extra: the optional extra's name in pyproject.toml (``viewer``, ``usd``, ``torch``, ``ray`` ...).
    """
    root = checkout_root()
    if root is None:
        return f"pip install 'pliant[{extra}]'"
    return f"pip install -e '.[{extra}]' (in {root})"


def missing_ray(flag: str = "--ray") -> str | None:
    """The one-line error when Ray (the ``ray`` extra) cannot be imported, naming ``flag`` and the pip
    command; None when it can."""
    try:
        import ray  # noqa: F401
    except ImportError:
        return f"{flag} needs Ray, an optional extra: {pip_install('ray')}"
    return None


__all__ = ["checkout_root", "missing_ray", "pip_install"]
