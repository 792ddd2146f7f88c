"""``pkmcal`` for the documentation's shell blocks without an interpreter start per command.

A server process imports the CLI once; each ``pkmcal ...`` of a block is a small client (Python
without ``site``) that hands the server its arguments, working directory, environment and its
stdin/stdout/stderr (file descriptors over a Unix socket); the server forks, the child runs
the console script's entry point (:func:`pkmcal._entry.main`) on those descriptors and reports
the exit code, which the client exits with. Redirections, pipes and exit codes behave as with
the console script; every command is its own (forked) process. ``PKMCAL_TEST_SUBPROCESS=1``
makes tests/test_docs.py use the console script itself instead.

Nothing here is imported at the client's module level but the standard library's socket.
"""

from __future__ import annotations

import json
import os
import socket
import sys


def _recv_exact(conn: socket.socket, n: int, first: bytes = b"") -> bytes:
    data = first
    while len(data) < n:
        chunk = conn.recv(n - len(data))
        if not chunk:
            raise ConnectionError("short message")
        data += chunk
    return data


def client(path: str) -> None:
    """The ``pkmcal`` command of a shell block: run by the server, exit with its code."""
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.connect(path)
    msg = json.dumps({"argv": sys.argv[1:], "cwd": os.getcwd(),
                      "env": dict(os.environ)}).encode()
    socket.send_fds(s, [len(msg).to_bytes(8, "big")], [0, 1, 2])
    s.sendall(msg)
    code = int.from_bytes(_recv_exact(s, 4), "big", signed=True)
    sys.exit(code)


def _child(conn: socket.socket, fds: list[int], request: dict) -> None:
    for target, fd in enumerate(fds):
        os.dup2(fd, target)
        os.close(fd)
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    sys.argv = ["pkmcal", *request["argv"]]
    code = 0
    try:
        from pkmcal._entry import main

        main()
    except SystemExit as exc:
        if exc.code is None:
            code = 0
        elif isinstance(exc.code, int):
            code = exc.code
        else:
            sys.stderr.write(f"{exc.code}\n")
            code = 1
    except BaseException:          # a traceback, as the console script would print it
        import traceback

        traceback.print_exc()
        code = 1
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    finally:
        conn.sendall(int(code).to_bytes(4, "big", signed=True))
        os._exit(0)


def serve(path: str) -> None:
    """Import the CLI, listen on ``path`` and fork one child per command, until killed."""
    import importlib
    import signal

    # what the commands import on their way (the CLI imports them lazily, per command)
    for name in ("pkmcal._entry", "pkmcal.cli", "pkmcal.calibration", "pkmcal.io",
                 "pkmcal.instruments", "pkmcal.planning", "pkmcal.analysis",
                 "pkmcal.compensation", "pkmcal.export", "pkmcal.report", "pkmcal.demo",
                 "scipy.stats", "matplotlib.pyplot"):
        try:
            importlib.import_module(name)
        except ImportError:
            pass

    signal.signal(signal.SIGCHLD, signal.SIG_IGN)      # children reap themselves
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    srv.bind(path)
    srv.listen(8)
    print("ready", flush=True)
    while True:
        conn, _ = srv.accept()
        head, fds, _, _ = socket.recv_fds(conn, 8, 3)
        size = int.from_bytes(_recv_exact(conn, 8, head), "big")
        request = json.loads(_recv_exact(conn, size))
        sys.stdout.flush()
        sys.stderr.flush()
        if os.fork() == 0:
            srv.close()
            _child(conn, fds, request)
        conn.close()
        for fd in fds:
            os.close(fd)


if __name__ == "__main__":
    serve(sys.argv[1])
