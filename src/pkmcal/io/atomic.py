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
- the renames of one set run with SIGINT/SIGTERM/SIGHUP held back and under a lock of the
  directories involved, so two runs at once commit one after the other; a destination that
  existed is kept as a hard-linked backup (``.<name>.pkmcal-<pid>-<random>.bak``) until the
  whole set is in place;
- before the first rename a *commit journal* (``.commit.pkmcal-<pid>-<random>.journal``,
  flushed to disk) listing every (temporary, destination, backup) is written into every
  directory involved, and removed after the last rename. A commit cut short - a failed
  rename, or ``kill -9`` between two renames - is settled from its journal, by this process
  or by the next one that reads or writes in one of those directories
  (:func:`recover_commits`): rolled back to the previous set while a temporary was still to
  be renamed, else completed (the new set stands). A backup a journal names is never removed
  as a stale temporary;
- temporaries are created and registered, and removed, with the signals held back: a SIGTERM
  in between cannot leave one that no cleanup knows of;
- on an error or an interrupt before the commit, the temporaries are removed and no output
  directory has been created: nothing of the new set remains, the previous set is untouched;
- a destination that is not a regular file (``/dev/null``, a FIFO, ``/dev/stdout``) is
  written into, never replaced, and needs no writable directory;
- temporaries are named ``.<name>.pkmcal-<pid>-<random>.tmp``: unique per run, hidden, never
  mistaken for output. Those left by a killed process (``kill -9``) are removed by the next
  run that writes to (or reads from) the same directory.

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
_STALE = re.compile(r"^\..+\.pkmcal-(\d+)-[^.]+\.(tmp|bak)$")
_JOURNAL = re.compile(r"^\.commit\.pkmcal-(\d+)-[0-9a-f]+\.journal$")
_ACTIVE: contextvars.ContextVar[OutputSet | None] = contextvars.ContextVar(
    "pkmcal_output_set", default=None)
#: fault injection for the tests (read by the commit code alone): ``<k>`` kills the process
#: (SIGKILL) right before step k of its commits (counted from 1 over the process); ``<k>:TERM``
#: (``INT``, ``HUP``) sends that signal instead; ``stage<k>:TERM`` sends it when the k-th
#: temporary has been created, before the set knows of it; ``list`` writes each commit step's
#: number and name to stderr
_KILL_AT = "PKMCAL_TEST_KILL_AT"
_step_count = {"": 0, "stage": 0}
_HELD_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP")
                      if hasattr(signal, name))


def _step(name: str) -> None:
    """A step of the commit protocol: the fault-injection point of ``PKMCAL_TEST_KILL_AT``."""
    spec = os.environ.get(_KILL_AT)
    if not spec:
        return
    kind = "stage" if name == "stage" else ""
    _step_count[kind] += 1
    if spec == "list":
        if not kind:
            os.write(2, f"pkmcal-test-step {_step_count[kind]} {name}\n".encode())
        return
    at, _, sig = spec.partition(":")
    if at == f"{kind}{_step_count[kind]}":
        os.kill(os.getpid(), getattr(signal, f"SIG{sig or 'KILL'}"))


class _Deferred:
    """SIGINT, SIGTERM and SIGHUP held back while a block runs (main thread only).

    The signals are blocked (a default handler cannot end the process) and pkmcal's Python
    handlers are replaced by one that only records the signal: a signal the C level received
    just before the block, whose Python handler had not run yet, is recorded too instead of
    raising inside the block. Leaving the block puts both back and then runs the handler of
    the first recorded signal (it raises there, outside the block), unless ``keep``."""

    def __init__(self):
        self.caught: list[int] = []
        self._handlers: dict[int, object] = {}
        self._mask = None
        self._active = False

    def _record(self, signum, frame) -> None:
        self.caught.append(signum)

    def __enter__(self) -> _Deferred:
        if threading.current_thread() is not threading.main_thread():
            return self
        self._active = True
        try:
            for signum in _HELD_SIGNALS:
                handler = signal.getsignal(signum)
                if callable(handler):
                    self._handlers[signum] = handler
                    signal.signal(signum, self._record)
            if hasattr(signal, "pthread_sigmask"):
                self._mask = signal.pthread_sigmask(signal.SIG_BLOCK, set(_HELD_SIGNALS))
        except BaseException:       # a signal's handler ran before its own was replaced
            self.caught.clear()
            self.release()
            raise
        return self

    def release(self, keep: bool = False) -> None:
        """End the block; ``keep``: hold the signals until the process exits."""
        if not self._active or keep:
            return
        self._active = False
        if self._mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, self._mask)
        for signum, handler in self._handlers.items():
            signal.signal(signum, handler)
        if self.caught and self.caught[0] in self._handlers:
            self._handlers[self.caught[0]](self.caught[0], None)

    def __exit__(self, *exc) -> None:
        self.release()


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


