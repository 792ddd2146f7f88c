"""File access: a command's outputs appear all together or not at all, and never over an input.

Every file the toolkit writes goes through :func:`atomic_write_bytes` (or its text twin
:func:`atomic_write_text`). Outside an output set this writes one file atomically. Inside an
:class:`OutputSet` (every ``pkmcal`` command runs in one) the file is only *staged*: written
to a uniquely named hidden temporary beside its destination and flushed to disk; the set is
*committed* at its end, when every staged file is moved over its destination with
:func:`os.replace` (atomic on POSIX within one file system):

- before the first rename, every output is checked against every file the command read
  (:func:`read_input_text` registers them by device and inode, so symbolic and hard links
  are caught too) and against the other outputs;
- the renames of one set run with SIGINT/SIGTERM held back and under a lock of the
  destination directories, so two runs at once commit one after the other and a reader sees
  either the previous set or the new one, never a mix; a destination that existed is kept as
  a hard-linked backup until the whole set is in place, and restored if a rename fails;
- on an error or an interrupt before the commit, the temporaries are removed and no output
  directory has been created: nothing of the new set remains, the previous set is untouched;
- a destination that is not a regular file (``/dev/null``, a FIFO, ``/dev/stdout``) is
  written into, never replaced, and needs no writable directory;
- temporaries are named ``.<name>.pkmcal-<pid>-<random>.tmp``: unique per run, hidden, never
  mistaken for output. Those left by a killed process (``kill -9``) are removed by the next
  output set that writes to the same directory.

Messages name the user's file, never a temporary.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import re
import secrets
import signal
import stat
import tempfile
import threading
from pathlib import Path

from ..errors import InputError, stop_if_signalled
from ..paths import file_identity, path_text

_TAG = "pkmcal"
_NEW = Path("/nonexistent/pkmcal-new-file")    # marker: the destination did not exist
_STALE = re.compile(r"^\..+\.pkmcal-(\d+)-[^.]+\.(tmp|bak)$")
_ACTIVE: contextvars.ContextVar[OutputSet | None] = contextvars.ContextVar(
    "pkmcal_output_set", default=None)


def _default_mode() -> int:
    """Permissions a plain ``open(path, 'w')`` would give: ``0o666`` minus the umask."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def _temporary_prefix(dest: Path) -> str:
    """``.<name>.pkmcal-<pid>-``: hidden, the process's own; the name shortened so that a
    destination name near the file system's limit (255 bytes) still has a temporary."""
    name = dest.name
    while len(os.fsencode(name)) > 120:
        name = name[:-1]
    return f".{name}.{_TAG}-{os.getpid()}-"


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


def remove_stale_temporaries(directory) -> list[Path]:
    """Remove the temporaries (``.<name>.pkmcal-<pid>-<random>.tmp`` and ``.bak``) that a
    process which no longer runs left in ``directory``; return the removed paths."""
    removed = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return removed
    for entry in entries:
        m = _STALE.match(entry.name)
        if m is None or _pid_alive(int(m.group(1))):
            continue
        with contextlib.suppress(OSError):
            os.unlink(entry.path)
            removed.append(Path(entry.path))
    return removed


def is_stream(path: Path) -> bool:
    """Outputs written into, never replaced: not a regular file (``/dev/null``, a FIFO, a
    terminal) or one of the process's own descriptors (``/dev/stdout``, ``/dev/fd/1``)."""
    text = str(path)
    if text in ("/dev/stdout", "/dev/stderr") or text.startswith(("/dev/fd/", "/proc/self/fd/")):
        return True
    try:
        st = os.stat(path)
    except OSError:
        return False
    return not stat.S_ISREG(st.st_mode) and not stat.S_ISDIR(st.st_mode)


def _existing_ancestor(directory: Path) -> Path:
    d = directory
    while not d.exists() and d != d.parent:
        d = d.parent
    return d


