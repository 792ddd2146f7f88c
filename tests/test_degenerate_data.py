"""Duplicate-row or otherwise degenerate constraint-link data are refused like collinear
tracker points: exit 2, one line naming the repeated rows, nothing written (issue 11, item 3)."""

from __future__ import annotations

import types

import numpy as np
import pytest

from clitools import assert_input_error, digest, run
from pkmcal.errors import InputError
from pkmcal.instruments.constraint_link import ConstraintLinkData
from pkmcal.instruments.constraint_link import methods as cl


@pytest.fixture(scope="module")
def data_csv(tmp_path_factory):
    d = tmp_path_factory.mktemp("link")
    proc = run("simulate", "default", "--scenario", "constraint-link", "--poses", "60",
               "--seed", "3", "-o", "d.csv", cwd=d)
    assert proc.returncode == 0, proc.stderr
    return (d / "d.csv").read_text().splitlines()


def test_distinct_counts_rows_and_names_the_copies():
    q = np.arange(12.0).reshape(4, 3)
    data = ConstraintLinkData(q[[0, 1, 0, 2, 1]], 0.3, passive=np.array([0, 1, 0, 2, 1]))
    count, repeats = data.distinct()
    assert count == 3
    assert repeats == "rows 3, 5 repeat rows 1, 2"
    # the same readings with another passive joint are another measurement
    other = ConstraintLinkData(q[[0, 0]], 0.3, passive=np.array([0, 1]))
    assert other.distinct() == (2, "")


@pytest.mark.parametrize("layout,words", [
    ("one row 60 times", ("60 rows, 1 distinct", "rows 3, 4, 5", "repeat row 2")),
    ("30 rows twice", ("60 rows, 30 distinct", "rows 32, 33, 34", "repeat rows 2, 3")),
])
def test_duplicated_rows_are_refused_naming_them(tmp_path, data_csv, layout, words):
    head, rows = data_csv[0], data_csv[1:]
    body = [rows[0]] * 60 if layout == "one row 60 times" else rows[:30] * 2
    path = tmp_path / "dup.csv"
    path.write_text("\n".join([head, *body]) + "\n")
    before = digest(path)
    for method in ("ml", "ik"):
        proc = run("calibrate", "default", "dup.csv", "--method", method, "-o", "cal.yaml",
                   cwd=tmp_path)
        assert_input_error(proc, "dup.csv", *words)
    assert digest(path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dup.csv"]


def test_distinct_rows_still_calibrate(tmp_path, data_csv):
    (tmp_path / "d.csv").write_text("\n".join(data_csv) + "\n")
    proc = run("calibrate", "default", "d.csv", "-o", "cal.yaml", "-q", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr


def test_a_null_space_beyond_the_frames_is_refused():
    data = ConstraintLinkData(np.zeros((50, 6)), 0.3, source="d.csv")
    free = np.ones(54, bool)
    result = types.SimpleNamespace(null_space=np.zeros((54, 9)),
                                   parameters=types.SimpleNamespace(free=free))
    with pytest.raises(InputError, match=r"d.csv: the 50 poses are degenerate: 3 direction"):
        cl._refuse_degenerate(data, result, 48, "")
    result.null_space = np.zeros((54, 6))          # the frames only: accepted
    cl._refuse_degenerate(data, result, 48, "")


@pytest.mark.parametrize("rows,words", [
    (47, ("47 measurements give 47 independent equation(s), fewer than the 48",)),
    (48, ("48 measurements give 48 independent equation(s), as many as the 48",
          "nothing left to check the fit")),
])
def test_data_that_leave_nothing_to_check_the_fit_are_refused(tmp_path, data_csv, rows, words):
    """One equation per constraint-link row (six readings, five pose unknowns): 48 rows for
    the default Hexa Slide's 48 identifiable parameters would fit exactly whatever the noise,
    as 37 probe heights for 37 directions do (refused alike); 49 calibrate."""
    head, body = data_csv[0], data_csv[1:]
    (tmp_path / "few.csv").write_text("\n".join([head, *body[:rows]]) + "\n")
    proc = run("calibrate", "default", "few.csv", "-o", "cal.yaml", cwd=tmp_path)
    assert_input_error(proc, "few.csv", *words)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["few.csv"]
    (tmp_path / "enough.csv").write_text("\n".join([head, *body[:49]]) + "\n")
    proc = run("calibrate", "default", "enough.csv", "-o", "cal.yaml", "-q", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
