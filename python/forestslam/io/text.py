"""Reading a user's text file (tree CSV, manifest, profile): a binary or non-UTF-8 file is an
InputError naming it, never a UnicodeDecodeError."""

from __future__ import annotations

from pathlib import Path

from forestslam.errors import InputError


def read_input_text(path: str | Path, kind: str) -> str:
    """The UTF-8 text of `path` (a `kind` file, e.g. "tree CSV"); InputError when it is not."""
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{path}: not a {kind} (not UTF-8 text: bad byte at offset {exc.start})"
        ) from None
    except IsADirectoryError:
        raise InputError(f"{path}: a directory, not a {kind}") from None
