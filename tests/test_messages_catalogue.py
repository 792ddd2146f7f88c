"""Messages that must send the user the right way (issue 28): an independent catalogue.

Each case is a user's mistake; the command must end with exit 2 and one line that names the
file and the key, row or argument the user must fix, in the file's own terms, and not a
wrong cause: joint limits that exclude the bed's centre (not "set the bed or home"), probe
planning on a machine without a bed (not "widen the candidate set"), a quote left open in a
data file (the row it opened on, not the row the csv module stopped at), text where a
calibration report holds a number (the key path, in every section), an empty argument (its
name, MACHINE, DATA, ...), and a format version written as text.
"""

from __future__ import annotations

import functools
import hashlib
import json
import operator
import re
from pathlib import Path

import pytest

from clitools import assert_input_error, digest, run
from pkmcal.errors import InputError
from pkmcal.report.schema import load_report

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
LINEAR = (EXAMPLES / "linear_delta.yaml").read_text()
DELTA = str(EXAMPLES / "delta_default.yaml")
HEXASLIDE = (EXAMPLES / "hexaslide_default.yaml").read_text()


def refused(tmp_path, args, words, wrong=()):
    """Run ``pkmcal *args`` in ``tmp_path``: exit 2, one line holding every word of ``words``
    and none of ``wrong``; the inputs unchanged and no file added. The message."""
    before = {p.name: digest(p) for p in tmp_path.iterdir() if p.is_file()}
    proc = run(*args, cwd=tmp_path)
    assert_input_error(proc, *words)
    for w in wrong:
        assert w not in proc.stderr, proc.stderr
    assert {p.name: digest(p) for p in tmp_path.iterdir() if p.is_file()} == before
    return proc.stderr.strip()


def with_limits(text: str, limits: str) -> str:
    """A machine file's text with ``joint_limits`` before ``home``."""
    return text.replace("\nhome:", f"\njoint_limits: {limits}\nhome:", 1)


@pytest.fixture(scope="module")
def probe(tmp_path_factory):
    """A linear Delta's probe heights (37 rows), its calibration and report: the inputs of
    the data-file and report cases."""
    d = tmp_path_factory.mktemp("probe")
    (d / "ld.yaml").write_text(LINEAR)
    assert run("simulate", "ld.yaml", "--scenario", "probe", "-o", "probe.csv",
               cwd=d).returncode == 0
    assert run("-q", "calibrate", "ld.yaml", "probe.csv", "-o", "cal.yaml",
               cwd=d).returncode == 0
    (d / "targets.csv").write_text("x_mm,y_mm,z_mm\n0,0,10\n5,5,20\n")
    return {name: (d / name).read_bytes()
            for name in ("ld.yaml", "probe.csv", "cal.yaml", "cal.json", "targets.csv")}


def put(tmp_path, files, *names):
    for name in names:
        (tmp_path / name).write_bytes(files[name])


# -- joint limits that exclude every probe point ------------------------------------------

LIMIT_COMMANDS = {
    "simulate": ["simulate", "lim.yaml", "--scenario", "probe", "-o", "p.csv"],
    "select-poses": ["select-poses", "lim.yaml", "--scenario", "probe", "-n", "20", "-o",
                     "plan.csv"],
    "identifiability": ["identifiability", "lim.yaml", "--scenario", "probe"],
}


@pytest.mark.parametrize("command", sorted(LIMIT_COMMANDS))
def test_joint_limits_below_the_bed_are_named_not_the_bed(tmp_path, command):
    """The carriages sit ~285 mm below the endstops at the bed's centre: limits of 0..50 mm
    exclude every probe point; the cause is joint_limits, not the bed or home."""
    (tmp_path / "lim.yaml").write_text(with_limits(LINEAR, "{min: 0, max: 50}"))
    message = refused(tmp_path, LIMIT_COMMANDS[command],
                      ["lim.yaml", "joint_limits", "q1..q3 within 0..50 mm",
                       "q1 = 285 mm above max 50 mm", "widen joint_limits"],
                      wrong=["set the bed or home", "cannot be probed"])
    assert "bed's centre" in message