def _file_id(path) -> tuple | None:
    # the one identity of pkmcal.paths (device + inode), for regular files only
    ident = file_identity(path)
    return ident if ident[0] == "inode" and os.path.isfile(path) else None


def _describe(exc: OSError) -> str:
    return exc.strerror or str(exc)


class OutputSet:
    """The outputs of one command: checked up front, staged, and committed together.

    Parameters
    ----------
    files : sequence of path, optional
        Output files known before the work starts (``-o``, the JSON beside it); checked at
        once (directory exists and is writable, not a directory, no two the same, not an
        input). Files staged later are checked when staged and again at the commit.
    directories : sequence of path, optional
        Output directories (``--report DIR``, ``montecarlo -o DIR``): created at the commit
        when missing (parents too); files staged inside them are outputs of the set.
    inputs : sequence of path, optional
        Files the command will read; every file read through :func:`read_input_text` while
        the set is active is added.

    Notes
    -----
    Use as a context manager: ``with OutputSet([out]) as outputs: ...``. Leaving the block
    normally commits what is not committed yet; leaving it by an exception (an error,
    Ctrl-C) discards the staged files. :meth:`commit` may be called earlier, e.g. before
    printing which files were written.
    """

    def __init__(self, files=(), directories=(), inputs=(), final: bool = False):
        #: the set of a process that ends after it: a committed set keeps SIGINT, SIGTERM and
        #: SIGHUP held back until the process exits, so a signal during or after the commit
        #: cannot turn a run whose outputs are all written into a failed one (exit 130/143)
        self.final = final
        self._staged: dict[str, tuple[Path, Path, Path | None, bytes | None]] = {}
        self._inputs: dict[tuple[int, int], Path] = {}
        self._directories: list[Path] = []
        self._token = None
        self._declared: dict[str, Path] = {}
        for d in directories:
            self.add_directory(d)
        for p in inputs:
            self.add_input(p)
        for f in files:
            f = Path(f)
            key = os.path.realpath(self._destination(f))
            if key in self._declared and not is_stream(f):
                raise InputError(f"{f}: used for two outputs ({self._declared[key]} and {f})")
            self.declare(f)

    # -- inputs --------------------------------------------------------------------------
    def add_input(self, path) -> None:
        """Register a file the command reads: no output may replace it."""
        fid = _file_id(path)
        if fid is not None:
            self._inputs.setdefault(fid, Path(path))
            for key, (user, _, _, _) in self._staged.items():
                self._check_not_input(user, Path(key))
            for user in self._declared.values():
                self._check_not_input(user, self._destination(user))

    def _check_not_input(self, user: Path, dest: Path) -> None:
        fid = _file_id(dest)
        if fid is not None and fid in self._inputs:
            raise InputError(f"{user}: the output would overwrite the input file "
                             f"{self._inputs[fid]}; choose another name")

    # -- outputs -------------------------------------------------------------------------
    def add_directory(self, directory) -> Path:
        """An output directory (created at the commit when missing); return it."""
        d = Path(directory)
        if d.exists() and not d.is_dir():
            raise InputError(f"{d}: exists and is not a directory (an output directory is "
                             "expected)")
        if not os.access(_existing_ancestor(d), os.W_OK | os.X_OK):
            raise InputError(f"{d}: cannot create or write this output directory "
                             "(permission denied)")
        key = os.path.realpath(d)
        if key in self._declared:
            raise InputError(f"{d}: used for an output file and an output directory")
        if all(os.path.realpath(e) != key for e in self._directories):
            self._directories.append(d)
        return d

    @staticmethod
    def _destination(path: Path) -> Path:
        """Where the bytes go: a symbolic link's target (the link stays a link); a link that
        points to itself through other links (a loop) is refused, never replaced."""
        if not path.is_symlink():
            return path
        try:
            return Path(os.path.realpath(path, strict=True))
        except FileNotFoundError:           # a dangling link: the file it names is created
            return Path(os.path.realpath(path))
        except (OSError, RuntimeError) as exc:
            raise InputError(f"{path}: cannot write through this symbolic link: "
                             f"{getattr(exc, 'strerror', None) or exc}") from None

    def _in_output_directory(self, path: Path) -> bool:
        parent = os.path.abspath(path.parent if str(path.parent) else ".")
        return any(parent == os.path.abspath(d) or parent.startswith(os.path.abspath(d) + os.sep)
                   for d in self._directories)

    def declare(self, path) -> Path:
        """Check an output file now (see the class); return it."""
        path = Path(path)
        if is_stream(path):
            return path
        dest = self._destination(path)
        directory = dest.parent if str(dest.parent) else Path(".")
        if not self._in_output_directory(dest):
            if not directory.is_dir():
                raise InputError(f"{path}: the output directory {directory} does not exist")
            if not os.access(directory, os.W_OK | os.X_OK):
                raise InputError(f"{path}: cannot write in the directory {directory} "
                                 "(permission denied)")
        if dest.is_dir():
            raise InputError(f"{path}: is a directory, expected a file name")
        key = os.path.realpath(dest)
        for d in self._directories:
            if os.path.realpath(d) == key:
                raise InputError(f"{path}: used for an output file and an output directory")
        self._declared.setdefault(key, path)
        self._check_not_input(path, dest)
        return path

    def stage(self, path, data: bytes) -> Path:
        """Write ``data`` for ``path`` to a temporary beside it; the destination changes at
        the commit. Staging the same path again replaces the earlier content."""
        path = self.declare(path)
        if is_stream(path):
            self._staged[str(path)] = (path, path, None, bytes(data))
            return path
        dest = self._destination(path)
        key = os.path.realpath(dest)
        self._discard_one(key)
        where = _existing_ancestor(dest.parent if str(dest.parent) else Path("."))
        remove_stale_temporaries(where)
        try:
            fd, tmp = tempfile.mkstemp(dir=where, prefix=_temporary_prefix(dest), suffix=".tmp")
        except OSError as exc:
            raise InputError(f"{path}: cannot write: {_describe(exc)}") from None
        self._staged[key] = (path, dest, Path(tmp), None)
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            try:
                mode = dest.stat().st_mode & 0o7777
            except OSError:
                mode = _default_mode()
            os.chmod(tmp, mode)
        except OSError as exc:
            self._discard_one(key)
            raise InputError(f"{path}: cannot write: {_describe(exc)}") from None
        return path

    def _discard_one(self, key: str) -> None:
        old = self._staged.pop(key, None)
        if old is not None and old[2] is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(old[2])

    def discard(self) -> None:
        """Remove every staged temporary: nothing of the set is written."""
        for key in list(self._staged):
            self._discard_one(key)

    @property
    def staged(self) -> list[Path]:
        """The output paths staged and not committed yet, in staging order."""
        return [v[0] for v in self._staged.values()]

    def commit(self) -> list[Path]:
        """Move every staged file over its destination, all or none; return the paths.

        Raises
        ------
        InputError
            An output would replace a file the command read, or a rename failed (the
            destinations written so far are restored first).
        KeyboardInterrupt or Terminated
            A signal came before the commit and something swallowed the exception it raised
            (:func:`pkmcal.errors.stop_if_signalled`): the user asked to stop, so nothing is
            written.
        """
        if not self._staged:
            return []
        try:
            stop_if_signalled()
        except BaseException:
            self.discard()
            raise
        items = list(self._staged.values())
        for user, dest, tmp, _ in items:
            if tmp is not None:
                self._check_not_input(user, dest)
        # streams first, interruptible (a FIFO without a reader blocks until Ctrl-C) and before
        # any file is replaced: a stream that cannot be written (/dev/full) leaves the files as
        # they were. What a stream received cannot be taken back.
        for user, _, tmp, data in items:
            if tmp is None:
                try:
                    with open(user, "wb") as fh:
                        fh.write(data)
                except OSError as exc:
                    self.discard()
                    raise InputError(f"{user}: cannot write: {_describe(exc)}") from None
        held = _hold_signals()
        committed = False
        locks = []
        created: list[Path] = []
        done: list[tuple[Path, Path | None]] = []     # (destination, backup or None)
        try:
            locks = _lock([d.parent for _, d, t, _ in items if t is not None])
            for d in self._directories:
                created += _make_directories(d)
            for user, dest, tmp, data in items:
                if tmp is None:
                    continue
                backup = _NEW           # a destination that did not exist: removed on a rollback
                if dest.exists():
                    backup = dest.with_name(_temporary_prefix(dest) + secrets.token_hex(4)
                                            + ".bak")
                    try:
                        os.link(dest, backup)
                    except OSError:
                        backup = None   # no hard links here: no rollback for this file
                try:
                    os.replace(tmp, dest)
                except OSError as exc:
                    if backup not in (None, _NEW):
                        os.unlink(backup)
                    raise InputError(f"{user}: cannot write: {_describe(exc)}") from None
                done.append((dest, backup))
        except BaseException:
            for dest, backup in reversed(done):
                with contextlib.suppress(OSError):
                    if backup is _NEW:
                        os.unlink(dest)
                    elif backup is not None:
                        os.replace(backup, dest)
            for d in reversed(created):
                with contextlib.suppress(OSError):
                    d.rmdir()
            self.discard()
            raise
        else:
            for _, backup in done:
                if backup not in (None, _NEW):
                    with contextlib.suppress(OSError):
                        os.unlink(backup)
            self._staged.clear()
            committed = True
        finally:
            for fd in locks:
                os.close(fd)
            if not (committed and self.final):
                _release_signals(held)
        return [user for user, *_ in items]

    # -- context manager -----------------------------------------------------------------
    def __enter__(self) -> OutputSet:
        self._token = _ACTIVE.set(self)
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is None:
                self.commit()
            else:
                self.discard()
        finally:
            _ACTIVE.reset(self._token)


