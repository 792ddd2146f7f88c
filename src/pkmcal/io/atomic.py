"""File access: atomic output (a reader never sees a half-written file, a failure leaves no
file) and input text with clear errors.

Every file the toolkit writes goes through :func:`atomic_write_text`: the text is written to a
temporary file in the destination directory, flushed to disk, then moved over the destination
with :func:`os.replace` (atomic on POSIX and Windows within one file system).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from ..errors import InputError


def _default_mode() -> int:
    """Permissions a plain ``open(path, 'w')`` would give: ``0o666`` minus the umask."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def atomic_write_text(path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically; return the path.

    The text goes to a temporary file in the destination directory, is flushed to disk and
    moved over the destination. The destination keeps its permissions when it exists (else
    the umask default applies); the temporary file is removed on any failure.

    Parameters
    ----------
    path : str or os.PathLike
        Destination file.
    text : str
        Content.
    encoding : str, optional
        Text encoding.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    FileNotFoundError
        When the destination directory does not exist.
    IsADirectoryError
        When ``path`` is a directory.
    """
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise FileNotFoundError(f"{path}: the output directory {directory} does not exist")
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a directory, expected a file name")
    try:
        mode = path.stat().st_mode & 0o7777
    except FileNotFoundError:
        mode = _default_mode()
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding=encoding, newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    return path


def read_input_text(path, kind: str) -> str:
    """Text of an input file (UTF-8, BOM allowed); :class:`InputError` naming the file when it
    is missing, a directory or not text. ``kind`` says what was expected ("machine file")."""
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError(f"{path}: {kind} not found") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, expected a {kind}") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a text file (UTF-8): {exc.reason}") from None
