"""File names: one identity for "the same file" and one way to show a name in a message.

Two names are the same file when they reach the same inode of the same device (hard links,
symbolic links, ``./x`` and ``x``, an absolute spelling): :func:`file_identity`,
:func:`same_file`. A name that does not exist yet is identified by its resolved path.

A file name is bytes on POSIX; Python holds the bytes that are not UTF-8 as lone surrogates
(``os.fsdecode``), which no UTF-8 text (a message, a JSON or YAML file) can hold.
:func:`path_text` renders a name as text with such bytes, and control characters, written
``\\xff`` (as ``ls`` and Python's ``repr`` show them); :func:`path_from_text` is its
inverse, for a name recorded that way in a file pkmcal wrote.
"""

from __future__ import annotations

import os
import re

__all__ = ["file_identity", "path_from_text", "path_text", "recorded_path", "same_file",
           "undecodable_escaped"]


def file_identity(path) -> tuple:
    """What identifies the file ``path`` names: ``("inode", st_dev, st_ino)`` when it exists
    (following symbolic links), else ``("path", resolved path)``.

    Parameters
    ----------
    path : str or os.PathLike
        A file name.

    Returns
    -------
    tuple
        Equal for two names of one file (hard links, symbolic links, relative and absolute
        spellings), different otherwise.
    """
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        try:
            return ("path", os.path.realpath(os.fspath(path)))
        except (OSError, ValueError, RuntimeError):    # a symbolic-link loop (3.11)
            return ("path", os.path.abspath(os.fspath(path)))
    return ("inode", st.st_dev, st.st_ino)


def same_file(a, b) -> bool:
    """Whether the names ``a`` and ``b`` are one file (see :func:`file_identity`).

    Parameters
    ----------
    a, b : str or os.PathLike
        File names.

    Returns
    -------
    bool
        True for two names of one file.
    """
    return file_identity(a) == file_identity(b)


def _escape(ch: str) -> str:
    code = ord(ch)
    if 0xDC80 <= code <= 0xDCFF:         # a byte that is not UTF-8 (os.fsdecode)
        return f"\\x{code - 0xDC00:02x}"
    if code < 0x20 or code == 0x7F:      # a control character: one line, no terminal codes
        return f"\\x{code:02x}"
    if 0xD800 <= code <= 0xDFFF:         # any other lone surrogate
        return f"\\u{code:04x}"
    return ch


_NEEDS_ESCAPE = re.compile("[\x00-\x1f\x7f\ud800-\udfff]")


def path_text(path) -> str:
    """A file name as text for a message or a record: printable UTF-8, bytes that are not
    UTF-8 and control characters written ``\\xNN``.

    Parameters
    ----------
    path : str, bytes or os.PathLike
        A file name.

    Returns
    -------
    str
        The name as given (no resolution), escaped where needed; encodable as UTF-8.

    Examples
    --------
    >>> path_text(b"out-\\xff.yaml")
    'out-\\\\xff.yaml'
    """
    text = os.fsdecode(path) if isinstance(path, (bytes, os.PathLike)) else str(path)
    if not _NEEDS_ESCAPE.search(text):
        return text
    return _NEEDS_ESCAPE.sub(lambda m: _escape(m.group()), text)


_ESCAPED = re.compile(r"\\x([0-9a-fA-F]{2})")


def path_from_text(text: str) -> str:
    """The file name :func:`path_text` rendered as ``text`` (``\\xNN`` back to its byte).

    Parameters
    ----------
    text : str
        A name recorded by :func:`path_text`.

    Returns
    -------
    str
        The name, bytes that are not UTF-8 as ``os.fsdecode`` holds them.
    """
    if "\\x" not in text:
        return text

    def byte(m):
        code = int(m.group(1), 16)
        return chr(code) if code < 0x80 else chr(0xDC00 + code)

    return _ESCAPED.sub(byte, text)


_UNDECODABLE = re.compile("[\ud800-\udfff]")


def undecodable_escaped(text: str) -> str:
    """``text`` with the bytes of file names that are not UTF-8 written ``\\xNN`` (as
    :func:`path_text` writes them), everything else kept (line breaks, terminal codes): what
    reaches the terminal cannot fail to encode, whichever message named a file.

    Parameters
    ----------
    text : str
        Output text (a table, a "wrote ..." line).

    Returns
    -------
    str
        The text, encodable as UTF-8.
    """
    if not _UNDECODABLE.search(text):
        return text
    return _UNDECODABLE.sub(lambda m: _escape(m.group()), text)


def recorded_path(directory, text: str):
    """The file a record (a calibrated file's ``calibration.report``) names in
    ``directory``: the name as written when such a file exists (a name that holds a
    backslash), else the name :func:`path_text` rendered as ``text``.

    Parameters
    ----------
    directory : str or os.PathLike
        Where the named file lies (the recording file's directory).
    text : str
        The recorded name.

    Returns
    -------
    pathlib.Path
        The file's path (it may not exist).
    """
    from pathlib import Path

    literal = Path(directory) / text
    if os.path.lexists(literal):
        return literal
    return Path(directory) / path_from_text(text)