def test_one_joints_limit_is_named_alone(tmp_path):
    (tmp_path / "lim.yaml").write_text(with_limits(LINEAR, "{min: 0, max: [400, 100, 400]}"))
    message = refused(tmp_path, LIMIT_COMMANDS["simulate"],
                      ["lim.yaml", "joint_limits", "q2 = 285 mm above max 100 mm"],
                      wrong=["set the bed or home"])
    assert "q1 =" not in message and "q3 =" not in message


def test_limits_above_the_centre_are_named_by_their_min(tmp_path):
    (tmp_path / "lim.yaml").write_text(with_limits(LINEAR, "{min: 290, max: 400}"))
    refused(tmp_path, LIMIT_COMMANDS["simulate"],
            ["lim.yaml", "joint_limits", "below min 290 mm"], wrong=["set the bed or home"])


def test_limits_that_exclude_a_set_probe_radius_are_named(tmp_path):
    """With probe_radius in the file the pattern is not fitted to the limits: the points
    outside them are named with the limits (the simulated data were written before)."""
    text = with_limits(LINEAR, "{min: 0, max: 300}").replace("\nhome:",
                                                            "\nprobe_radius: 120\nhome:")
    (tmp_path / "lim.yaml").write_text(text)
    refused(tmp_path, LIMIT_COMMANDS["simulate"],
            ["lim.yaml", "joint_limits (q1..q3 within 0..300 mm) exclude 33 of the 37 probe "
             "points", "above max 300 mm", "widen joint_limits or lower probe_radius"])


def test_limits_that_hold_the_centre_still_plan(tmp_path):
    (tmp_path / "lim.yaml").write_text(with_limits(LINEAR, "{min: 0, max: 400}"))
    assert run(*LIMIT_COMMANDS["simulate"], cwd=tmp_path).returncode == 0


# -- probe planning on a machine without a bed --------------------------------------------

@pytest.mark.parametrize("machine, kind", [("default", "hexaslide"), (DELTA, "delta"),
                                           ("bed.yaml", "hexaslide")])
def test_probe_plans_on_a_machine_without_a_bed_name_it(tmp_path, machine, kind):
    """No candidate set helps: the estimated bed plane takes up moves of the whole platform;
    the message says the machine has no bed and which scenarios measure the platform (a
    bed section in the file does not make it a printer)."""
    (tmp_path / "bed.yaml").write_text(HEXASLIDE + "bed: {height: 300, tilt_x: 0, tilt_y: 0}\n")
    message = refused(tmp_path, ["select-poses", machine, "--scenario", "probe", "-n", "30",
                                 "-o", "plan.csv"],
                      ["--scenario probe", f"a {kind} has no bed", "machine: linear_delta",
                       "tracker", "distance"],
                      wrong=["widen the candidate set", "<candidates>"])
    assert Path(machine).name in message
    assert re.search(r"choose a scenario that measures the platform: [a-z-]+(, [a-z-]+)*$",
                     message), message
    assert "probe" not in message.rsplit(":", 1)[1]


