"""Bad input fails fast and in proportion (issue 37 item 2).

A 50 MB file of comma-separated words given to ``pkmcal fk`` as data ran for more than 200 s:
the CSV reader split the whole text again for every row of a file without a final line break.
Each reader now refuses at the first row it cannot read (CSV data), after a bounded number of
lines that are not its format (G-code, HAL), at its first line (Klipper config, JSON) or by
its size before reading (machine files). Proportion is shown by what was read - records the
csv module gave, the line named, the count of lines looked at in the message - not by timing.
"""

from __future__ import annotations

import csv
import os
import types
from pathlib import Path

import pytest

from clitools import assert_input_error, run
from pkmcal.export.base import FOREIGN_SCAN_LINES
from pkmcal.io import csv_io, csv_table

ROOT = Path(__file__).resolve().parents[1]
SIZE = 50 * 2**20
WORDS = ("alpha", "beta", "gamma", "delta", "eps", "zeta", "eta", "theta", "iota", "kappa")


def _garbage(path, size=SIZE, header="", final_newline=False):
    """``size`` bytes of comma-separated words, written in chunks (fast)."""
    line = ",".join(WORDS[:6]) + "\n"
    block = (",".join(reversed(WORDS[:6])) + "\n" + line) * 4096
    with open(path, "w") as f:
        f.write(header)
        written = len(header)
        while written + len(block) <= size:
            f.write(block)
            written += len(block)
        f.write(block[:size - written - 1] + ("\n" if final_newline else "x"))
    return path


@pytest.fixture(scope="module")
def big(tmp_path_factory):
    return _garbage(tmp_path_factory.mktemp("garbage") / "big.txt")


@pytest.fixture
def records(monkeypatch):
    """Count the records the csv module gives the data reader."""
    count = {"n": 0}

    class Reader:
        def __init__(self, *args, **kwargs):
            self._reader = csv.reader(*args, **kwargs)

        def __iter__(self):
            return self

        def __next__(self):
            row = next(self._reader)
            count["n"] += 1
            return row

        @property
        def line_num(self):
            return self._reader.line_num
    monkeypatch.setattr(csv_table, "csv", types.SimpleNamespace(reader=Reader, Error=csv.Error))
    return count


def _link(big, tmp_path, name):
    os.symlink(big, tmp_path / name)
    return name


def test_a_50mb_csv_of_words_is_refused_at_its_header(big, tmp_path, records):
    """The issue's case: words, no final line break (> 200 s before). Its first row holds no
    column pkmcal reads: the reader stops after one more and names the column it misses."""
    proc = run("fk", "default", _link(big, tmp_path, "words.csv"), "-o", "p.csv", cwd=tmp_path)
    assert_input_error(proc, "words.csv", "missing column q1_<unit>")
    assert records["n"] <= 2
    assert not (tmp_path / "p.csv").exists()


@pytest.mark.parametrize("header", ["q1_mm,q2_mm,q3_mm,q4_mm,q5_mm,q6_mm\n",
                                    "a1,b1,c1,d1,e1,f1\n"])
def test_a_csv_of_words_is_refused_at_its_first_row(tmp_path, records, header):
    """Under a header of pkmcal's columns, at the first word where a number belongs; under a
    header of none, after the first row (the reader names the column it misses)."""
    _garbage(tmp_path / "g.csv", 5 * 2**20, header=header)
    proc = run("fk", "default", "g.csv", "-o", "p.csv", cwd=tmp_path)
    if header.startswith("q1"):
        assert_input_error(proc, "g.csv", "row 2, column q1_mm: not a number")
    else:
        assert_input_error(proc, "g.csv", "missing column q1_<unit>")
    assert records["n"] <= 3


