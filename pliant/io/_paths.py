"""Output paths confined to an output folder: every file pliant writes for a run or an export.

Defence in depth: the scene layer already checks that a scene name is one safe file-name component; here
every output path is resolved (symbolic links followed) and refused unless it lies directly in the output
folder, before any work is done.
"""

from __future__ import annotations

import os
from pathlib import Path

#: Longest file-name component (in UTF-8 bytes) an output *stem* may have: the file system's 255 bytes
#: less the longest suffix pliant adds (".render.npz", ".ckpt.npz") and the temporary file's extra
#: characters (atomic writes go through "<name><8 random>.tmp.npz").
MAX_STEM_BYTES = 200


class OutputPathError(ValueError):
    """An output name or folder that would write outside the output folder, or that no file system takes."""


def check_file_stem(name: str, what: str = "name", max_bytes: int = MAX_STEM_BYTES) -> str:
    """``name`` if it is one safe file-name component, else :class:`OutputPathError` saying why.

    Safe: non-empty, at most :data:`MAX_STEM_BYTES` UTF-8 bytes, no path separator, no NUL or other control
    character, not "." or "..".
    """
    if not isinstance(name, str) or not name:
        raise OutputPathError(f"{what} is empty; give a file name such as 'my_run'")
    bad = sorted({c for c in name if ord(c) < 32 or c == "\x7f" or c in "/\\" or c == os.sep})
    if bad or name in (".", ".."):
        shown = ", ".join(repr(c) for c in bad) or repr(name)
        raise OutputPathError(
            f"{what} {name[:60]!r} is not a plain file name ({shown}); outputs go into the output folder, "
            "use letters, digits, '_', '-' and '.' only"
        )
    size = len(name.encode("utf-8", "surrogatepass"))
    if size > max_bytes:
        raise OutputPathError(
            f"{what} is {size} bytes long; at most {max_bytes} fit a file name with pliant's suffixes"
        )
    return name


def check_out_dir(out: str | os.PathLike) -> Path:
    """The output folder as a resolved Path (it may not exist yet), or :class:`OutputPathError`."""
    text = os.fspath(out)
    if not text or "\x00" in text:
        raise OutputPathError(f"--out {text!r} is not a usable folder name")
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise OutputPathError(f"--out {path} exists and is not a folder; give a folder for the outputs")
    try:
        return path.resolve()
    except (OSError, RuntimeError) as exc:  # a symlink loop, a name too long
        raise OutputPathError(f"--out {path}: {exc}") from None


def check_writable_dir(out: str | os.PathLike) -> Path:
    """Create the output folder (and its parents) if needed and check that a file can be written in it, so
    that a read-only or forbidden ``--out`` is an error before a simulation runs, not after it.

    Args:
        out: the output folder.

    Returns:
        The resolved folder.

    Raises:
        OutputPathError: the folder cannot be created or written to (the message names it and the fix).
    """
    import tempfile

    root = check_out_dir(out)
    try:
        root.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=root):
            pass
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise OutputPathError(
            f"--out {os.fspath(out)}: cannot write there ({reason}); choose a folder you can write to"
        ) from None
    return root


def confined(out: str | os.PathLike, filename: str) -> Path:
    """``out / filename``, refused unless it resolves (symbolic links followed) to a file directly in
    ``out``. Checks ``filename``'s stem with :func:`check_file_stem` first."""
    root = check_out_dir(out)
    # 255 bytes per name on common file systems, less the temporary file's 16 extra characters.
    check_file_stem(filename, "output file name", 255 - 16)
    path = root / filename
    try:
        real = path.resolve()
    except (OSError, RuntimeError) as exc:
        raise OutputPathError(f"{path}: {exc}") from None
    if real.parent != root:
        raise OutputPathError(
            f"output {path} resolves to {real}, outside the output folder {root} (a symbolic link?); "
            "remove that link or choose another --out"
        )
    return path


__all__ = [
    "MAX_STEM_BYTES",
    "OutputPathError",
    "check_file_stem",
    "check_out_dir",
    "check_writable_dir",
    "confined",
]