def _make_directories(directory: Path) -> list[Path]:
    """Create ``directory`` and its missing parents; return the created ones, outermost
    first."""
    missing = []
    d = directory
    while not d.exists() and d != d.parent:
        missing.append(d)
        d = d.parent
    created = []
    for d in reversed(missing):
        d.mkdir()
        created.append(d)
    return created


def _lock(directories) -> list[int]:
    """Exclusive advisory locks (flock) on the directories, in a fixed order (no deadlock
    between two runs); POSIX only, a no-op elsewhere."""
    try:
        import fcntl
    except ImportError:     # pragma: no cover - not POSIX
        return []
    fds = []
    keys = sorted({os.path.realpath(_existing_ancestor(Path(d) if str(d) else Path(".")))
                   for d in directories})
    for key in keys:
        try:
            fd = os.open(key, os.O_RDONLY)
        except OSError:
            continue
        fds.append(fd)
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_EX)
    return fds


def _hold_signals():
    """Hold SIGINT, SIGTERM and SIGHUP back (delivered after the commit); main thread only."""
    if threading.current_thread() is not threading.main_thread() or \
            not hasattr(signal, "pthread_sigmask"):
        return None
    return signal.pthread_sigmask(signal.SIG_BLOCK,
                                  {signal.SIGINT, signal.SIGTERM, signal.SIGHUP})


