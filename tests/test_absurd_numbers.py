"""Finite but absurd numbers on the command line are refused naming the option, before they
overflow a computation; no numpy warning reaches the user (issue 11, item 3)."""

from __future__ import annotations

from pathlib import Path

import pytest

from clitools import assert_input_error, run
from pkmcal.errors import InputError
from pkmcal.units import MAX_MAGNITUDE, parse_quantity


@pytest.mark.parametrize("quantity", sorted(MAX_MAGNITUDE))
def test_every_quantity_has_a_limit_and_keeps_ordinary_values(quantity):
    limit = MAX_MAGNITUDE[quantity]
    assert parse_quantity(repr(limit / 2), quantity) == limit / 2
    for text in (repr(limit * 1.01), "1e308", "-1e308", "1e400"):
        with pytest.raises(InputError, match=r"^--opt: .* is out of range"):
            parse_quantity(text, quantity, "--opt")


def test_the_limit_applies_after_the_unit():
    assert parse_quantity("999999m", "length") == 999999.0
    with pytest.raises(InputError, match="out of range"):
        parse_quantity("1e10mm", "length", "--radius")
    assert parse_quantity("1e9um", "length") == pytest.approx(1e3, rel=1e-15)


#: (arguments, the option the message must name)
ABSURD = [
    (["simulate", "default", "--scenario", "constraint-link", "--noise", "1e308", "-o",
      "x.csv"], "--noise"),
    (["simulate", "default", "--scenario", "constraint-link", "--lc-error", "-1e300", "-o",
      "x.csv"], "--lc-error"),
    (["identifiability", "default", "--noise", "1e308"], "--noise"),
    (["select-poses", "default", "-n", "60", "--noise", "1e308um", "-o", "x.csv"], "--noise"),
    (["montecarlo", "default", "--vary", "noise=1e308", "--runs", "2", "-o", "mc"],
     "--vary noise"),
    (["errors", "cubic", "--radius", "1e308", "-o", "x.csv"], "--radius"),
    (["errors", "cubic", "--clearance", "1e308", "-o", "x.csv"], "--clearance"),
    (["errors", "cubic", "--mass", "1e308", "-o", "x.csv"], "--mass"),
    (["errors", "cubic", "--omega", "1e308", "-o", "x.csv"], "--omega"),
    (["errors", "cubic", "--cutting-force", "0,0,-1e308", "-o", "x.csv"], "--cutting-force"),
]


@pytest.mark.parametrize("args,option", ABSURD, ids=[" ".join(a[:1] + a[-4:-2])
                                                     for a, _ in ABSURD])
def test_absurd_options_are_refused_naming_them(tmp_path, args, option):
    proc = run(*args, cwd=tmp_path)
    assert_input_error(proc, option, "out of range")
    assert "Warning" not in proc.stderr
    assert list(tmp_path.iterdir()) == []


#: finite numbers within the absolute limits but absurd for the machine (a bare number is SI)
ABSURD_FOR_THE_MACHINE = [
    (["simulate", "default", "--scenario", "constraint-link", "--noise", "1e3", "-o", "x.csv"],
     "--noise"),
    (["simulate", "default", "--scenario", "constraint-link", "--lc-error", "0.2", "-o",
      "x.csv"], "--lc-error"),
    (["calibrate", "default", "data.csv", "--noise", "10mm", "-o", "x.yaml"], "--noise"),
    (["identifiability", "default", "--noise", "1"], "--noise"),
    (["montecarlo", "default", "--vary", "noise=1,2", "--runs", "2", "-o", "mc"],
     "--vary noise"),
    (["montecarlo", "default", "--vary", "tolerance=1", "--runs", "2", "-o", "mc"],
     "--vary tolerance"),
    (["errors", "cubic", "--radius", "100", "-o", "x.csv"], "--radius"),
    (["errors", "cubic", "--clearance", "1", "-o", "x.csv"], "--clearance"),
    (["errors", "cubic", "--screw-error", "0.5", "-o", "x.csv"], "--screw-error"),
    (["simulate", "delta", "--scenario", "tracker", "--noise", "1", "-o", "x.csv"], "--noise"),
    (["simulate", "cubic", "--scenario", "pose", "--pose-noise", "20um,1", "-o", "x.csv"],
     "--pose-noise (orientation)"),
    (["simulate", "cubic", "--scenario", "pose", "--pose-noise", "0.5,1urad", "-o", "x.csv"],
     "--pose-noise (position)"),
]


@pytest.fixture(scope="module")
def link_data(tmp_path_factory):
    d = tmp_path_factory.mktemp("data")
    assert run("simulate", "default", "--scenario", "constraint-link", "--poses", "60", "-o",
               "data.csv", cwd=d).returncode == 0
    return (d / "data.csv").read_text()


@pytest.mark.parametrize("args,option", ABSURD_FOR_THE_MACHINE,
                         ids=[" ".join(a[:1] + a[-4:-2]) for a, _ in ABSURD_FOR_THE_MACHINE])
def test_numbers_absurd_for_the_machine_are_refused(tmp_path, link_data, args, option):
    examples = Path(__file__).resolve().parents[1] / "examples"
    files = {"delta": examples / "delta_default.yaml", "cubic": examples / "cubic_6upu.yaml"}
    args = [str(files.get(a, a)) if i == 1 else a for i, a in enumerate(args)]
    if "data.csv" in args:
        (tmp_path / "data.csv").write_text(link_data)
    before = sorted(p.name for p in tmp_path.iterdir())
    proc = run(*args, cwd=tmp_path)
    assert_input_error(proc, option, "plausible")
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_ordinary_values_for_the_machine_pass(tmp_path):
    proc = run("simulate", "default", "--scenario", "constraint-link", "--poses", "60",
               "--noise", "1mm", "--lc-error", "20mm", "-o", "x.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
