"""Finite but absurd numbers on the command line are refused naming the option, before they
overflow a computation; no numpy warning reaches the user (issue 11, item 3)."""

from __future__ import annotations

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
