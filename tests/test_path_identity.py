"""One file by two names, and names that are not UTF-8 (issue 28), on every command that
takes files.

- "The same file" is one device and inode (:func:`pkmcal.paths.file_identity`): a hard link,
  a symbolic link, ``./x`` and an absolute spelling of a data file given twice are refused
  (exit 2, one line naming both names); the same file named as an input and as an output is
  refused without writing anything.
- A name that is not UTF-8 (``$'\\xff'``) as an input, an output or an output directory of
  every command works: the file appears under exactly those bytes, the console and the
  messages show the byte as ``\\xff`` (:func:`pkmcal.paths.path_text`), the JSON and YAML
  records hold UTF-8 text, and the report a calibrated file names is still found.

Commands run in this process (``clitools.run``); the one check of a strict UTF-8 stdout runs
a subprocess (the in-process runner's stdout cannot fail to encode).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from clitools import assert_input_error, digest, run, run_process
from pkmcal.paths import file_identity, path_from_text, path_text, same_file

#: the byte 0xff, as Python holds it in a file name (os.fsdecode)
X = os.fsdecode(b"\xff")
#: how messages, the console and records show it
SHOWN = "\\xff"
#: a Klipper config of a linear delta (its geometry is all ``import`` reads)
KLIPPER = """[printer]
kinematics: delta
delta_radius: 132.5

[stepper_a]
microsteps: 16
rotation_distance: 40
arm_length: 268.0
position_endstop: 296.4
angle: 210.3

[stepper_b]
microsteps: 16
rotation_distance: 40
position_endstop: 296.9
angle: 330.2

