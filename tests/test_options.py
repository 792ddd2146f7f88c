"""Options out of range are refused up front (issue 11, item 3): exit 2, one line naming the
option, no traceback, no output; usage errors are one line too."""

from __future__ import annotations

import pytest

from clitools import assert_input_error, run

#: (arguments, the option the message must name)
BAD_OPTIONS = [
    (["simulate", "default", "--seed", "-1", "-o", "x.csv"], "--seed"),
    (["simulate", "default", "--poses", "0", "-o", "x.csv"], "--poses"),
    (["simulate", "default", "--poses", "100000000000000000000", "-o", "x.csv"], "--poses"),
    (["simulate", "default", "--outliers", "-3", "-o", "x.csv"], "--outliers"),
    (["identifiability", "default", "--seed", "-5"], "--seed"),
    (["identifiability", "default", "--poses", "99999999999"], "--poses"),
    (["select-poses", "default", "-n", "60", "--seed", "-1", "-o", "x.csv"], "--seed"),
    (["select-poses", "default", "-n", "0", "-o", "x.csv"], "-n"),
    (["select-poses", "default", "-n", "60", "--candidates", "1000000000", "-o", "x.csv"],
     "--candidates"),
    (["select-poses", "default", "-n", "60", "--random-sets", "-1", "-o", "x.csv"],
     "--random-sets"),
    (["montecarlo", "default", "--vary", "noise=1um", "--seed", "-1", "-o", "mc"], "--seed"),
    (["montecarlo", "default", "--vary", "noise=1um", "--runs", "0", "-o", "mc"], "--runs"),
    (["montecarlo", "default", "--vary", "poses=1e400", "-o", "mc"], "--vary poses"),
    (["montecarlo", "default", "--vary", "poses=100000000", "-o", "mc"], "--vary poses"),
    (["errors", "cubic", "--samples", "0", "-o", "x.csv"], "--samples"),
    (["errors", "cubic", "--samples", "1000000000000", "-o", "x.csv"], "--samples"),
    (["calibrate", "default", "data.csv", "-o", "x.yaml", "--seed", "-2", "--holdout", "0.2"],
     "--seed"),
    (["calibrate", "default", "data.csv", "-o", "x.yaml", "--holdout", "0.95"], "--holdout"),
    (["calibrate", "default", "data.csv", "-o", "x.yaml", "--holdout", "59"], "--holdout"),
    (["calibrate", "default", "data.csv", "-o", "x.yaml", "--holdout", "60"], "--holdout"),
    (["calibrate", "default", "data.csv", "-o", "x.yaml", "--bogus"], "--bogus"),
    (["calibrate", "default", "data.csv"], "--output"),
]


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("options")
    proc = run("simulate", "default", "--poses", "60", "-o", "data.csv", cwd=d)
    assert proc.returncode == 0, proc.stderr
    return d


@pytest.mark.parametrize("args,option", BAD_OPTIONS, ids=[" ".join(a[:1] + [o])
                                                          for a, o in BAD_OPTIONS])
def test_bad_option_is_one_line_naming_it(data_dir, args, option):
    before = sorted(p.name for p in data_dir.iterdir())
    proc = run(*args, cwd=data_dir)
    assert_input_error(proc, option)
    assert sorted(p.name for p in data_dir.iterdir()) == before    # nothing written


def test_help_and_version_still_exit_0(tmp_path):
    for args in (["--help"], ["calibrate", "--help"], ["--version"]):
        proc = run(*args, cwd=tmp_path)
        assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
