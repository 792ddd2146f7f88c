"""Numbers for people (issue 26: "3.59e+03 um should read mm"): tables and lines of the
command line and the reports print lengths and angles in the unit they read naturally in
(pkmcal.units.format_quantity: um below 1 mm, then mm; urad, mrad, deg), never in exponent
notation for ordinary magnitudes. JSON keeps its numbers (in um / urad)."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest

from pkmcal.units import (
    format_number,
    format_quantity,
    format_um,
    format_urad,
    readable_unit,
)

#: exponent notation, as format(x, 'g') writes it
EXPONENT = re.compile(r"\d[eE][-+]\d")


@pytest.mark.parametrize(("value", "digits", "sign", "text"), [
    (20184.0, 4, False, "20180"),             # '.4g' gives 2.018e+04
    (3590.0, 3, False, "3590"),               # '.3g' gives 3.59e+03
    (-37720.4, 4, True, "-37720"),
    (99999.7, 4, False, "100000"),            # rounding carries into a new digit
    (9.99996, 4, False, "10"),
    (12.345678, 4, False, "12.35"),
    (0.5, 4, True, "+0.5"),
    (0.0001234567, 4, False, "0.0001235"),
    (0.0, 4, True, "+0"),
    (1e-9, 4, False, "1e-09"),                # far below anything shown: g's exponent stays
])
def test_format_number(value, digits, sign, text):
    assert format_number(value, digits, sign) == text


def test_format_number_agrees_with_g_without_its_exponent():
    """Within g's positional range the text is g's; beyond it the same digits, positional."""
    for value in (1.0, 0.000123, 1.5, 123.456, 1234.5, 7.25e-3, -42.0):
        assert format_number(value) == format(value, ".4g")
    for value in (1.234e4, 5.5e5, -7.77e7):
        assert float(format_number(value)) == float(format(value, ".4g"))
        assert not EXPONENT.search(format_number(value))
    for value in (math.nan, math.inf, -math.inf):
        assert format_number(value) == format(value, ".4g")


@pytest.mark.parametrize(("value", "quantity", "text"), [
    (3.59e-3, "length", "3.59 mm"),
    (999e-6, "length", "999 um"),
    (1e-3, "length", "1 mm"),
    (1.5, "length", "1500 mm"),
    (2e-6, "length", "2 um"),
    (50e-6, "angle", "50 urad"),
    (-0.01594, "angle", "-15.94 mrad"),
    (0.2, "angle", "11.46 deg"),
])
def test_format_quantity(value, quantity, text):
    assert format_quantity(value, quantity) == text


def test_units_given_and_report_numbers():
    assert format_quantity(2.5e-3, "length", unit="um") == "2500 um"
    assert format_quantity(0.001, "angle", 3, sign=True, unit="urad") == "+1000 urad"
    assert format_um(3590.0, 3) == "3.59 mm" and format_um(12.34) == "12.34 um"
    assert format_urad(1234.0) == "1.234 mrad" and format_urad(None) == "n/a"
    assert readable_unit(math.nan, "length") == "um"


def test_calibrate_prints_changes_in_the_values_unit(cli, tmp_path):
    """A Delta built 1 mm / 0.5 deg off, its tracker pose unknown: the changes reach 20 mm
    and 15 mrad; the table printed -2.018e+04 um and +1.496e+04 urad. Then mm and mrad; now
    (issue 36: an uncertainty of 0.5 deg was printed as "8810 urad" beside values in degrees)
    the change and its std in the unit of the nominal and identified values, the file's, to
    three significant digits without an exponent; calibrate's JSON report keeps its numbers
    in the file's units."""
    delta = Path(__file__).resolve().parents[1] / "examples" / "delta_default.yaml"
    proc = cli("simulate", delta, "-o", "d.csv", "--deviations", "random")
    assert proc.returncode == 0, proc.stderr
    proc = cli("calibrate", delta, "d.csv", "-o", "c.yaml")
    assert proc.returncode == 0, proc.stderr
    table = proc.stdout.split("largest parameter changes", 1)[1].split("note:", 1)[0]
    assert not EXPONENT.search(table), table
    rows = [[c.strip() for c in line.split("\u2502")] for line in table.splitlines()
            if line.count("\u2502") == 5]
    params = {p["name"]: p for p in json.loads(
        (tmp_path / "c.json").read_text(encoding="utf-8"))["parameters"]}
    assert len(rows) == 10, table
    for name, nominal, _, change, std, unit in rows:
        p = params[name]
        assert unit == p["unit"] and nominal.endswith(f" {unit}"), (name, change, unit)
        assert float(change) == pytest.approx(p["change"], rel=5e-3)
        assert len(change.lstrip("+-0.").replace(".", "")) <= 3, change
        assert float(std) == pytest.approx(p["std"], rel=5e-3)
    assert {"mm", "deg"} <= {row[-1] for row in rows}, table
