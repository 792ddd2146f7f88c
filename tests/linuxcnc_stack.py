"""LinuxCNC's own code for the tests: Debian's Python bindings of its Delta kinematics and the
whole stack headless (``linuxcnc`` + ``rtapi_app`` + motion + task, driven through the
``linuxcnc`` module by :mod:`linuxcnc_driver`).

Debian's ``linuxcnc-uspace`` 2.9 (``apt-get install -y --no-install-recommends
linuxcnc-uspace``) puts its Python modules into Debian's own Python (``/usr/bin/python3``),
not the project's: everything here runs them in a subprocess. What the stack needs, read in
LinuxCNC's ``src/rtapi/uspace_rtapi_main.cc``, ``scripts/linuxcnc.in`` and
``src/emc/tooldata/tooldata_mmap.cc``: as root, ``rtapi_app`` refuses to run unless
``RTAPI_UID`` names another user (it runs with that real uid), whose ``RTAPI_FIFO_PATH``
socket directory must be writable by that user; the ``linuxcnc`` script keeps one instance per
machine (``/tmp/linuxcnc.lock``: a second start cleans the first away), hence a file lock
here; the tool table is a memory map in ``$HOME`` (the driver needs the same ``HOME``).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

DEBIAN_PYTHON = Path("/usr/bin/python3")
DRIVER = Path(__file__).resolve().with_name("linuxcnc_driver.py")
#: serialises LinuxCNC starts across test processes (pytest-xdist)
LOCK = Path(tempfile.gettempdir()) / "pkmcal-tests-linuxcnc.lock"
#: the unprivileged user rtapi_app runs as when the tests run as root (nobody)
FALLBACK_UID = 65534


def _debian_imports(*modules: str) -> str | None:
    """None when Debian's Python imports the modules, else why not."""
    if not DEBIAN_PYTHON.exists():
        return f"{DEBIAN_PYTHON} is missing (Debian's Python with linuxcnc-uspace's modules)"
    p = subprocess.run([str(DEBIAN_PYTHON), "-c", f"import {', '.join(modules)}"],
                       capture_output=True, text=True)
    if p.returncode != 0:
        return (f"{DEBIAN_PYTHON} cannot import {', '.join(modules)} (apt-get install "
                f"linuxcnc-uspace): {p.stderr.strip().splitlines()[-1:]}")
    return None


def kins_missing() -> str | None:
    """Why Debian's ``rotarydeltakins`` / ``lineardeltakins`` bindings cannot run (None: they
    can)."""
    return _debian_imports("rotarydeltakins", "lineardeltakins")


def stack_missing() -> str | None:
    """Why LinuxCNC cannot start headless here (None: it can)."""
    for program in ("linuxcnc", "rtapi_app", "halrun"):
        if shutil.which(program) is None:
            return f"LinuxCNC's {program} is not installed (apt-get install linuxcnc-uspace)"
    return _debian_imports("linuxcnc", "hal")


_KINS_SCRIPT = r"""
import json, sys, importlib
req = json.load(sys.stdin)
kins = importlib.import_module(req["module"])
kins.set_geometry(*req["geometry"])
def call(f, args):
    try:
        r = f(*args)
    except Exception:
        return None
    return None if r is None else list(r)
json.dump({"geometry": list(kins.get_geometry()),
           "inverse": [call(kins.inverse, p) for p in req.get("inverse", [])],
           "forward": [call(kins.forward, j) for j in req.get("forward", [])]}, sys.stdout)
"""


def debian_kins(module: str, geometry, inverse=(), forward=()) -> dict:
    """LinuxCNC's kinematics as Debian builds them (its Python bindings of the C code).

    Parameters
    ----------
    module : str
        ``rotarydeltakins`` or ``lineardeltakins``.
    geometry : sequence of float
        ``set_geometry``'s arguments (pfr, tl, sl, fr; or R, L), mm.
    inverse : array_like, shape (K, 3)
        World positions (mm) for ``inverse``.
    forward : array_like, shape (M, 3)
        Joints for ``forward``.

    Returns
    -------
    dict
        ``geometry`` (``get_geometry``), ``inverse`` and ``forward``: lists of triples, None
        where the module fails.
    """
    req = {"module": module, "geometry": [float(v) for v in geometry],
           "inverse": [[float(v) for v in p] for p in inverse],
           "forward": [[float(v) for v in j] for j in forward]}
    p = subprocess.run([str(DEBIAN_PYTHON), "-c", _KINS_SCRIPT], input=json.dumps(req),
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout)