def test_a_printer_plans_probe_points(tmp_path):
    (tmp_path / "ld.yaml").write_text(LINEAR)
    proc = run("select-poses", "ld.yaml", "--scenario", "probe", "-n", "20", "-o", "plan.csv",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr


# -- a quote left open in a data file -----------------------------------------------------

def open_quote(text: str, line: int, column: int = 0, end: str = "\n") -> str:
    """``text`` with a quote opened before field ``column`` of file line ``line``."""
    lines = text.splitlines()
    fields = lines[line - 1].split(",")
    fields[column] = '"' + fields[column]
    lines[line - 1] = ",".join(fields)
    return end.join(lines) + end


QUOTES = {
    # name: (line of the quote, column, rows kept, line end, close on line, final break)
    "row 6, to the end": (6, 0, 12, "\n", None, True),
    "row 6, column 3": (6, 2, 12, "\n", None, True),
    "row 2, first data row": (2, 3, 12, "\n", None, True),
    "last row, no final line break": (12, 1, 12, "\n", None, False),
    "last row, CRLF": (12, 3, 12, "\r\n", None, True),
    "closed three rows later": (6, 1, 12, "\n", 9, True),
    "old Mac line ends": (6, 0, 12, "\r", None, False),
}


@pytest.mark.parametrize("name", sorted(QUOTES))
def test_an_open_quote_is_named_at_its_row(tmp_path, probe, name):
    line, column, keep, end, closed, final = QUOTES[name]
    lines = probe["probe.csv"].decode().splitlines()[:keep]
    header = lines[0].split(",")
    text = open_quote("\n".join(lines), line, column, end)
    if closed is not None:
        rows = text.split(end)
        rows[closed - 1] += '"'
        text = end.join(rows)
    if not final:
        text = text.rstrip("\r\n")
    (tmp_path / "ld.yaml").write_bytes(probe["ld.yaml"])
    (tmp_path / "data.csv").write_bytes(text.encode())
    message = refused(tmp_path, ["calibrate", "ld.yaml", "data.csv", "-o", "c.yaml"],
                      [f"data.csv: row {line}, column {header[column]}: a quote"],
                      wrong=["field(s), the header", "equation(s)"])
    if closed is not None:
        assert f"on to row {closed}" in message
    else:
        assert "to the end of the file" in message


def test_an_open_quote_in_the_header_is_named(tmp_path, probe):
    put(tmp_path, probe, "ld.yaml")
    text = '"' + probe["probe.csv"].decode()
    (tmp_path / "data.csv").write_text(text)
    refused(tmp_path, ["calibrate", "ld.yaml", "data.csv", "-o", "c.yaml"],
            ["data.csv: row 1: a quote"])


@pytest.mark.parametrize("command, name, text, row", [
    ("compensate", "targets.csv", 'x_mm,y_mm,z_mm\n0,0,10\n"5,5,20\n1,1,30\n', 3),
    ("ik", "poses.csv", 'x_mm,y_mm,z_mm\n0,0,10\n1,1,20\n2,"2,30\n', 4),
    ("fk", "joints.csv", 'q1_mm,q2_mm,q3_mm\n"285,285,285', 2),
])
def test_an_open_quote_is_named_in_every_commands_files(tmp_path, probe, command, name,
                                                        text, row):
    put(tmp_path, probe, "ld.yaml", "cal.yaml", "cal.json")
    (tmp_path / name).write_text(text)
    machine = "cal.yaml" if command == "compensate" else "ld.yaml"
    refused(tmp_path, [command, machine, name, "-o", "out.csv"], [f"{name}: row {row}",
                                                                  "a quote"])


def test_a_quote_inside_a_number_is_the_number(tmp_path, probe):
    """A quote inside a field opens nothing (the csv module reads it as a character): the
    field is not a number, named as such."""
    put(tmp_path, probe, "ld.yaml")
    lines = probe["probe.csv"].decode().splitlines()
    lines[4] = "2" + '"' + lines[4][1:]
    (tmp_path / "data.csv").write_text("\n".join(lines) + "\n")
    refused(tmp_path, ["calibrate", "ld.yaml", "data.csv", "-o", "c.yaml"],
            ["data.csv: row 5, column q1_mm: not a number"], wrong=["a quote"])


def test_well_quoted_fields_are_read(tmp_path, probe):
    put(tmp_path, probe, "ld.yaml")
    lines = probe["probe.csv"].decode().splitlines()
    lines[3] = ",".join(f'"{f}"' for f in lines[3].split(","))
    (tmp_path / "data.csv").write_text("\n".join(lines) + "\n")
    proc = run("-q", "calibrate", "ld.yaml", "data.csv", "-o", "c.yaml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr


# -- text where a report holds a number ---------------------------------------------------

def edited_report(tmp_path, probe, edit):
    """cal.yaml and cal.json in ``tmp_path``, the report edited by ``edit(doc)`` and
    cal.yaml's report hash updated (so the edit, not the hash, is what is refused)."""
    doc = json.loads(probe["cal.json"])
    edit(doc)
    (tmp_path / "cal.json").write_text(json.dumps(doc, indent=1))
    sha = hashlib.sha256((tmp_path / "cal.json").read_bytes()).hexdigest()
    text = re.sub(r"report_sha256: \w+", f"report_sha256: {sha}", probe["cal.yaml"].decode())
    (tmp_path / "cal.yaml").write_text(text)
    (tmp_path / "targets.csv").write_bytes(probe["targets.csv"])


def setter(path, value):
    def edit(doc):
        node = doc
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value
    return edit


REPORT_CASES = {
    "covariance text": (("covariance", "matrix", 3, 7), "abc",
                        'covariance.matrix[3][7]: expected a number, got "abc"'),
    "covariance numeric text": (("covariance", "matrix", 0, 0), "1e-6",
                                'covariance.matrix[0][0]: expected a number, got "1e-6"'),
    "covariance null": (("covariance", "matrix", 2, 1), None,
                        "covariance.matrix[2][1]: expected a number, got null"),
    "covariance row as text": (("covariance", "matrix", 4), "abc",
                               'covariance.matrix[4]: expected a list, got "abc"'),
    "null space text": (("covariance", "null_space", 1, 0), "x",
                        'covariance.null_space[1][0]: expected a number, got "x"'),
    "std text": (("parameters", 3, "std"), "abc",
                 'parameters[3].std: expected a number, got "abc"'),
    "identified bool": (("parameters", 0, "identified"), True,
                        "parameters[0].identified: expected a number, got true"),
    "change text": (("parameters", 5, "change"), "+1",
                    'parameters[5].change: expected a number, got "+1"'),
    "chi2 text (was an internal error)": (
        ("acceptance", "residuals", "chi2"), "abc",
        'acceptance.residuals.chi2: expected a number, got "abc"'),
    "dof as a fraction": (("acceptance", "residuals", "dof"), 2.5,
                          "acceptance.residuals.dof: expected a whole number, got 2.5"),
    "bed height text": (("bed", "height"), "0", 'bed.height: expected a number, got "0"'),
    "rms text": (("residuals", "rms_um"), "6.4 um",
                 'residuals.rms_um: expected a number, got "6.4 um"'),
    "measurements text": (("measurements",), "37",
                          'measurements: expected a whole number, got "37"'),
    "version as text": (("pkmcal_report",), "1",
                        'pkmcal_report: must be the number 1, not the text "1"'),
    "version 2": (("pkmcal_report",), 2, "pkmcal_report: expected 1, got 2"),
    "units as a number": (("units", "length"), 1,
                          "units.length: expected 'mm', 'm' or 'in', got 1"),
    "success as text": (("convergence", "success"), "yes",
                        'convergence.success: expected true or false, got "yes"'),
    "poorly determined std": (("poorly_determined", "parameters", 0, "std"), "big",
                              'poorly_determined.parameters[0].std: expected a number, '
                              'got "big"'),
}


@pytest.mark.parametrize("command", ["report", "compensate"])
@pytest.mark.parametrize("name", sorted(REPORT_CASES))
def test_text_in_a_report_is_named_by_key_path(tmp_path, probe, name, command):
    path, value, words = REPORT_CASES[name]
    edited_report(tmp_path, probe, setter(path, value))
    args = (["report", "cal.json", "-o", "r.html"] if command == "report"
            else ["compensate", "cal.yaml", "targets.csv", "-o", "q.csv"])
    refused(tmp_path, args, [f"cal.json: {words}"],
            wrong=["Input should", "internal error", "is not the report of"])


def numeric_leaves(doc, loc=()):
    """Key paths of the numbers of a report (two elements of each long list)."""
    if isinstance(doc, dict):
        for key, value in doc.items():
            yield from numeric_leaves(value, (*loc, key))
    elif isinstance(doc, list):
        for i in sorted({0, len(doc) - 1}) if len(doc) > 3 else range(len(doc)):
            yield from numeric_leaves(doc[i], (*loc, i))
    elif isinstance(doc, (int, float)) and not isinstance(doc, bool):
        yield loc


def key_path(loc) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


@pytest.fixture(scope="module")
def reports(probe, tmp_path_factory):
    """Reports of other kinds: a Delta from a tracker (registration, identifiable
    combinations), a six-leg platform from full poses (frames, noise levels), a linear Delta
    from probe heights and a ballbar together (files of a joint fit), a Hexa Slide with rows
    held out (validation, link length)."""
    d = tmp_path_factory.mktemp("reports")
    (d / "ld.yaml").write_bytes(probe["ld.yaml"])
    (d / "probe.csv").write_bytes(probe["probe.csv"])
    steps = [("simulate", DELTA, "--scenario", "tracker", "-o", "tr.csv"),
             ("calibrate", DELTA, "tr.csv", "-o", "delta.yaml"),
             ("simulate", str(EXAMPLES / "cubic_6upu.yaml"), "--scenario", "pose", "--poses",
              "60", "-o", "po.csv"),
             ("calibrate", str(EXAMPLES / "cubic_6upu.yaml"), "po.csv", "-o", "six.yaml"),
             ("simulate", "ld.yaml", "--scenario", "distance", "-o", "bb.csv"),
             ("calibrate", "ld.yaml", "probe.csv", "bb.csv", "-o", "joint.yaml"),
             ("simulate", "default", "-o", "cl.csv"),
             ("calibrate", "default", "cl.csv", "--holdout", "0.2", "-o", "held.yaml")]
    for step in steps:
        proc = run("-q", *step, cwd=d)
        assert proc.returncode == 0, proc.stderr
    docs = {"probe": json.loads(probe["cal.json"])}
    docs.update({name: json.loads((d / f"{name}.json").read_text())
                 for name in ("delta", "six", "joint", "held")})
    return docs


@pytest.mark.parametrize("kind", ["probe", "delta", "six", "joint", "held"])
def test_every_number_of_a_report_as_text_is_named(tmp_path, reports, kind):
    """Each number of a report (two elements of each long list) replaced by text, in turn:
    refused naming its key path, in the schema's sections and in those shown as written."""
    doc = reports[kind]
    path = tmp_path / "cal.json"
    missed = []
    leaves = list(numeric_leaves(doc))
    assert len(leaves) > 50
    # json.dumps(doc) of a dict is its top-level members' texts joined: only the member
    # holding the replaced number is written again (the covariance alone was most of each
    # file's ~15 ms of encoding, for one number elsewhere)
    members = {key: json.dumps(value) for key, value in doc.items()}

    def dumped(changed):
        return "{" + ", ".join(f"{json.dumps(key)}: "
                               f"{json.dumps(doc[key]) if key == changed else text}"
                               for key, text in members.items()) + "}"

    assert dumped(None) == json.dumps(doc)
    for loc in leaves:
        # the one number replaced in place and put back (a copy of the whole report per
        # number cost more than reading it)
        parent = functools.reduce(operator.getitem, loc[:-1], doc)
        value = parent[loc[-1]]
        parent[loc[-1]] = "abc"
        try:
            path.write_text(dumped(loc[0]))
        finally:
            parent[loc[-1]] = value
        try:
            load_report(path)
        except InputError as exc:
            if f"cal.json: {key_path(loc)}: " not in str(exc) or '"abc"' not in str(exc):
                missed.append(f"{key_path(loc)}: {exc}")
        else:
            missed.append(f"{key_path(loc)}: accepted")
    assert not missed, "\n".join(missed)
    path.write_text(json.dumps(doc))
    assert load_report(path) == doc


def test_a_nan_in_a_report_is_placed_by_line(tmp_path, probe):
    text = probe["cal.json"].decode()
    lines = text.splitlines()
    k = next(i for i, line in enumerate(lines) if '"rms_um"' in line)
    lines[k] = re.sub(r'("rms_um": )[-0-9.e+]+', r"\1NaN", lines[k])
    (tmp_path / "cal.json").write_text("\n".join(lines))
    refused(tmp_path, ["report", "cal.json", "-o", "r.html"], [f"cal.json: line {k + 1}, ",
                                                              "NaN"])


# -- an empty argument ---------------------------------------------------------------------

EMPTY = {
    "machine of calibrate": (["calibrate", "", "probe.csv", "-o", "c.yaml"],
                             "MACHINE (machine file, argument 1 of pkmcal calibrate)"),
    "machine after an option's value": (
        ["calibrate", "--noise", "10um", "", "probe.csv", "-o", "c.yaml"],
        "MACHINE (machine file, argument 1 of pkmcal calibrate)"),
    "machine after a flag": (["calibrate", "--json", "", "probe.csv"],
                             "MACHINE (machine file, argument 1 of pkmcal calibrate)"),
    "machine after --quiet": (["-q", "simulate", "", "-o", "s.csv"],
                              "MACHINE (machine file, argument 1 of pkmcal simulate)"),
    "data of calibrate": (["calibrate", "ld.yaml", "", "-o", "c.yaml"],
                          "DATA (measurement file(s), argument 2 of pkmcal calibrate)"),
    "second data file": (["calibrate", "ld.yaml", "probe.csv", "", "-o", "c.yaml"],
                         "DATA (measurement file(s), argument 3 of pkmcal calibrate)"),
    "calibrated of compensate": (["compensate", "", "targets.csv", "-o", "q.csv"],
                                 "CALIBRATED (the calibrated machine file, argument 1 of "
                                 "pkmcal compensate)"),
    "targets of compensate": (["compensate", "cal.yaml", "", "-o", "q.csv"],
                              "TARGETS.csv (target poses, argument 2 of pkmcal compensate)"),
    "controller file of import": (["import", "", "--from", "klipper", "-o", "m.yaml"],
                                  "FILE (the controller's parameter file, argument 1 of "
                                  "pkmcal import)"),
    "report of report": (["report", "", "-o", "r.html"],
                         "RESULT (a calibration report, argument 1 of pkmcal report)"),
    "machine of montecarlo": (["montecarlo", "", "--vary", "poses=20,30", "-o", "mc"],
                              "MACHINE (machine file, argument 1 of pkmcal montecarlo)"),
    "the command": (["", "ld.yaml"], "COMMAND (the first argument"),
    "the output": (["calibrate", "ld.yaml", "probe.csv", "-o", ""], "-o: an empty value"),
    "an option with =": (["calibrate", "ld.yaml", "probe.csv", "--noise=", "-o", "c.yaml"],
                         "--noise: an empty value"),
}


@pytest.mark.parametrize("name", sorted(EMPTY))
def test_an_empty_argument_is_named(tmp_path, probe, name):
    put(tmp_path, probe, "ld.yaml", "probe.csv", "cal.yaml", "cal.json", "targets.csv")
    args, words = EMPTY[name]
    message = refused(tmp_path, args, [words, "an empty value (an unset shell variable?)"])
    if not words.startswith("-"):
        assert "leave the option out" not in message and "(after " not in message


# -- a format version written as text -----------------------------------------------------

VERSIONS = {
    "double-quoted": ('pkmcal: "1"', "must be the number 1, not the text '1' (line 1); "
                                     "write pkmcal: 1 without quotes"),
    "single-quoted": ("pkmcal: '1'", "must be the number 1, not the text '1' (line 1)"),
    "with spaces": ('pkmcal: " 1 "', "must be the number 1, not the text ' 1 '"),
    "a fraction": ("pkmcal: 1.0", "must be the number 1, not 1.0 (line 1); write pkmcal: 1"),
    "a word": ("pkmcal: one", "must be the number 1, not the text 'one'"),
    "a boolean": ("pkmcal: true", "must be the number 1, not true"),
    "a later version": ("pkmcal: 2", "unsupported file format version 2 (line 1); this "
                                     "pkmcal reads version 1"),
}


@pytest.mark.parametrize("name", sorted(VERSIONS))
def test_a_text_version_is_explained(tmp_path, probe, name):
    line, words = VERSIONS[name]
    put(tmp_path, probe, "targets.csv")
    (tmp_path / "m.yaml").write_text(LINEAR.replace("pkmcal: 1", line, 1))
    message = refused(tmp_path, ["ik", "m.yaml", "targets.csv", "-o", "q.csv"],
                      [f"m.yaml: pkmcal: {words}"
                       if name == "a later version" else
                       f"m.yaml: pkmcal: the file format version {words}"])
    if name != "a later version":
        assert "unsupported" not in message


@pytest.mark.parametrize("old, new, words", [
    ("delta_radius: 132.5", 'delta_radius: "132.5"',
     "delta_radius: not a number: the text '132.5' (write it without quotes) (line 5)"),
    ("home: [0.0, 0.0, 100.0]", "home: [0.0, '0', 100.0]",
     "home[1]: not a number: the text '0' (write it without quotes) (line 9)"),
    ("arm_length: 250.0", "arm_length: [250, 250, '250']",
     "arm_length: not a number: '250'"),
    ("home:", "joint_limits: {min: '0', max: 400}\nhome:",
     "joint_limits.min: not a number: the text '0' (write it without quotes)"),
    ("arm_length: 250.0", "arm_length: long", "arm_length: not a number: 'long'"),
])
def test_text_numbers_in_a_machine_file_are_named(tmp_path, probe, old, new, words):
    put(tmp_path, probe, "targets.csv")
    assert old in LINEAR
    (tmp_path / "m.yaml").write_text(LINEAR.replace(old, new, 1))
    message = refused(tmp_path, ["ik", "m.yaml", "targets.csv", "-o", "q.csv"],
                      [f"m.yaml: {words}"])
    assert "(line " in message
    if "'long'" in words:
        assert "without quotes" not in message