[stepper_c]
microsteps: 16
rotation_distance: 40
position_endstop: 296.4
"""
EXAMPLES = Path(__file__).parents[1] / "examples"


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """Inputs of every command: a Hexa Slide calibration and its data, poses, targets and a
    trajectory; a linear Delta, its probe data and calibration; a Klipper config."""
    d = tmp_path_factory.mktemp("paths")
    shutil.copy(EXAMPLES / "linear_delta.yaml", d / "m.yaml")
    (d / "in.cfg").write_text(KLIPPER)
    for args in (["simulate", "default", "--poses", "60", "-o", "data.csv"],
                 ["calibrate", "default", "data.csv", "-o", "cal.yaml"],
                 ["fk", "cal.yaml", "data.csv", "-o", "poses.csv"],
                 ["simulate", "m.yaml", "--scenario", "probe", "-o", "probe.csv"],
                 ["calibrate", "m.yaml", "probe.csv", "-o", "ld.yaml"]):
        proc = run(*args, cwd=d)
        assert proc.returncode == 0, proc.stderr
    poses = (d / "poses.csv").read_text().splitlines()
    (d / "targets.csv").write_text("\n".join(poses[:6]) + "\n")
    (d / "traj.csv").write_text("t_s,x_mm,y_mm,z_mm\n" + "".join(
        f"{k * 0.01},{100 * (k % 3) / 3:.3f},0,410\n" for k in range(12)))
    return d


def _copy(workdir: Path, d: Path) -> Path:
    for f in workdir.iterdir():
        if f.is_file():
            shutil.copy(f, d / f.name)
    return d


#: command -> (arguments, input files, outputs); "{o}" is the outputs' name prefix
COMMANDS = {
    "simulate": (["simulate", "cal.yaml", "--poses", "50", "-o", "{o}sim.csv",
                  "--truth", "{o}truth.yaml"], ["cal.yaml"], ["{o}sim.csv", "{o}truth.yaml"]),
    "calibrate": (["calibrate", "m.yaml", "probe.csv", "-o", "{o}c.yaml", "--report",
                   "{o}rep"], ["m.yaml", "probe.csv"],
                  ["{o}c.yaml", "{o}c.json", "{o}rep/report.html", "{o}rep/report.json"]),
    "fk": (["fk", "cal.yaml", "data.csv", "-o", "{o}p.csv"], ["cal.yaml", "data.csv"],
           ["{o}p.csv"]),
    "ik": (["ik", "cal.yaml", "poses.csv", "-o", "{o}q.csv"], ["cal.yaml", "poses.csv"],
           ["{o}q.csv"]),
    "identifiability": (["identifiability", "cal.yaml", "data.csv", "--map", "{o}map.png"],
                        ["cal.yaml", "data.csv"], ["{o}map.png"]),
    "select-poses": (["select-poses", "cal.yaml", "-n", "50", "--candidates", "300",
                      "--random-sets", "3", "-o", "{o}plan.csv", "--map", "{o}plan.png"],
                     ["cal.yaml"], ["{o}plan.csv", "{o}plan.png"]),
    "compensate": (["compensate", "cal.yaml", "targets.csv", "-o", "{o}cmd.csv"],
                   ["cal.yaml", "targets.csv"], ["{o}cmd.csv"]),
    "export": (["export", "ld.yaml", "--to", "klipper", "-o", "{o}out.cfg"], ["ld.yaml"],
               ["{o}out.cfg", "{o}out.cfg.json"]),
    "import": (["import", "in.cfg", "--from", "klipper", "-o", "{o}imp.yaml"], ["in.cfg"],
               ["{o}imp.yaml"]),
    "report": (["report", "cal.yaml", "-o", "{o}r.html"], ["cal.yaml"],
               ["{o}r.html", "{o}r.json"]),
    "errors": (["errors", "cubic", "--trajectory", "file", "--trajectory-file", "traj.csv",
                "-o", "{o}e.csv", "--plot", "{o}pl"], ["traj.csv"],
               ["{o}e.csv", "{o}e_envelope.csv", "{o}pl/link_forces.png",
                "{o}pl/pose_errors.png", "{o}pl/error_map.png"]),
    "montecarlo": (["montecarlo", "m.yaml", "--vary", "noise=1,2um", "--runs", "2",
                    "--poses", "40", "--workers", "1", "-o", "{o}mc"], ["m.yaml"],
                   ["{o}mc/runs.csv", "{o}mc/summary.csv", "{o}mc/summary.json",
                    "{o}mc/montecarlo.png"]),
}


def _temporaries(d: Path) -> list[bytes]:
    """Hidden files a run left (its temporaries carry ``.pkmcal-``), by their bytes."""
    return [os.path.join(root, n) for root, _, names in os.walk(os.fsencode(d))
            for n in names if b".pkmcal-" in n]


def _args(name: str, prefix: str = "", rename: dict | None = None) -> list[str]:
    args = [a.format(o=prefix) for a in COMMANDS[name][0]]
    return [(rename or {}).get(a, a) for a in args]


def _no_surrogates(text: str) -> bool:
    return not any(0xD800 <= ord(c) <= 0xDFFF for c in text)


def _strings(obj):
    if isinstance(obj, str):
        yield obj
    elif isinstance(obj, dict):
        for k, v in obj.items():
            yield from _strings(k)
            yield from _strings(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from _strings(v)


def _records_are_utf8(path: Path) -> None:
    """A JSON or YAML output: strict UTF-8, no lone surrogate in any string it holds."""
    text = path.read_bytes().decode("utf-8")        # strict: raises on a raw 0xff
    assert "\\udcff" not in text.lower(), path
    if path.suffix == ".json":
        assert all(_no_surrogates(s) for s in _strings(json.loads(text))), path


# -- the two functions ------------------------------------------------------------------------


def test_path_text_escapes_what_is_not_printable_utf8_and_reads_back():
    for b in range(256):
        name = os.fsdecode(b"a" + bytes([b]) + b".csv")
        shown = path_text(name)
        shown.encode("utf-8")                                 # always encodable
        assert "\n" not in shown and "\r" not in shown
        assert os.fsencode(path_from_text(shown)) == b"a" + bytes([b]) + b".csv"
    assert path_text(X + "x.yaml") == "\\xffx.yaml"
    assert path_text(Path("d\udcfe") / "r.json") == "d\\xfe/r.json"
    assert path_text("ü/ok.csv") == "ü/ok.csv"               # valid UTF-8 is kept
    assert path_from_text("plain.csv") == "plain.csv"


def test_file_identity_is_device_and_inode(tmp_path):
    a = tmp_path / "a.csv"
    a.write_text("x\n")
    os.link(a, tmp_path / "hard.csv")
    (tmp_path / "sym.csv").symlink_to("a.csv")
    (tmp_path / "b.csv").write_text("x\n")                   # same bytes, another file
    st = os.stat(a)
    assert file_identity(a) == ("inode", st.st_dev, st.st_ino)
    for alias in ("hard.csv", "sym.csv", "./a.csv", str(a)):
        assert same_file(a, tmp_path / alias) if not alias.startswith("./") else \
            same_file(a, os.path.join(tmp_path, alias))
    assert not same_file(a, tmp_path / "b.csv")
    # names not made yet: the resolved path
    assert same_file(tmp_path / "new.csv", tmp_path / "." / "new.csv")
    assert not same_file(tmp_path / "new.csv", tmp_path / "new2.csv")


# -- one data file by two names ---------------------------------------------------------------


def _alias(d: Path, kind: str, target: str = "probe.csv") -> str:
    if kind == "hard link":
        os.link(d / target, d / "hard.csv")
        return "hard.csv"
    if kind == "symbolic link":
        (d / "sym.csv").symlink_to(target)
        return "sym.csv"
    if kind == "link to a link":
        (d / "sym.csv").symlink_to(target)
        (d / "sym2.csv").symlink_to("sym.csv")
        return "sym2.csv"
    if kind == "hard link in a subdirectory":
        (d / "sub").mkdir()
        os.link(d / target, d / "sub" / "copy.csv")
        return "sub/copy.csv"
    if kind == "absolute path":
        return str(d / target)
    if kind == "./ spelling":
        return "./" + target
    if kind == "same name":
        return target
    if kind == "not UTF-8 hard link":
        os.link(d / target, d / (X + ".csv"))
        return X + ".csv"
    raise AssertionError(kind)


@pytest.mark.parametrize("kind", ["hard link", "symbolic link", "link to a link",
                                  "hard link in a subdirectory", "absolute path",
                                  "./ spelling", "same name", "not UTF-8 hard link"])
def test_a_data_file_given_twice_is_refused(workdir, tmp_path, kind):
    d = _copy(workdir, tmp_path)
    alias = _alias(d, kind)
    proc = run("calibrate", "m.yaml", "probe.csv", alias, "-o", "c.yaml", cwd=d)
    assert_input_error(proc, "probe.csv", "the same data file is given twice")
    if kind not in ("./ spelling", "same name"):      # the shell's spellings of one name
        assert_input_error(proc, path_text(alias), "are the same file")
    assert not (d / "c.yaml").exists() and not (d / "c.json").exists()


def test_two_files_with_the_same_rows_are_two_files(workdir, tmp_path):
    """Identity is the inode, not the bytes: a copy is another file (refused for another
    reason, its rows repeat the first file's, or fitted: never 'the same file')."""
    d = _copy(workdir, tmp_path)
    shutil.copy(d / "probe.csv", d / "copy.csv")
    proc = run("calibrate", "m.yaml", "probe.csv", "copy.csv", "-o", "c.yaml", cwd=d)
    assert "same data file" not in proc.stderr


# -- an input named as an output --------------------------------------------------------------


def _first_output_slot(name: str) -> int:
    return next(i for i, a in enumerate(COMMANDS[name][0]) if "{o}" in a)


ALIAS_KINDS = ["hard link", "symbolic link", "./ spelling", "absolute path"]


@pytest.mark.parametrize("name,kind", [(n, k) for n in sorted(COMMANDS) for k in ALIAS_KINDS])
def test_an_input_by_another_name_is_never_an_output(workdir, tmp_path, name, kind):
    d = _copy(workdir, tmp_path)
    args, inputs, outputs = COMMANDS[name]
    victim = inputs[0]
    slot = _first_output_slot(name)
    out = args[slot].format(o="")
    if name == "montecarlo":            # an output directory: its runs.csv is the input
        (d / "mc").mkdir()
        inner = "mc/runs.csv"
    else:
        inner = out
    if kind == "hard link":
        os.link(d / victim, d / inner)
    elif kind == "symbolic link":
        (d / inner).symlink_to(os.path.relpath(d / victim, (d / inner).parent))
    elif kind == "./ spelling":
        out = "./" + victim if name != "montecarlo" else out
        if name == "montecarlo":
            os.link(d / victim, d / inner)
    else:
        out = str(d / victim) if name != "montecarlo" else str(d / out)
        if name == "montecarlo":
            os.link(d / victim, d / inner)
    call = list(_args(name))
    call[slot] = out
    before = {f: digest(d / f) for f in inputs}
    proc = run(*call, cwd=d)
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    assert_input_error(proc, victim)
    assert {f: digest(d / f) for f in inputs} == before       # nothing replaced
    assert _temporaries(d) == []


def test_a_report_named_through_a_hard_link(workdir, tmp_path):
    """The report a calibrated file pins is the same file under any name: given with
    --report through a hard link it is used; written over through one it is refused."""
    d = _copy(workdir, tmp_path)
    os.link(d / "cal.json", d / "alias.json")
    proc = run("compensate", "cal.yaml", "targets.csv", "-o", "cmd.csv", "--report",
               "alias.json", "--json", cwd=d)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["covariance_from"] == "alias.json"
    os.link(d / "cal.json", d / "x.json")
    before = digest(d / "cal.json")
    proc = run("report", "cal.yaml", "-o", "x.html", cwd=d)    # writes x.json too
    assert_input_error(proc, "x.json", "cal.json")
    assert digest(d / "cal.json") == before and not (d / "x.html").exists()


# -- names that are not UTF-8 -----------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_an_output_name_that_is_not_utf8_is_written_as_given(workdir, tmp_path, name):
    d = _copy(workdir, tmp_path)
    proc = run(*_args(name, X), cwd=d)
    assert proc.returncode == 0, proc.stderr
    for template in COMMANDS[name][2]:
        raw = os.fsencode(template.format(o=X))
        assert raw.startswith(b"\xff")
        assert os.path.isfile(os.fsencode(d) + b"/" + raw), (template, os.listdir(d))
        if raw.endswith((b".json", b".yaml")):
            _records_are_utf8(d / template.format(o=X))
    assert _no_surrogates(proc.stdout) and _no_surrogates(proc.stderr)
    if "wrote" in proc.stdout or "written" in proc.stdout:
        assert SHOWN in proc.stdout
    assert _temporaries(d) == []


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_an_input_name_that_is_not_utf8_is_read(workdir, tmp_path, name):
    d = _copy(workdir, tmp_path)
    rename = {}
    for f in COMMANDS[name][1]:
        os.rename(d / f, d / (X + f))
        rename[f] = X + f
    proc = run(*_args(name, "", rename), cwd=d)
    assert proc.returncode == 0, proc.stderr
    for template in COMMANDS[name][2]:
        assert (d / template.format(o="")).is_file(), template
        if template.endswith((".json", ".yaml")):
            _records_are_utf8(d / template.format(o=""))
    assert _no_surrogates(proc.stdout) and _no_surrogates(proc.stderr)


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_a_missing_input_that_is_not_utf8_is_one_line(workdir, tmp_path, name):
    d = _copy(workdir, tmp_path)
    victim = COMMANDS[name][1][0]
    missing = X + "missing" + Path(victim).suffix
    proc = run(*_args(name, "", {victim: missing}), cwd=d)
    assert_input_error(proc, SHOWN + "missing")
    assert _no_surrogates(proc.stderr)


def test_a_line_break_in_a_name_stays_on_one_line(workdir, tmp_path):
    d = _copy(workdir, tmp_path)
    proc = run("fk", "cal.yaml", "no\nsuch.csv", "-o", "p.csv", cwd=d)
    assert_input_error(proc, "no\\x0asuch.csv")
    proc = run("fk", "cal.yaml", "data.csv", "-o", "p\n.csv", cwd=d)
    assert proc.returncode == 0, proc.stderr
    assert (d / "p\n.csv").is_file() and "p\\x0a.csv" in proc.stdout


def test_a_calibrated_file_that_is_not_utf8_finds_its_report(workdir, tmp_path):
    """calibration.report records the name escaped; compensate, report and export map it
    back to the file beside; a report of another run is still refused, by its name."""
    d = _copy(workdir, tmp_path)
    cal, targets = X + "c.yaml", X + "t.csv"
    os.rename(d / "data.csv", d / (X + "data.csv"))
    os.rename(d / "targets.csv", d / targets)
    proc = run("calibrate", "default", X + "data.csv", "-o", cal, cwd=d)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().endswith(f"wrote {SHOWN}c.yaml and {SHOWN}c.json")
    text = (d / cal).read_bytes().decode("utf-8")
    assert f"report: {SHOWN}c.json" in text and f"data: {SHOWN}data.csv" in text
    report = json.loads((d / (X + "c.json")).read_text())
    assert report["calibrated_file"] == f"{SHOWN}c.yaml"
    assert report["data_file"] == f"{SHOWN}data.csv"
    proc = run("compensate", cal, targets, "-o", "cmd.csv", "--json", cwd=d)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["covariance_from"] == f"{SHOWN}c.json"
    assert summary["targets_file"] == f"{SHOWN}t.csv"
    assert run("report", cal, "-o", "r.html", cwd=d).returncode == 0
    assert json.loads((d / "r.json").read_text())["calibrated_file"] == f"{SHOWN}c.yaml"
    # another run's report under the pinned name: refused, both names shown escaped
    proc = run("calibrate", "default", X + "data.csv", "-o", X + "d.yaml", "--noise", "3um",
               cwd=d)
    assert proc.returncode == 0, proc.stderr
    os.replace(d / (X + "d.json"), d / (X + "c.json"))
    proc = run("compensate", cal, targets, "-o", "cmd.csv", cwd=d)
    assert_input_error(proc, f"{SHOWN}c.json: is not the report of {SHOWN}c.yaml")


def test_the_command_line_recorded_is_utf8_and_runs_in_bash(workdir, tmp_path):
    d = _copy(workdir, tmp_path)
    proc = run("calibrate", "m.yaml", "probe.csv", "-o", X + "c.yaml", cwd=d)
    assert proc.returncode == 0, proc.stderr
    text = (d / (X + "c.json")).read_bytes().decode("utf-8")
    assert "-o $'\\\\xffc.yaml'" in text        # JSON's escape of $'\xffc.yaml'


def test_a_strict_utf8_stdout_does_not_end_in_an_internal_error(workdir, tmp_path):
    """The issue's command: a terminal whose encoding refuses the byte (PYTHONIOENCODING
    strict) printed 'internal error (UnicodeEncodeError)' after import -o $'out-\\xff.yaml'."""
    d = _copy(workdir, tmp_path)
    env = dict(os.environ, PYTHONIOENCODING="utf-8:strict")
    proc = run_process("import", "in.cfg", "--from", "klipper", "-o", "out-" + X + ".yaml",
                       cwd=d, env=env)
    assert proc.returncode == 0, proc.stderr
    assert f"out-{SHOWN}.yaml" in proc.stdout
    assert os.path.isfile(os.fsencode(d) + b"/out-\xff.yaml")
    proc = run_process("fk", "cal.yaml", X + "none.csv", "-o", "p.csv", cwd=d, env=env)
    assert_input_error(proc, f"{SHOWN}none.csv")


def test_export_reads_the_pinned_report_of_a_name_that_is_not_utf8(workdir, tmp_path):
    """export takes the report a calibrated file names as an input: mapped back from its
    escaped record, it is found (and protected: FILE.json may not replace it)."""
    d = _copy(workdir, tmp_path)
    cal = X + "l.yaml"
    assert run("calibrate", "m.yaml", "probe.csv", "-o", cal, cwd=d).returncode == 0
    proc = run("export", cal, "--to", "klipper", "-o", X + "o.cfg", cwd=d)
    assert proc.returncode == 0, proc.stderr
    record = json.loads((d / (X + "o.cfg.json")).read_text())
    assert record["calibrated"] == f"{SHOWN}l.yaml" and record["file"] == f"{SHOWN}o.cfg"
    before = digest(d / (X + "l.json"))
    proc = run("export", cal, "--to", "klipper", "-o", X + "l", cwd=d)   # record: \xffl.json
    assert_input_error(proc, f"{SHOWN}l.json")
    assert digest(d / (X + "l.json")) == before


def test_the_library_refuses_one_file_twice(workdir, tmp_path):
    """pkmcal.calibration.calibrate decides "the same file" as the command does."""
    from pkmcal.calibration.run import calibrate
    from pkmcal.errors import InputError
    from pkmcal.io.machine_file import load_machine

    d = _copy(workdir, tmp_path)
    os.link(d / "probe.csv", d / "hard.csv")
    machine = load_machine(d / "m.yaml")
    with pytest.raises(InputError, match="probe.csv and .*hard.csv are the same file"):
        calibrate(machine, [d / "probe.csv", d / "hard.csv"])


def test_a_report_directory_file_that_is_an_input_is_refused(workdir, tmp_path):
    """--report DIR: DIR/report.json a hard link of the data file is the data file."""
    d = _copy(workdir, tmp_path)
    (d / "rep").mkdir()
    os.link(d / "probe.csv", d / "rep" / "report.json")
    before = digest(d / "probe.csv")
    proc = run("calibrate", "m.yaml", "probe.csv", "-o", "c.yaml", "--report", "rep", cwd=d)
    assert_input_error(proc, "report.json", "probe.csv")
    assert digest(d / "probe.csv") == before and not (d / "c.yaml").exists()


def test_a_klipper_include_of_the_same_file_by_another_name(workdir, tmp_path):
    """[include] of a hard link of the config itself is the recursion it is."""
    d = _copy(workdir, tmp_path)
    (d / "main.cfg").write_text("[include again.cfg]\n" + (d / "in.cfg").read_text())
    os.link(d / "main.cfg", d / "again.cfg")
    proc = run("import", "main.cfg", "--from", "klipper", "-o", "imp.yaml", cwd=d)
    assert_input_error(proc, "again.cfg", "included again from itself")
    assert not (d / "imp.yaml").exists()


def test_a_name_holding_a_backslash_is_not_read_as_an_escape(workdir, tmp_path):
    """A calibrated file named ``c\\x41.yaml`` (a real backslash) names its report as it is,
    not as ``cA.json``."""
    d = _copy(workdir, tmp_path)
    cal = "c\\x41.yaml"
    assert run("calibrate", "default", "data.csv", "-o", cal, cwd=d).returncode == 0
    assert (d / "c\\x41.json").is_file() and not (d / "cA.json").exists()
    proc = run("compensate", cal, "targets.csv", "-o", "cmd.csv", "--json", cwd=d)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["covariance_from"] == "c\\x41.json"
