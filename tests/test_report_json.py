"""The calibration report's JSON text (report_json, json_safe): what json.loads gives back is
what was written, lists of numbers stay on one line, and nothing not finite gets through."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pkmcal.calibration.run import json_safe, report_json


def test_the_text_loads_back_to_the_value_with_number_lists_on_one_line():
    rng = np.random.default_rng(3)
    cov = rng.normal(size=(5, 5))
    value = json_safe({
        "a": 1, "b": [], "c": {}, "d": "text \"quoted\" \u00b5m", "e": None, "f": True,
        "covariance": {"parameters": ["x", "y"], "matrix": cov},
        "rows": [{"row": 1, "r": [0.5, np.nan, np.inf]}, {"row": 2, "r": []}],
        "ints": np.arange(4), "mixed": [1, [2, 3], {"k": (4.0, 5.0)}], 7: "a key"})
    text = report_json(value)
    assert json.loads(text) == json.loads(json.dumps(value))
    lines = text.splitlines()
    # the 5 x 5 matrix: one line per row, each with its 5 numbers at full precision
    rows = [line.strip().rstrip(",") for line in lines if line.strip().startswith("[")
            and line.strip().rstrip(",").count(",") == 4]
    assert len(rows) == 5
    for line, want in zip(rows, cov, strict=True):
        assert json.loads(line) == want.tolist()
    assert '"r": [0.5, null, null]' in text and '"ints": [0, 1, 2, 3]' in text
    # nested lines indented by two spaces a level
    assert '\n  "covariance": {\n    "parameters": ["x", "y"],' in text


def test_non_finite_numbers_are_refused_not_written():
    with pytest.raises(ValueError):
        report_json({"x": [1.0, float("nan")]})


def test_json_safe_gives_python_numbers_and_null_for_what_is_not_finite():
    out = json_safe({"f": np.array([1.5, np.inf]), "g": np.array([[1.0, 2.0]]),
                     "i": np.int64(3), "b": np.bool_(True), "n": np.float32(np.nan)})
    assert out == {"f": [1.5, None], "g": [[1.0, 2.0]], "i": 3, "b": True, "n": None}
    assert all(type(v) is float for v in out["g"][0])