@contextlib.contextmanager
def _one_linuxcnc(timeout: float = 300.0):
    """Hold the lock of the one LinuxCNC instance a machine runs."""
    with open(LOCK, "a") as fh:
        t0 = time.monotonic()
        while True:
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() - t0 > timeout:
                    raise TimeoutError(f"another LinuxCNC held {LOCK} for {timeout:g} s") \
                        from None
                time.sleep(0.2)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def run_linuxcnc(ini: Path, request: dict, timeout: float = 60.0) -> dict:
    """Start LinuxCNC with ``ini`` headless, drive it with :mod:`linuxcnc_driver`, stop it.

    ``linuxcnc INI`` runs in its own process group with its standard input a pipe (the
    ``dummy`` display ends LinuxCNC when it closes); the driver runs beside it with the same
    environment. Afterwards the group is ended if it has not ended itself, and ``halrun -U``
    unloads whatever remains.

    Parameters
    ----------
    ini : Path
        The INI file (its directory is the configuration's, unchanged).
    request : dict
        The driver's request (:mod:`linuxcnc_driver`).
    timeout : float, optional
        Seconds for the driver.

    Returns
    -------
    dict
        The driver's result, with ``log`` (LinuxCNC's output) and ``exit`` (its exit code).
    """
    work = Path(tempfile.mkdtemp(prefix="pkmcal-lcnc-"))
    os.chmod(work, 0o755)
    fifo = work / "fifo"
    fifo.mkdir()
    os.chmod(fifo, 0o777)                  # rtapi_app's socket, made as the fallback user
    home = work / "home"
    home.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env.update(HOME=str(home), RTAPI_FIFO_PATH=str(fifo / "rtapi_fifo"))
    if os.getuid() == 0:
        env["RTAPI_UID"] = str(FALLBACK_UID)
    (work / "request.json").write_text(json.dumps(request))
    log = open(work / "linuxcnc.log", "w")
    result: dict = {}
    with _one_linuxcnc():
        proc = subprocess.Popen(["linuxcnc", str(ini)], stdin=subprocess.PIPE, stdout=log,
                                stderr=subprocess.STDOUT, env=env, cwd=str(ini.parent),
                                start_new_session=True)
        try:
            drv = subprocess.run([str(DEBIAN_PYTHON), str(DRIVER), str(work / "request.json"),
                                  str(work / "result.json")], env=env, capture_output=True,
                                 text=True, timeout=timeout)
            if (work / "result.json").exists():
                result = json.loads((work / "result.json").read_text())
            else:
                result = {"failed": f"driver: {drv.stderr.strip()[-2000:]}"}
        except subprocess.TimeoutExpired:
            result = {"failed": f"driver timed out after {timeout:g} s"}
        finally:
            with contextlib.suppress(OSError):
                proc.stdin.close()          # the dummy display returns: LinuxCNC cleans up
            try:
                result["exit"] = proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGTERM)
                try:
                    result["exit"] = proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    with contextlib.suppress(ProcessLookupError):
                        os.killpg(proc.pid, signal.SIGKILL)
                    result["exit"] = proc.wait()
                subprocess.run(["halrun", "-U"], env=env, capture_output=True, timeout=60)
            log.close()
    # without a terminal the linuxcnc script logs to files it copies into HOME on an error
    result["log"] = "\n".join(f.read_text(errors="replace") for f in
                              [work / "linuxcnc.log", home / "linuxcnc_debug.txt",
                               home / "linuxcnc_print.txt"] if f.exists())
    shutil.rmtree(work, ignore_errors=True)
    return result