def test_a_large_file_without_a_final_line_break_is_read_in_proportion(tmp_path, records):
    """Good rows with no final line break: each row was checked for an open quote by
    splitting the whole text again (quadratic); 200000 rows now read at once, and the last
    row's open quote is still refused."""
    rows = "\n".join(["0,0,410,0,0,0"] * 200000)
    (tmp_path / "p.csv").write_text("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n" + rows)
    header, table = csv_io.read_table(tmp_path / "p.csv")
    assert len(table) == 200000 and records["n"] <= 200001 + 4     # + the last row's quote check
    (tmp_path / "q.csv").write_text("x_mm,y_mm\n1,2\n3,\"4")
    with pytest.raises(csv_io.InputError, match="row 3, column y_mm: a quote"):
        csv_io.read_table(tmp_path / "q.csv")


@pytest.mark.parametrize("fmt", ["marlin", "reprapfirmware", "linuxcnc-genhexkins",
                                 "linuxcnc-lineardelta", "linuxcnc-rotarydelta"])
def test_a_50mb_controller_file_of_words_is_refused_after_a_bounded_scan(big, tmp_path, fmt):
    """G-code and HAL files: their readers passed over every line looking for their values
    (30 s for Marlin); now refused after FOREIGN_SCAN_LINES lines of something else."""
    proc = run("import", _link(big, tmp_path, "in.txt"), "--from", fmt, "-o", "m.yaml",
               cwd=tmp_path)
    assert_input_error(proc, "in.txt: line 1:",
                       f"neither are the {FOREIGN_SCAN_LINES - 1} line(s) after it")
    assert not (tmp_path / "m.yaml").exists()


@pytest.mark.parametrize("fmt", ["klipper", "klipper-rotary-delta"])
def test_a_50mb_klipper_config_of_words_is_refused_at_its_first_line(big, tmp_path, fmt):
    proc = run("import", _link(big, tmp_path, "printer.cfg"), "--from", fmt, "-o", "m.yaml",
               cwd=tmp_path)
    assert_input_error(proc, "printer.cfg: line 1:", "neither a [section] nor an option")


def test_a_50mb_machine_file_is_refused_by_its_size(big, tmp_path):
    """A machine file is at most MAX_MACHINE_FILE_BYTES: refused before it is read."""
    from pkmcal.limits import MAX_MACHINE_FILE_BYTES

    proc = run("fk", _link(big, tmp_path, "m.yaml"), "j.csv", "-o", "p.csv", cwd=tmp_path)
    assert_input_error(proc, "m.yaml", f"at most {MAX_MACHINE_FILE_BYTES} bytes")


def test_a_50mb_calibration_report_of_words_is_refused_at_its_first_character(big, tmp_path):
    """compensate --report: the nesting scan went over every character first (a Python loop
    over 50 MB); a text that opens no array or object goes to json, which stops at once."""
    (tmp_path / "t.csv").write_text("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n0,0,300,0,0,0\n")
    proc = run("compensate", "default", "t.csv", "--report", _link(big, tmp_path, "r.json"),
               "-o", "c.csv", cwd=tmp_path)
    assert_input_error(proc, "r.json", "not JSON (line 1, column 1)")


def test_a_50mb_probe_report_of_words_is_read_in_proportion(tmp_path, monkeypatch):
    """A pasted probe report (calibrate's data) whose one report line is followed by 50 MB of
    words: every line went through the report's patterns (15 s of CPU); now the reader leaves
    the text REPORT_GAP lines after the report's last line (counted: the lines it looks at)."""
    from pkmcal.export import firmware_reports, gcode_text

    seen = {"n": 0}
    host_line = gcode_text.host_line

    def counting(raw):
        seen["n"] += 1
        return host_line(raw)

    monkeypatch.setattr(gcode_text, "host_line", counting)
    report = _garbage(tmp_path / "report.txt", header="Bed X: 0.000 Y: 0.000 Z: 0.100\n")
    proc = run("calibrate", str(ROOT / "examples" / "linear_delta.yaml"), report.name,
               "-o", "x.yaml", cwd=tmp_path)
    assert_input_error(proc, "report.txt", "1 probe height(s)")
    # a few passes over the report block (its lines, its commands, the values in force)
    assert 0 < seen["n"] <= 4 * (firmware_reports.REPORT_GAP + 1)
    assert not (tmp_path / "x.yaml").exists()
