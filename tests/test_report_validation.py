"""A calibration report a user hands to `pkmcal report` or `compensate` is checked before use:
one line naming the file and the key, exit 2, nothing written (issue 11, item 3)."""

from __future__ import annotations

import copy
import json

import pytest

from clitools import assert_input_error, digest, run
from pkmcal.errors import InputError
from pkmcal.report.schema import MAX_DEPTH, load_report, validate_report


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A real calibration (default Hexa Slide, simulated constraint-link data)."""
    d = tmp_path_factory.mktemp("cal")
    assert run("simulate", "default", "--scenario", "constraint-link", "--poses", "60",
               "-o", "d.csv", cwd=d).returncode == 0
    proc = run("calibrate", "default", "d.csv", "-o", "cal.yaml", cwd=d)
    assert proc.returncode == 0, proc.stderr
    return d, json.loads((d / "cal.json").read_text())


def test_a_real_report_passes_unchanged(calibrated):
    _, doc = calibrated
    assert validate_report(copy.deepcopy(doc), "cal.json") == doc


def _set(path, value):
    def edit(doc):
        node = doc
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value
    return edit


def _drop(path):
    def edit(doc):
        node = doc
        for key in path[:-1]:
            node = node[key]
        del node[path[-1]]
    return edit


#: (edit, words the message must contain)
CASES = {
    "std as text": (_set(("parameters", 3, "std"), "abc"), "parameters[3].std"),
    "negative std": (_set(("parameters", 0, "std"), -1.0), "parameters[0].std"),
    "name not text": (_set(("parameters", 1, "name"), 7), "parameters[1].name"),
    "parameters not a list": (_set(("parameters",), {"a": 1}), "parameters"),
    "no success flag": (_drop(("convergence", "success")), "convergence.success"),
    "success as text": (_set(("convergence", "success"), "yes"), "convergence.success"),
    "rank above count": (_set(("identifiability", "identifiable"), 999), "identifiability"),
    "rank as float": (_set(("identifiability", "identifiable"), 48.5),
                      "identifiability.identifiable"),
    "singular value text": (_set(("identifiability", "singular_values", 2), "x"),
                            "identifiability.singular_values[2]"),
    "covariance not square": (lambda d: d["covariance"]["matrix"].pop(), "covariance"),
    "covariance row short": (lambda d: d["covariance"]["matrix"][5].pop(), "covariance"),
    "covariance entry text": (_set(("covariance", "matrix", 0, 0), "1"),
                              "covariance.matrix[0][0]"),
    "null space ragged": (lambda d: d["covariance"]["null_space"][0].append(0.0),
                          "covariance"),
    "normalised residual text": (_set(("normalised_residuals", 0), "0.1"),
                                 "normalised_residuals[0]"),
    "provenance nested": (_set(("provenance", "command"), {"a": [1]}), "provenance.command"),
    "noise level negative": (_set(("noise_model", "groups", 0, "sigma"), -1.0),
                             "noise_model.groups[0].sigma"),
    "noise level text": (_set(("noise_model", "groups", 0, "sigma"), "2"),
                         "noise_model.groups[0].sigma"),
    "noise status unknown": (_set(("noise_model", "groups", 0, "status"), "guessed"),
                             "noise_model.groups[0].status"),
    "outlier p above 1": (_set(("outliers", "threshold_p"), 2.0), "outliers.threshold_p"),
    "adequacy without verdict": (_drop(("model_adequacy", "verdict")),
                                 "model_adequacy.verdict"),
    "adequacy not an object": (_set(("model_adequacy",), [1, 2]), "model_adequacy"),
    "adequacy ratio negative": (_set(("model_adequacy", "noise_ratio"), -2.0),
                                "model_adequacy.noise_ratio"),
    "adequacy group count text": (_set(("model_adequacy", "groups", 0, "count"), "9"),
                                  "model_adequacy.groups[0].count"),
    "extension adopted untried": (_set(("model_extensions",), {
        "tried": ["a"], "adopted": ["b"], "folds": 5, "trials": []}), "model_extensions"),
    "extension loss text": (_set(("model_extensions",), {
        "tried": ["a"], "adopted": [], "folds": 5, "trials": [
            {"name": "a", "cv_loss": "1", "adopted": False, "why": "x"}]}),
        "model_extensions.trials[0].cv_loss"),
    "extension trials not a list": (_set(("model_extensions",), {
        "tried": [], "adopted": [], "trials": {"a": 1}}), "model_extensions.trials"),
    "another command": (_set(("command",), "simulate"), "not a calibration report"),
    "no command": (_drop(("command",)), "not a calibration report"),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_a_wrong_section_names_its_key(calibrated, name):
    _, doc = calibrated
    edit, words = CASES[name]
    bad = copy.deepcopy(doc)
    edit(bad)
    with pytest.raises(InputError) as err:
        validate_report(bad, "cal.json")
    msg = str(err.value)
    assert msg.startswith("cal.json: ") and words in msg, msg
    assert "\n" not in msg


@pytest.mark.parametrize("text,words", [
    ("not json at all", "not JSON (line 1"),
    ("", "not JSON"),
    ("[1, 2]", "a JSON object was expected"),
    ('{"command": "calibrate", "parameters": [{"name": "a", "std": NaN}]}',
     "NaN is not a number"),
    ('{"command": "calibrate", "x": Infinity}', "Infinity is not a number"),
    ("[" * 200_000 + "]" * 200_000, f"nested more than {MAX_DEPTH} deep"),
])
def test_unreadable_reports_are_refused(tmp_path, text, words):
    path = tmp_path / "r.json"
    path.write_text(text)
    with pytest.raises(InputError) as err:
        load_report(path)
    assert words in str(err.value) and str(err.value).startswith(str(path))


def _depth_by_characters(text: str) -> int:
    """The depth scan the report reader used before its regular expressions: a state machine
    over every character (the reference)."""
    depth = deepest = 0
    in_string = escaped = False
    for ch in text:
        if in_string:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
        elif ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
            if deepest > MAX_DEPTH:
                return deepest
        elif ch in "]}":
            depth -= 1
    return deepest


def test_the_depth_scan_agrees_with_a_scan_of_every_character(calibrated):
    """The depth of nesting outside strings (escaped quotes, unterminated strings, a lone
    backslash at the end, brackets closed before opened, deeper than MAX_DEPTH) is the one a
    scan of each character finds, on random texts and on a real report."""
    import numpy as np

    from pkmcal.report.schema import _depth

    _, doc = calibrated
    texts = [json.dumps(doc), json.dumps(doc, indent=1), "", '"', '"\\', '"[', '["]"[',
             "]]][[", "[" * (MAX_DEPTH + 5), '"' + "[" * 40]
    rng = np.random.default_rng(38)
    alphabet = list('[]{}"\\ a,')
    for n in rng.integers(0, 400, 3000):
        # nesting-heavy: brackets 5 times as likely as the rest
        p = np.array([5, 5, 5, 5, 2, 2, 1, 1, 1], float)
        texts.append("".join(rng.choice(alphabet, size=n, p=p / p.sum())))
    for text in texts:
        assert _depth(text) == _depth_by_characters(text), text


@pytest.mark.parametrize("command", ["report", "compensate"])
def test_the_commands_refuse_a_bad_report_naming_the_key(calibrated, tmp_path, command):
    d, doc = calibrated
    bad = copy.deepcopy(doc)
    bad["covariance"]["matrix"][3][4] = "oops"
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    (tmp_path / "cal.yaml").write_text((d / "cal.yaml").read_text())
    (tmp_path / "t.csv").write_text("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n"
                                    "0,0,300,0,0,0\n10,0,300,0,0,0\n")
    before = digest(tmp_path / "bad.json")
    if command == "report":
        proc = run("report", "bad.json", "-o", "out.html", cwd=tmp_path)
    else:
        # the nominal machine: a calibrated file would refuse a report it does not pin
        proc = run("compensate", "default", "t.csv", "--report", "bad.json", "-o", "c.csv",
                   cwd=tmp_path)
    assert_input_error(proc, "bad.json", "covariance.matrix[3][4]")
    assert digest(tmp_path / "bad.json") == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.json", "cal.yaml", "t.csv"]


def test_a_report_given_with_report_must_be_the_one_the_file_pins(calibrated, tmp_path):
    d, doc = calibrated
    (tmp_path / "cal.yaml").write_text((d / "cal.yaml").read_text())
    other = copy.deepcopy(doc)
    other["residuals"]["rms_um"] = 1.0            # a valid report, of another run
    (tmp_path / "other.json").write_text(json.dumps(other))
    (tmp_path / "t.csv").write_text("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n0,0,300,0,0,0\n")
    proc = run("compensate", "cal.yaml", "t.csv", "--report", "other.json", "-o", "c.csv",
               cwd=tmp_path)
    assert_input_error(proc, "other.json", "another run")
    assert not (tmp_path / "c.csv").exists()


REQUIRED_CASES = {
    "unknown version": (_set(("pkmcal_report",), 99), "pkmcal_report"),
    "unknown measurement": (_set(("measurement",), "telepathy"), "measurement"),
    "unknown length unit": (_set(("units", "length"), "furlong"), "units.length"),
    "negative noise": (_set(("noise_sigma_um",), -1), "noise_sigma_um"),
    "rms as text": (_set(("residuals", "rms_um"), "0.5"), "residuals.rms_um"),
    "no parameters": (_set(("parameters",), []), "parameters"),
    "covariance null": (_set(("covariance",), "none"), "covariance"),
    **{f"no {key}": (_drop((key,)), key) for key in (
        "parameters", "residuals", "identifiability", "measurement", "units", "convergence",
        "method", "measurements", "covariance", "link_length")},
}


@pytest.mark.parametrize("name", sorted(REQUIRED_CASES))
def test_the_sections_every_report_has_are_required(calibrated, name):
    _, doc = calibrated
    edit, words = REQUIRED_CASES[name]
    bad = copy.deepcopy(doc)
    edit(bad)
    with pytest.raises(InputError, match=r"^cal\.json: " + words.replace(".", r"\.")):
        validate_report(bad, "cal.json")


@pytest.mark.parametrize("layout,words", [
    ("report is a directory", ["cal.json", "not a file"]),
    ("report key a number", ["cal.yaml", "calibration.report"]),
])
def test_a_calibrated_files_report_that_cannot_be_used_is_refused(calibrated, tmp_path, layout,
                                                                  words):
    d, _ = calibrated
    text = (d / "cal.yaml").read_text()
    if layout == "report is a directory":
        (tmp_path / "cal.json").mkdir()
    else:
        text = text.replace("report: cal.json", "report: 5")
    (tmp_path / "cal.yaml").write_text(text)
    (tmp_path / "t.csv").write_text("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n0,0,300,0,0,0\n")
    for command in (["compensate", "cal.yaml", "t.csv", "-o", "c.csv"],
                    ["report", "cal.yaml", "-o", "r.html"]):
        proc = run(*command, cwd=tmp_path)
        assert_input_error(proc, *words)
    assert not (tmp_path / "c.csv").exists() and not (tmp_path / "r.html").exists()


def test_a_calibrated_file_without_its_report_warns_naming_it(calibrated, tmp_path):
    d, _ = calibrated
    (tmp_path / "cal.yaml").write_text((d / "cal.yaml").read_text())
    (tmp_path / "t.csv").write_text("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n0,0,300,0,0,0\n")
    proc = run("compensate", "cal.yaml", "t.csv", "-o", "c.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "cal.json (named by cal.yaml) is missing" in proc.stderr


def test_every_calibration_kind_is_a_known_measurement():
    """The report schema knows every kind calibrate writes (the registry) and joint fits."""
    from pkmcal.calibration.run import KINDS
    from pkmcal.report.schema import measurements

    assert set(measurements()) == set(KINDS) | {"joint"}