def _release_signals(previous) -> None:
    if previous is not None:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def active_output_set() -> OutputSet | None:
    """The :class:`OutputSet` of the running command, or None."""
    return _ACTIVE.get()


def output_directory(directory) -> Path:
    """Make ``directory`` ready for outputs: inside an :class:`OutputSet` it is created at the
    commit (nothing remains of it if the command fails); else at once. Returns it."""
    outputs = _ACTIVE.get()
    if outputs is not None:
        return outputs.add_directory(directory)
    d = Path(directory)
    if d.exists() and not d.is_dir():
        raise InputError(f"{d}: exists and is not a directory (an output directory is "
                         "expected)")
    d.mkdir(parents=True, exist_ok=True)
    return d


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; return the path.

    Inside an :class:`OutputSet` the file is staged and appears at the set's commit; else
    it is written at once, through a one-file set. The destination keeps its permissions
    when it exists (else the umask default applies); a symbolic link keeps pointing to the
    written file; ``/dev/null`` and other non-regular files are written into.

    Parameters
    ----------
    path : str or os.PathLike
        Destination file.
    data : bytes
        Content.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    InputError
        When the destination's directory is missing or not writable, ``path`` is a
        directory, or the file cannot be written (the message names ``path``).
    """
    outputs = _ACTIVE.get()
    if outputs is not None:
        return outputs.stage(path, data)
    one = OutputSet([path])
    one.stage(path, data)
    one.commit()
    return Path(path)


def atomic_write_text(path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_write_bytes`); return the
    path.

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
    """
    return atomic_write_bytes(path, text.encode(encoding))


