"""Nothing lost (issue 11, item 2): outputs never replace an input, appear all together or not
at all (errors, Ctrl-C, SIGTERM, ``kill -9``, two runs at once), temporaries are unique and
never mistaken for output, and ``-o /dev/null`` is written into, never replaced.

The library's :class:`~pkmcal.io.atomic.OutputSet` is tested directly; every command is then
run as a subprocess from one table (its inputs, its outputs)."""

from __future__ import annotations

import os
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from clitools import PKMCAL, assert_input_error, digest, popen, run, run_process, wait_at_most
from pkmcal.errors import InputError
from pkmcal.io.atomic import (
    OutputSet,
    atomic_write_text,
    output_directory,
    read_input_text,
    remove_stale_temporaries,
)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _visible(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if not p.name.startswith("."))


def _temporaries(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.rglob(".*pkmcal-*"))


# -- the library: OutputSet ---------------------------------------------------------------


def test_staged_files_appear_only_at_the_commit(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    b.write_text("old b")
    with OutputSet([a, b]) as out:
        atomic_write_text(a, "new a")
        atomic_write_text(b, "new b")
        assert not a.exists() and b.read_text() == "old b"
        assert len(_temporaries(tmp_path)) == 2
        assert out.staged == [a, b]
    assert a.read_text() == "new a" and b.read_text() == "new b"
    assert _temporaries(tmp_path) == []


def test_an_error_before_the_commit_leaves_the_previous_set(tmp_path):
    a, b, d = tmp_path / "a.txt", tmp_path / "b.txt", tmp_path / "new" / "dir"
    a.write_text("old a")
    with pytest.raises(RuntimeError), OutputSet([a, b], directories=[d]):
        atomic_write_text(a, "new a")
        atomic_write_text(b, "new b")
        atomic_write_text(d / "c.txt", "new c")
        raise RuntimeError("boom")
    assert a.read_text() == "old a" and not b.exists()
    assert not (tmp_path / "new").exists()           # the output directory was never made
    assert _visible(tmp_path) == ["a.txt"] and _temporaries(tmp_path) == []


def test_a_failed_rename_restores_the_files_already_replaced(tmp_path, monkeypatch):
    a, b, c = (tmp_path / n for n in ("a.txt", "b.txt", "c.txt"))
    a.write_text("old a")
    c.write_text("old c")
    real = os.replace
    calls = []

    def flaky(src, dst):
        if Path(dst).name.startswith("."):      # the commit journal's own rename
            return real(src, dst)
        calls.append(dst)
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        return real(src, dst)

    out = OutputSet([a, b, c])
    for p in (a, b, c):
        out.stage(p, b"new")
    monkeypatch.setattr(os, "replace", flaky)
    with pytest.raises(InputError, match=r"c\.txt: cannot write: No space left"):
        out.commit()
    monkeypatch.setattr(os, "replace", real)
    assert a.read_text() == "old a" and c.read_text() == "old c" and not b.exists()
    assert _visible(tmp_path) == ["a.txt", "c.txt"] and _temporaries(tmp_path) == []


@pytest.mark.parametrize("alias", ["same", "symlink", "hardlink", "dotted"])
def test_an_output_never_replaces_a_file_that_was_read(tmp_path, alias):
    src = tmp_path / "in.csv"
    src.write_text("q1_mm\n1\n")
    out_path = {"same": src, "symlink": tmp_path / "link.csv",
                "hardlink": tmp_path / "hard.csv", "dotted": tmp_path / "." / "in.csv"}[alias]
    if alias == "symlink":
        out_path.symlink_to(src)
    if alias == "hardlink":
        os.link(src, out_path)
    before = digest(src)
    with pytest.raises(InputError, match="would overwrite the input file"), OutputSet():
        read_input_text(src, "data file")          # read first: registered as an input
        atomic_write_text(out_path, "x")
    assert digest(src) == before and _temporaries(tmp_path) == []
    # declared up front: refused before any work
    with pytest.raises(InputError, match="would overwrite the input file"):
        OutputSet([out_path], inputs=[src])


def test_an_input_read_after_staging_is_still_protected(tmp_path):
    src = tmp_path / "report.json"
    src.write_text("{}")
    with pytest.raises(InputError, match="would overwrite the input file"), OutputSet():
        atomic_write_text(src, "new")
        read_input_text(src, "calibration report")
    assert src.read_text() == "{}"


def test_two_outputs_on_one_file_are_refused(tmp_path):
    with pytest.raises(InputError, match="used for two outputs"):
        OutputSet([tmp_path / "a.yaml", tmp_path / "." / "a.yaml"])
    with pytest.raises(InputError, match="output file and an output directory"):
        OutputSet([tmp_path / "d"], directories=[tmp_path / "d"])


def test_symlinked_output_keeps_the_link(tmp_path):
    target = tmp_path / "real.csv"
    target.write_text("old")
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    atomic_write_text(link, "new")
    assert link.is_symlink() and target.read_text() == "new"


def test_permissions_of_a_replaced_file_are_kept(tmp_path):
    p = tmp_path / "a.txt"
    p.write_text("old")
    p.chmod(0o640)
    atomic_write_text(p, "new")
    assert stat.S_IMODE(p.stat().st_mode) == 0o640


def test_dev_null_and_fifos_are_written_into(tmp_path):
    atomic_write_text(os.devnull, "discarded")
    assert stat.S_ISCHR(os.stat(os.devnull).st_mode)
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    reader = subprocess.Popen(["cat", str(fifo)], stdout=subprocess.PIPE, text=True)
    with OutputSet([fifo]):
        atomic_write_text(fifo, "through the pipe\n")
    assert reader.communicate(timeout=10)[0] == "through the pipe\n"
    assert stat.S_ISFIFO(fifo.stat().st_mode) and _temporaries(tmp_path) == []


def test_stale_temporaries_of_dead_processes_are_removed(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    dead_pid = int(dead.stdout)
    stale = tmp_path / f".out.csv.pkmcal-{dead_pid}-abc123.tmp"
    stale_bak = tmp_path / f".out.csv.pkmcal-{dead_pid}-def456.bak"
    live = tmp_path / f".out.csv.pkmcal-{os.getpid()}-xyz789.tmp"
    other = tmp_path / ".hidden-user-file"
    for p in (stale, stale_bak, live, other):
        p.write_text("x")
    removed = remove_stale_temporaries(tmp_path)
    assert sorted(removed) == sorted([stale, stale_bak])
    assert live.exists() and other.exists()
    # the next write into the directory removes them too
    stale.write_text("x")
    atomic_write_text(tmp_path / "out.csv", "new")
    assert not stale.exists() and (tmp_path / "out.csv").read_text() == "new"


def test_output_directory_outside_a_set_is_made_at_once(tmp_path):
    d = output_directory(tmp_path / "x" / "y")
    assert d.is_dir()
    (tmp_path / "f").write_text("")
    with pytest.raises(InputError, match="not a directory"):
        output_directory(tmp_path / "f")


# -- every command, as a subprocess ---------------------------------------------------------


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """Inputs of every command: Hexa Slide data and a calibration, Delta targets."""
    d = tmp_path_factory.mktemp("outputs")
    for args in (["simulate", "default", "--poses", "60", "-o", "data.csv"],
                 ["calibrate", "default", "data.csv", "-o", "cal.yaml"],
                 ["fk", "cal.yaml", "data.csv", "-o", "poses.csv"]):
        proc = run(*args, cwd=d)
        assert proc.returncode == 0, proc.stderr
    poses = (d / "poses.csv").read_text().splitlines()
    (d / "targets.csv").write_text("\n".join(poses[:6]) + "\n")
    (d / "traj.csv").write_text("t_s,x_mm,y_mm,z_mm\n" + "".join(
        f"{k * 0.01},{100 * (k % 3) / 3:.3f},0,410\n" for k in range(12)))
    return d


#: command -> (arguments, input files, output files); every file name is relative to workdir
COMMANDS = {
    "simulate": (["simulate", "cal.yaml", "--poses", "50", "-o", "{o0}", "--truth", "{o1}"],
                 ["cal.yaml"], ["sim.csv", "truth.yaml"]),
    "calibrate": (["calibrate", "default", "data.csv", "-o", "{o0}", "--report", "rep"],
                  ["data.csv"], ["c.yaml", "c.json", "rep/report.html", "rep/report.json"]),
    "fk": (["fk", "cal.yaml", "data.csv", "-o", "{o0}"], ["cal.yaml", "data.csv"], ["p.csv"]),
    "ik": (["ik", "cal.yaml", "poses.csv", "-o", "{o0}"], ["cal.yaml", "poses.csv"],
           ["q.csv"]),
    "identifiability": (["identifiability", "cal.yaml", "data.csv", "--map", "{o0}"],
                        ["cal.yaml", "data.csv"], ["map.png"]),
    "select-poses": (["select-poses", "cal.yaml", "-n", "50", "--candidates", "300",
                      "--random-sets", "3", "-o", "{o0}", "--map", "{o1}"],
                     ["cal.yaml"], ["plan.csv", "plan.png"]),
    "compensate": (["compensate", "cal.yaml", "targets.csv", "-o", "{o0}"],
                   ["cal.yaml", "targets.csv", "cal.json"], ["cmd.csv"]),
    "report": (["report", "cal.yaml", "-o", "{o0}"], ["cal.yaml", "cal.json"],
               ["r.html", "r.json"]),
    "errors": (["errors", "cubic", "--trajectory", "file", "--trajectory-file", "traj.csv",
                "-o", "{o0}", "--plot", "pl"], ["traj.csv"],
               ["e.csv", "e_envelope.csv", "pl/link_forces.png", "pl/pose_errors.png",
                "pl/error_map.png"]),
    "montecarlo": (["montecarlo", "default", "--vary", "noise=1,2um", "--runs", "2",
                    "--poses", "60", "--workers", "1", "-o", "mc"], [],
                   ["mc/runs.csv", "mc/summary.csv", "mc/summary.json", "mc/montecarlo.png"]),
}


def _args(name: str, outputs: list[str]) -> list[str]:
    args, _, default_outputs = COMMANDS[name]
    fill = {f"o{i}": o for i, o in enumerate(outputs)}
    return [a.format(**fill) for a in args]


def _digests(d: Path, names) -> dict:
    return {n: digest(d / n) if (d / n).is_file() else None for n in names}


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_command_writes_its_outputs_together(workdir, name, tmp_path):
    args, inputs, outputs = COMMANDS[name]
    d = tmp_path
    for f in workdir.iterdir():
        if f.is_file():
            (d / f.name).write_bytes(f.read_bytes())
    proc = run(*_args(name, outputs), cwd=d)
    assert proc.returncode == 0, proc.stderr
    for o in outputs:
        assert (d / o).is_file(), (o, sorted(p.name for p in d.rglob("*")))
    assert _temporaries(d) == []


def _collisions(name):
    """(output index, input) pairs: each output of the command named as each of its inputs."""
    args, inputs, outputs = COMMANDS[name]
    slots = [i for i, a in enumerate(args) if a.startswith("{o")]
    return [(k, inp) for k in range(len(slots)) for inp in inputs]


@pytest.mark.parametrize("name,slot,victim",
                         [(n, k, v) for n in sorted(COMMANDS) for k, v in _collisions(n)])
def test_no_command_overwrites_an_input(workdir, tmp_path, name, slot, victim):
    d = tmp_path
    for f in workdir.iterdir():
        if f.is_file():
            (d / f.name).write_bytes(f.read_bytes())
    args, inputs, outputs = COMMANDS[name]
    outs = list(outputs)
    outs[slot] = victim
    before = _digests(d, set(inputs) | set(outputs))
    proc = run(*_args(name, outs), cwd=d)
    assert_input_error(proc, victim)
    assert _digests(d, set(inputs) | set(outputs)) == before     # nothing written at all
    assert _temporaries(d) == []


def test_files_written_beside_the_output_are_protected(workdir, tmp_path):
    """The envelope table beside -o and the JSON beside a calibrated file are outputs too."""
    d = tmp_path
    (d / "e_envelope.csv").write_text((workdir / "traj.csv").read_text())
    before = digest(d / "e_envelope.csv")
    proc = run("errors", "cubic", "--trajectory", "file", "--trajectory-file",
               "e_envelope.csv", "-o", "e.csv", cwd=d)
    assert_input_error(proc, "e_envelope.csv", "input")
    assert digest(d / "e_envelope.csv") == before and not (d / "e.csv").exists()
    (d / "data.csv").write_bytes((workdir / "data.csv").read_bytes())
    (d / "data.json").write_text("{}")        # calibrate -o data.yaml writes data.json
    proc = run("calibrate", "default", "data.csv", "-o", "data.yaml", cwd=d)
    assert proc.returncode == 0, proc.stderr
    proc = run("calibrate", "default", "data.json", "-o", "x.yaml", cwd=d)
    assert proc.returncode == 2


def test_a_report_from_another_run_is_refused(workdir, tmp_path):
    """A calibrated file pins its JSON report by digest: a pair from two runs is refused."""
    d = tmp_path
    (d / "data.csv").write_bytes((workdir / "data.csv").read_bytes())
    assert run("calibrate", "default", "data.csv", "-o", "a.yaml", cwd=d).returncode == 0
    (d / "old.yaml").write_bytes((d / "a.yaml").read_bytes())
    assert run("calibrate", "default", "data.csv", "-o", "a.yaml", "--noise", "3um",
               cwd=d).returncode == 0
    (d / "targets.csv").write_bytes((workdir / "targets.csv").read_bytes())
    proc = run("compensate", "old.yaml", "targets.csv", "-o", "cmd.csv", cwd=d)
    assert_input_error(proc, "a.json", "another run")
    proc = run("report", "old.yaml", "-o", "r.html", cwd=d)
    assert_input_error(proc, "a.json", "another run")
    proc = run("compensate", "a.yaml", "targets.csv", "-o", "cmd.csv", cwd=d)
    assert proc.returncode == 0, proc.stderr


def test_a_stream_output_needs_no_writable_directory(tmp_path, monkeypatch):
    """Only regular files are staged beside their destination: /dev/null, a FIFO or
    /dev/stdout are opened for writing at the commit, whatever the directory allows."""
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: False if str(p) == "/dev"
                        else real(p, mode, **kw))
    with OutputSet([os.devnull]):
        atomic_write_text(os.devnull, "x")
    with pytest.raises(InputError, match="permission denied"):
        OutputSet(["/dev/not-a-device"])


@pytest.mark.parametrize("name", ["calibrate", "errors", "report", "fk"])
def test_dev_null_is_written_into_even_from_a_read_only_directory(workdir, name):
    """A user who cannot write the working directory may still send any output to
    /dev/null: it is written into, not replaced, and nothing is created beside it (no
    /dev/null.json)."""
    import shutil
    import tempfile

    top = Path(tempfile.mkdtemp(prefix="pkmcal-ro-"))
    d = top / "ro"
    try:
        top.chmod(0o755)
        d.mkdir()
        for f in workdir.iterdir():
            if f.is_file():
                (d / f.name).write_bytes(f.read_bytes())
                (d / f.name).chmod(0o644)
        args = _args(name, ["/dev/null", "/dev/null"])
        args = [a for a in args if a not in ("--report", "rep", "--plot", "pl")]
        d.chmod(0o555)
        # (root writes anywhere: there the test shows /dev/null is not replaced and nothing
        # is written beside it; the library test below covers the unwritable directory)
        proc = run(*args, cwd=d)
        assert proc.returncode == 0, proc.stderr
        assert stat.S_ISCHR(os.stat(os.devnull).st_mode)
        assert not Path("/dev/null.json").exists()
        assert _temporaries(d) == []
    finally:
        d.chmod(0o755)
        shutil.rmtree(top)


def _run_and_signal(args, cwd, delay, sig):
    proc = popen(*args, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    wait_at_most(proc, delay)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=120)
    return proc.returncode, err


def _set_state(d: Path, outputs) -> str:
    """'old' (every output as before), 'new' (every output changed) or 'mixed'."""
    changed = {o: digest(d / o) != (d / (o + ".before")).read_text()
               for o in outputs}
    if not any(changed.values()):
        return "old"
    return "new" if all(changed.values()) else f"mixed {changed}"


@pytest.fixture(scope="module")
def complete_run(workdir, tmp_path_factory):
    """``complete_run(name) -> (directory, seconds)``: the inputs and the outputs of one
    complete run of the command as a subprocess, and how long that whole process took; made
    once per command and copied by each signal's test (the previous set it interrupts)."""
    made = {}

    def get(name):
        if name not in made:
            d = tmp_path_factory.mktemp(f"complete-{name}")
            for f in workdir.iterdir():
                if f.is_file():
                    (d / f.name).write_bytes(f.read_bytes())
            _, _, outputs = COMMANDS[name]
            t0 = time.perf_counter()
            first = run_process(*_args(name, outputs), cwd=d)
            total = time.perf_counter() - t0
            assert first.returncode == 0, first.stderr
            made[name] = d, total
        return made[name]

    return get


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL],
                         ids=["ctrl-c", "sigterm", "kill-9"])