def _fsync_directory(directory) -> None:
    """Make the renames and removals in ``directory`` durable (best effort)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        with contextlib.suppress(OSError):
            os.fsync(fd)
    finally:
        os.close(fd)


def _relative(path, directory) -> str:
    """``path`` relative to ``directory`` (both resolved: the kernel resolves ``..`` the same
    way when the journal is read back)."""
    return os.path.relpath(os.path.realpath(path), os.path.realpath(directory))


def _write_journal(path: Path, data: bytes) -> None:
    """Write one copy of a commit journal: a hidden temporary, flushed, renamed into place,
    the directory flushed; a copy is whole or absent."""
    tmp = path.with_name(path.name.removesuffix(".journal") + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        os.write(fd, data)
        os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(tmp, path)
    _fsync_directory(path.parent)


def _read_journal(path: Path) -> dict | None:
    import json

    try:
        with open(path, "rb") as fh:
            doc = json.loads(fh.read().decode("utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get("format") != "pkmcal-commit-journal-1":
        return None
    return doc if _journal_is_sound(path, doc) else None


def _journal_is_sound(path: Path, doc: dict) -> bool:
    """Whether a journal may be acted on: this user's (a journal another user could plant
    names files to replace or delete), and naming only pkmcal's own hidden files of the run
    that wrote it (its pid) as temporaries, backups and copies."""
    m = _JOURNAL.match(path.name)
    try:
        if m is None or os.stat(path).st_uid != os.geteuid():
            return False
        pid = m.group(1)
        for entry in doc["files"]:
            for key in ("tmp", "backup"):
                if entry[key] is None and key == "backup":
                    continue
                stale = _STALE.match(os.path.basename(entry[key]))
                if stale is None or stale.group(1) != pid:
                    return False
            if not isinstance(entry["dest"], str) or not isinstance(entry["id"], list):
                return False
        for copy in doc["copies"]:
            j = _JOURNAL.match(os.path.basename(copy))
            if j is None or j.group(1) != pid:
                return False
        return isinstance(doc["locks"], list) and isinstance(doc["created"], list)
    except (KeyError, TypeError, OSError):
        return False


def _settle(base: Path, doc: dict) -> None:
    """Settle the commit of journal ``doc`` (a copy found in ``base``), idempotently (a
    settlement that is itself interrupted is finished by the next one).

    Every temporary renamed (none left): the commit is complete, only its backups go. Else it
    is rolled back: every destination it replaced gets its backup back, a destination it
    created is removed, then the temporaries and the directories it created go. A destination
    that is no longer the commit's file (the inode differs: a later run replaced it) is left
    alone and its backup dropped."""
    touched = {str(base)}
    pending = [e for e in doc["files"] if os.path.lexists(base / e["tmp"])]
    for entry in doc["files"]:
        dest = base / entry["dest"]
        touched.add(str(dest.parent))
        backup = None if entry["backup"] is None else base / entry["backup"]
        if not pending:
            if backup is not None:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(backup)
            continue
        try:
            st = os.lstat(dest)
        except OSError:
            st = None
        ours = st is not None and [st.st_dev, st.st_ino] == entry["id"]
        if backup is not None:
            if os.path.lexists(backup):
                if ours or st is None:
                    os.replace(backup, dest)
                else:
                    os.unlink(backup)
        elif ours:
            os.unlink(dest)
    for entry in pending:               # last: while one is left, the next run rolls back
        with contextlib.suppress(FileNotFoundError):
            os.unlink(base / entry["tmp"])
    for d in reversed(doc["created"] if pending else ()):   # with the journal's copy inside
        for copy in doc["copies"]:
            if os.path.dirname(copy) == d:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(base / copy)
        with contextlib.suppress(OSError):
            os.rmdir(base / d)
    for d in touched:
        _fsync_directory(d)


def _forget_journal(base: Path, doc: dict) -> None:
    """Remove every copy of a journal, the one in ``base`` last (the run that settled it, or
    the next run in ``base``, finds that one until all are gone)."""
    for copy in sorted(doc["copies"], key=lambda c: os.path.dirname(c) in ("", ".")):
        _step("forget")
        with contextlib.suppress(FileNotFoundError):
            os.unlink(base / copy)
        _fsync_directory((base / copy).parent)


def recover_commits(directory) -> int:
    """Finish what a killed run's commit left in ``directory``: each commit journal there
    whose run no longer holds its directories is settled - rolled back (the previous files
    restored whole) when a temporary was still to be renamed, else completed (the new files
    are all in place; the backups go) - and removed.

    Parameters
    ----------
    directory : str or os.PathLike
        A directory a command reads from or writes to.

    Returns
    -------
    int
        How many journals were settled.

    Notes
    -----
    A run holds an exclusive lock of every directory its commit touches from before it
    writes its journal until after it removes it; a journal seen under those locks is an
    orphan. Nothing is done where the directory cannot be written.
    """
    directory = Path(directory)
    try:
        names = [e.name for e in os.scandir(directory) if _JOURNAL.match(e.name)]
    except OSError:
        return 0
    if not names or not os.access(directory, os.W_OK | os.X_OK):
        return 0
    done = 0
    for name in names:
        path = directory / name
        doc = _read_journal(path)
        if doc is None:
            continue
        with _Deferred():
            locks = _lock([directory / d for d in doc["locks"]] + [directory])
            try:
                doc = _read_journal(path)        # gone: another run handled it meanwhile
                if doc is None:
                    continue
                try:
                    _settle(directory, doc)
                    _forget_journal(directory, doc)
                except OSError:
                    continue
                done += 1
            finally:
                for fd in locks:
                    os.close(fd)
    return done


def _journal_pids(directory) -> set[str]:
    """The runs (pids) with a commit journal still in ``directory``, readable or not: their
    temporaries and backups are kept (a journal this run cannot read or may not act on -
    another user's, a newer format - may still need them)."""
    try:
        return {m.group(1) for e in os.scandir(directory)
                if (m := _JOURNAL.match(e.name)) is not None}
    except OSError:
        return set()


def _journal_references(directory) -> set[str]:
    """Names in ``directory`` that a commit journal there still needs."""
    names = set()
    try:
        journals = [e.path for e in os.scandir(directory) if _JOURNAL.match(e.name)]
    except OSError:
        return names
    for j in journals:
        doc = _read_journal(Path(j))
        for entry in doc["files"] if doc else ():
            for key in ("tmp", "backup"):
                if entry[key] is not None:
                    p = os.path.join(directory, entry[key])
                    if os.path.realpath(os.path.dirname(p)) == os.path.realpath(directory):
                        names.add(os.path.basename(p))
    return names


def remove_stale_temporaries(directory) -> list[Path]:
    """Clean up after killed runs in ``directory``: settle the commits they left
    (:func:`recover_commits`), then remove the temporaries (``.<name>.pkmcal-<pid>-<random>
    .tmp`` and ``.bak``) of processes that no longer run; a file a remaining journal needs
    is kept.

    Parameters
    ----------
    directory : str or os.PathLike
        The directory.

    Returns
    -------
    list of pathlib.Path
        The removed files.
    """
    recover_commits(directory)
    removed = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return removed
    needed = journaled = None
    for entry in entries:
        m = _STALE.match(entry.name)
        if m is None or _pid_alive(int(m.group(1))):
            continue
        if needed is None:
            needed, journaled = _journal_references(directory), _journal_pids(directory)
        if entry.name in needed or m.group(1) in journaled:
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
        self._recovered: set[str] = set()
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
        """Register a file the command reads: no output may replace it. A commit that a killed
        run left unfinished in the file's directory is settled first (the file read is
        then one of a whole set)."""
        if _file_id(path) is not None:      # a regular file (not a pipe or /dev/stdin)
            self._recover(Path(path).parent)
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

    def _recover(self, directory: Path) -> None:
        """Clean up after killed runs in ``directory`` (once per set): their unfinished
        commits settled, their temporaries removed (:func:`remove_stale_temporaries`)."""
        key = os.path.realpath(directory if str(directory) else ".")
        if key not in self._recovered:
            self._recovered.add(key)
            if os.path.isdir(key) and os.access(key, os.W_OK | os.X_OK):
                remove_stale_temporaries(key)

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
        self._recover(_existing_ancestor(d))
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
        self._recover(_existing_ancestor(directory))
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
        # created and registered with the signals held back: a SIGTERM between the two would
        # leave a temporary that no cleanup knows of
        with _Deferred():
            try:
                fd, tmp = tempfile.mkstemp(dir=where, prefix=_temporary_prefix(dest),
                                           suffix=".tmp")
            except OSError as exc:
                raise InputError(f"{path}: cannot write: {_describe(exc)}") from None
            _step("stage")
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
        with _Deferred():           # forgotten and removed together
            old = self._staged.pop(key, None)
            if old is not None and old[2] is not None:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(old[2])

    def discard(self) -> None:
        """Remove every staged temporary: nothing of the set is written."""
        with _Deferred():           # a second signal does not cut the cleanup short
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
            items = list(self._staged.values())
            for user, dest, tmp, _ in items:
                if tmp is not None:
                    self._check_not_input(user, dest)
            # streams first, interruptible (a FIFO without a reader blocks until Ctrl-C) and
            # before any file is replaced: a stream that cannot be written (/dev/full) leaves
            # the files as they were. What a stream received cannot be taken back.
            for user, _, tmp, data in items:
                if tmp is None:
                    try:
                        # appended, never truncated: /dev/stdout redirected to a file with
                        # >> (or holding what was printed before) keeps what it holds
                        with open(user, "ab") as fh:
                            fh.write(data)
                    except OSError as exc:
                        raise InputError(f"{user}: cannot write: {_describe(exc)}") from None
            files = [(user, dest, tmp) for user, dest, tmp, _ in items if tmp is not None]
            for d in {str(t.parent) for _, _, t in files}:
                recover_commits(d)      # a run killed meanwhile: its set back first
        except BaseException:
            self.discard()
            raise
        held = _Deferred()
        committed = False
        try:
            held.__enter__()
            if files:
                self._commit_files(files)
            else:
                for d in self._directories:
                    _make_directories(d)
            self._staged.clear()
            committed = True
        except BaseException:
            self.discard()
            raise
        finally:
            held.release(keep=committed and self.final)
        return [user for user, *_ in items]

    def _commit_files(self, files: list[tuple[Path, Path, Path]]) -> None:
        """The commit protocol (the directories locked, the signals held back):

        1. each destination that exists gets a hard-linked backup (a copy where the file
           system has no hard links);
        2. a journal listing every (temporary, destination, backup) is written, flushed, into
           every directory involved (``.commit.pkmcal-<pid>-<random>.journal``);
        3. missing output directories are created, the temporaries renamed over their
           destinations one by one, the directories flushed;
        4. the journal's copies are removed;
        5. the backups are removed.

        A failure or a kill while a temporary is still to be renamed is rolled back to the
        previous set, in this process or by the next run that reads or writes in one of the
        directories (:func:`recover_commits`); after the last rename the new set stands and
        that run only removes the journal and the backups. A kill in step 5 leaves backups no
        journal names, removed by the next run as stale temporaries. A set of one file that
        creates no directory is one rename: no backup, no journal."""
        tmp_dirs = {os.path.realpath(t.parent) for _, _, t in files}
        dest_dirs = {os.path.realpath(d.parent if str(d.parent) else ".") for _, d, _ in files}
        created: list[str] = []
        for d in [*self._directories, *(Path(p) for p in sorted(dest_dirs))]:
            for m in _missing_directories(Path(os.path.realpath(d))):
                if m not in created:
                    created.append(m)
        lock_dirs = sorted({os.path.realpath(_existing_ancestor(Path(d)))
                            for d in tmp_dirs | dest_dirs})
        journal_dirs = sorted(tmp_dirs | dest_dirs)
        name = f".commit.{_TAG}-{os.getpid()}-{secrets.token_hex(6)}.journal"
        home = Path(next(d for d in journal_dirs if d not in created))
        locks = _lock(lock_dirs)
        if len(files) == 1 and not created:     # one rename is atomic: no journal needed
            user, dest, tmp = files[0]
            try:
                _step("rename")
                os.replace(tmp, dest)
                _fsync_directory(dest.parent if str(dest.parent) else ".")
            except OSError as exc:
                raise InputError(f"{user}: cannot write: {_describe(exc)}") from None
            finally:
                for fd in locks:
                    os.close(fd)
            return
        backups: list[Path] = []
        doc = None
        try:
            _step("backup")
            entries = []
            for user, dest, tmp in files:
                backup = None
                if os.path.lexists(dest):
                    backup = dest.with_name(_temporary_prefix(dest) + secrets.token_hex(4)
                                            + ".bak")
                    try:
                        _backup(dest, backup)
                    except OSError as exc:
                        raise InputError(f"{user}: cannot write: {_describe(exc)}") from None
                    backups.append(backup)
                st = os.stat(tmp)
                entries.append({"tmp": os.path.realpath(tmp),
                                "dest": os.path.join(os.path.realpath(dest.parent), dest.name),
                                "backup": None if backup is None else os.path.realpath(backup),
                                "id": [st.st_dev, st.st_ino]})
            plan = {"locks": lock_dirs, "copies": [os.path.join(d, name) for d in journal_dirs],
                    "created": created, "files": entries}
            doc = _journal(plan, home)
            for d in journal_dirs:
                if d not in created:
                    _step("journal")
                    _write_journal(Path(d) / name, _journal_bytes(_journal(plan, Path(d))))
            for d in created:
                _step("mkdir")
                with contextlib.suppress(FileExistsError):  # another run made it meanwhile
                    os.mkdir(d)
                if d in journal_dirs:
                    _write_journal(Path(d) / name, _journal_bytes(_journal(plan, Path(d))))
            for user, dest, tmp in files:
                _step("rename")
                try:
                    os.replace(tmp, dest)
                except OSError as exc:
                    raise InputError(f"{user}: cannot write: {_describe(exc)}") from None
            for d in dest_dirs | tmp_dirs:
                _fsync_directory(d)
            _forget_journal(home, doc)
            doc = None
            _step("cleanup")
            for backup in backups:
                with contextlib.suppress(OSError):
                    os.unlink(backup)
        except BaseException as exc:
            if doc is not None:
                try:
                    _settle(home, doc)
                    _forget_journal(home, doc)
                except OSError:
                    # the journal stays for the next run, which needs the temporaries to
                    # roll the set back: discard() must not remove them
                    self._staged.clear()
            else:
                for backup in backups:
                    with contextlib.suppress(OSError):
                        os.unlink(backup)
            if isinstance(exc, OSError):
                raise InputError(f"{files[0][0]}: cannot write: {_describe(exc)}") from None
            raise
        finally:
            for fd in locks:
                os.close(fd)

    # -- context manager -----------------------------------------------------------------
    def __enter__(self) -> OutputSet:
        self._token = _ACTIVE.set(self)
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is None:
                try:
                    self.commit()
                except BaseException:
                    self.discard()
                    raise
            else:
                self.discard()
        finally:
            _ACTIVE.reset(self._token)


def _journal(plan: dict, base: Path) -> dict:
    """The journal of a commit ``plan`` (absolute paths) as a copy in ``base`` holds it: every
    path relative to ``base``, so the journal still applies where the tree was moved."""
    def rel(p):
        return None if p is None else _relative(p, base)

    return {"format": "pkmcal-commit-journal-1", "pid": os.getpid(),
            "locks": [rel(d) for d in plan["locks"]],
            "copies": [rel(c) for c in plan["copies"]],
            "created": [rel(d) for d in plan["created"]],
            "files": [dict(e, tmp=rel(e["tmp"]), dest=rel(e["dest"]), backup=rel(e["backup"]))
                      for e in plan["files"]]}


def _journal_bytes(doc: dict) -> bytes:
    """JSON, ASCII: a name that is not UTF-8 is kept as its escaped surrogates."""
    import json

    return (json.dumps(doc, ensure_ascii=True, indent=1) + "\n").encode("ascii")


def _backup(dest: Path, backup: Path) -> None:
    """``backup``: the file ``dest`` is now (a hard link; a flushed copy where the file system
    has none)."""
    try:
        os.link(dest, backup)
        return
    except OSError:
        pass
    fd = os.open(backup, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as out, open(dest, "rb") as src:
        while chunk := src.read(1 << 20):
            out.write(chunk)
        out.flush()
        os.fchmod(fd, os.stat(dest).st_mode & 0o7777)
        os.fsync(fd)


def _missing_directories(directory: Path) -> list[str]:
    """``directory`` and its parents that do not exist, outermost first."""
    missing = []
    d = directory
    while not d.exists() and d != d.parent:
        missing.append(str(d))
        d = d.parent
    return missing[::-1]


def _make_directories(directory: Path) -> None:
    for d in _missing_directories(directory):
        os.mkdir(d)


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