#: largest input file read when the caller gives no smaller bound (a data file of a million
#: rows is about 100 MB): a device such as /dev/zero or a wrong multi-gigabyte file is refused
#: after this many bytes instead of exhausting memory
MAX_INPUT_BYTES = 1 << 30
#: the text of inputs that are not regular files (a pipe, /dev/stdin, a process substitution
#: ``<(...)``): they can be read once, and a command may read an input more than once
_STREAM_TEXT: dict[str, str] = {}


def read_input_text(path, kind: str, max_bytes: int | None = None, register: bool = True) -> str:
    """Text of an input file (UTF-8, BOM allowed); :class:`InputError` naming the file when it
    is missing, a directory, too large or not text. ``kind`` says what was expected ("machine
    file"). At most ``max_bytes`` (default :data:`MAX_INPUT_BYTES`) are accepted; a larger file
    is refused before it is read, a device or pipe after at most ``max_bytes + 1`` bytes, and
    binary data (a NUL byte) as soon as it is seen. A pipe is read once: later reads of the
    same path in this process give the same text.
    Inside an :class:`OutputSet` the file becomes one of the command's inputs: no output may
    replace it (``register=False``: the file an output updates, read to be rewritten)."""
    path = Path(path)
    outputs = _ACTIVE.get()
    if outputs is not None and register:
        outputs.add_input(path)
    if str(path) in _STREAM_TEXT:
        return _STREAM_TEXT[str(path)]
    limit = MAX_INPUT_BYTES if max_bytes is None else max_bytes
    shown = path_text(path)     # the name as messages show it (bytes not UTF-8 as \xNN)
    try:
        with open(path, "rb") as f:
            st = os.fstat(f.fileno())
            regular = stat.S_ISREG(st.st_mode)
            if regular and st.st_size > limit:
                raise InputError(f"{shown}: the {kind} is {st.st_size} bytes; a {kind} is at "
                                 f"most {limit} bytes (is this the right file?)")
            chunks, total = [], 0
            while True:
                chunk = f.read(min(1 << 20, limit + 1 - total))
                if not chunk:
                    break
                if b"\0" in chunk:
                    raise InputError(f"{shown}: not a text file (UTF-8): it contains NUL bytes "
                                     "(binary data, or UTF-16: save it as UTF-8)")
                chunks.append(chunk)
                total += len(chunk)
                if total > limit:
                    raise InputError(f"{shown}: the {kind} is more than {limit} bytes; a {kind} "
                                     f"is at most {limit} bytes (is this the right file?)")
        text = b"".join(chunks).decode("utf-8-sig")
    except FileNotFoundError:
        raise InputError(f"{shown}: {kind} not found") from None
    except IsADirectoryError:
        raise InputError(f"{shown}: is a directory, expected a {kind}") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{shown}: not a text file (UTF-8): {exc.reason}") from None
    except OSError as exc:
        raise InputError(f"{shown}: cannot read the {kind}: {_describe(exc)}") from None
    if not regular:
        _STREAM_TEXT[str(path)] = text
    return text