@pytest.mark.parametrize("name", ["calibrate", "select-poses", "errors", "montecarlo"])
def test_interrupted_runs_leave_the_previous_set_or_the_whole_new_one(complete_run, tmp_path,
                                                                    name, sig):
    args, inputs, outputs = COMMANDS[name]
    # the first (complete) run's time decides where to interrupt: early, middle, near the end
    # (a whole process, as the interrupted ones: start-up included); its outputs are the
    # previous set (one complete run per command, shared by the three signals)
    first, total = complete_run(name)
    d = tmp_path / "d"
    shutil.copytree(first, d)
    seen = set()

    def interrupt(frac):
        for o in outputs:           # make the previous set recognisable
            (d / o).write_bytes((d / o).read_bytes() + b"\n")
            (d / (o + ".before")).write_text(digest(d / o))
        code, err = _run_and_signal(_args(name, outputs), d, frac * total, sig)
        state = _set_state(d, outputs)
        assert state in ("old", "new"), (frac, state, err)
        seen.add(state)
        if code > 0:                 # interrupted: one line, no traceback (code < 0: the
            assert "Traceback" not in err, err      # signal came before Python started)
            if sig == signal.SIGINT:
                assert code == 130 and err.strip().endswith("interrupted"), (code, err)
            if sig == signal.SIGTERM:
                assert code == 143 and "terminated" in err, (code, err)
        if sig != signal.SIGKILL:
            assert _temporaries(d) == [], (frac, _temporaries(d))
        for o in outputs:
            (d / (o + ".before")).unlink()

    for frac in (0.15, 0.6, 0.95):
        interrupt(frac)
    # whatever a killed run left behind is hidden, and the next run cleans it up
    assert all(n.startswith(".") for n in _temporaries(d))
    again = run(*_args(name, outputs), cwd=d)
    assert again.returncode == 0, again.stderr
    assert _temporaries(d) == []
    assert "old" in seen            # at least the early interrupt left the previous set


@pytest.mark.parametrize("name", ["calibrate", "montecarlo", "errors"])
def test_two_runs_at_once_both_succeed(workdir, tmp_path, name):
    d = tmp_path
    for f in workdir.iterdir():
        if f.is_file():
            (d / f.name).write_bytes(f.read_bytes())
    args, inputs, outputs = COMMANDS[name]
    procs = [subprocess.Popen([str(PKMCAL), *_args(name, outputs)], cwd=d,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(2)]
    for p in procs:
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
    assert _temporaries(d) == []
    for o in outputs:
        assert (d / o).is_file()
    if name == "calibrate":          # the machine file and its report come from one run
        info = yaml.safe_load((d / "c.yaml").read_text())["calibration"]
        assert info["report_sha256"] == digest(d / "c.json")


def _children(pid: int) -> list[int]:
    out = []
    for status in Path("/proc").glob("[0-9]*/status"):
        try:
            text = status.read_text()
        except OSError:
            continue
        fields = dict(line.split(":\t", 1) for line in text.splitlines() if ":\t" in line)
        if fields.get("PPid", "").strip() == str(pid):
            out.append(int(status.parent.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "\nState:\tZ" not in state


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc (Linux)")
def test_montecarlo_workers_end_when_the_parent_is_killed(tmp_path):
    # --workers 3: the command computes too, beside a pool of two worker processes
    proc = subprocess.Popen([str(PKMCAL), "montecarlo", "default", "--vary",
                             "noise=1,2,3,4um", "--runs", "40", "--workers", "3", "-o", "mc"],
                            cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers = []
    deadline = time.monotonic() + 60
    while len(workers) < 2 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.2)
        workers = [c for c in _children(proc.pid) if _alive(c)]
    assert len(workers) >= 2, "the workers did not start"
    time.sleep(1.0)                  # the workers are computing now
    proc.kill()
    proc.wait()
    # the workers end at once (the kernel's parent-death signal, else their watch of the
    # parent every 0.2 s); without that they never do (measured: still alive 300 s later):
    # a generous wait for an event, not a speed requirement
    deadline = time.monotonic() + 60
    while any(_alive(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [w for w in workers if _alive(w)]
    for w in left:
        os.kill(w, signal.SIGKILL)
    assert not left, "montecarlo workers outlived their parent"
    assert not (tmp_path / "mc").exists()        # nothing of the killed run's set


def test_a_full_disk_names_the_users_file_and_leaves_no_temporary(tmp_path, monkeypatch):
    def full(fd):
        raise OSError(28, "No space left on device")

    target = tmp_path / "cal.yaml"
    target.write_text("previous")
    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(InputError) as info, OutputSet([target]):
        atomic_write_text(target, "new" * 1000)
    assert str(info.value).startswith(f"{target}: cannot write: No space left")
    assert ".tmp" not in str(info.value)
    assert target.read_text() == "previous" and _temporaries(tmp_path) == []


def test_a_name_near_the_file_system_limit_still_has_a_temporary(tmp_path):
    long = tmp_path / ("x" * 240 + ".csv")
    long.write_text("old")
    atomic_write_text(long, "new")
    assert long.read_text() == "new" and _temporaries(tmp_path) == []


@pytest.mark.parametrize("delay", [0.05, 0.15, 0.3, 0.6])
def test_ctrl_c_at_any_moment_is_one_line_and_exit_130(workdir, tmp_path, delay):
    """Also while the modules are still being imported (the console script's _entry)."""
    (tmp_path / "data.csv").write_bytes((workdir / "data.csv").read_bytes())
    code, err = _run_and_signal(["calibrate", "default", "data.csv", "-o", "c.yaml"],
                                tmp_path, delay, signal.SIGINT)
    if code < 0:                    # the signal came before Python set up its handler
        return
    if code == 0:                   # a fast machine finished first: the whole set is there
        assert (tmp_path / "c.yaml").is_file() and (tmp_path / "c.json").is_file()
        return
    assert code == 130, (code, err)
    assert err.strip().splitlines() == ["error: interrupted"], err
    assert _visible(tmp_path) == ["data.csv"] and _temporaries(tmp_path) == []
