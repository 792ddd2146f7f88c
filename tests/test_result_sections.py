"""Typed sections of a calibration result (issue 38): an instrument's section, declared in its
own module, reaches the report (JSON), the console summary and the HTML page through the
generic renderers, which name no instrument."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from pkmcal.estimation.estimator import CalibrationResult
from pkmcal.estimation.sections import (
    DETAILS,
    ResultSection,
    Section,
    add_sections,
    blank_details,
    section_rows,
)
from pkmcal.instruments.base import Instrument
from pkmcal.report.calibration_summary import calibrate_summary
from pkmcal.report.html import build_html


@dataclasses.dataclass
class ToySection(Section):
    """A section of an instrument no renderer knows."""

    instrument: ClassVar[str] = "toy"
    title: ClassVar[str] = "toy gauge"

    offset_m: float
    reads: list

    def as_report(self, units=None) -> dict:
        unit = (units or {}).get("length", "mm")
        f = {"mm": 1e3, "m": 1.0}[unit]
        return {"toy_gauge": {"offset": self.offset_m * f, "unit": unit,
                              "reads": len(self.reads)},
                "toy_rows": [{"row": i + 1, "value": v * f} for i, v in enumerate(self.reads)]}

    def summary_rows(self, units=None) -> list:
        rep = self.as_report(units)["toy_gauge"]
        return [("toy offset", f"{rep['offset']:.4g} {rep['unit']} over {rep['reads']} reads")]


class Toy(Instrument):
    """A fake instrument: only its name; its summary is the base class's."""

    name = "toy"


def _report() -> dict:
    """A minimal calibration report of the toy instrument (what the shared rows read)."""
    return {
        "measurement": "toy", "method": "joint", "measurements": 3,
        "units": {"length": "mm", "angle": "deg"},
        "identifiability": {"identifiable": 2, "free_parameters": 2, "unidentifiable": [],
                            "weakly_identifiable": []},
        "convergence": {"success": True, "message": "converged", "iterations": 4},
        "residuals": {},
    }


def _params() -> list:
    return [{"name": "a.x", "kind": "length", "unit": "mm", "nominal": 1.0, "identified": 1.5,
             "change": 0.5, "std": 0.01, "fixed": False, "scaled_change": 0.5}]


def test_toy_section_is_a_result_section():
    section = ToySection(2e-3, [1e-3, 2e-3])
    assert isinstance(section, ResultSection)


def test_toy_section_in_report_console_and_html(monkeypatch):
    """A section type the renderers have never seen shows in the report's keys and index, in
    the console summary (the shared "sections" row) and on the HTML page."""
    from pkmcal.instruments import registry

    monkeypatch.setitem(registry.INSTRUMENTS, "toy", Toy())
    result_sections = {"toy": ToySection(2e-3, [1e-3, 2e-3, 4e-3])}
    report = add_sections(_report(), result_sections, {"length": "mm"})
    # JSON: the section's keys (file units) and its index, and they survive a JSON round trip
    report = json.loads(json.dumps(report))
    assert report["toy_gauge"] == {"offset": pytest.approx(2.0), "unit": "mm", "reads": 3}
    assert [r["value"] for r in report["toy_rows"]] == pytest.approx([1.0, 2.0, 4.0])
    assert report["sections"]["toy"] == {
        "title": "toy gauge", "keys": ["toy_gauge", "toy_rows"],
        "summary": [["toy offset", "2 mm over 3 reads"]]}
    assert section_rows(report) == [("toy offset", "2 mm over 3 reads")]
    # console: the instrument's rows (base class) include its section's rows
    summary = calibrate_summary(report, _params(), "toy", "m.yaml", "toy.csv",
                                Path("out.json"))
    text = summary.text()
    assert "toy offset\t2 mm over 3 reads" in text
    assert "largest parameter changes" in text and "residual test\t" in text
    # HTML: the section's title, its rows and a table of each of its keys
    page = build_html(report)
    assert "<h2>toy gauge</h2>" in page
    assert "toy offset" in page and "2 mm over 3 reads" in page
    assert "<h3>toy gauge</h3>" in page and "<h3>toy rows</h3>" in page
    assert page.count("<tr><td>") >= 3          # one row per toy read


def test_toy_section_in_the_calibrated_files_metadata():
    """The calibrated machine file's ``calibration:`` mapping (YAML) carries every section's
    summary rows, whatever the instrument; sections without rows add nothing."""
    metadata = {"method": "toy"}
    add_sections(_report(), {"toy": ToySection(2e-3, [1e-3])}, {"length": "mm"}, metadata)
    assert metadata["sections"] == {"toy": ["toy offset: 2 mm over 1 reads"]}
    quiet = {"method": "toy"}
    add_sections(_report(), {"toy": Section()}, {"length": "mm"}, quiet)
    assert "sections" not in quiet


def test_flow_keys_are_kept():
    """A key an instrument's flow wrote already (a richer one) is not replaced by the section's;
    the index still names it."""
    report = add_sections({**_report(), "toy_gauge": {"offset": 9.0, "before": 1.0}},
                          {"toy": ToySection(2e-3, [])}, {"length": "mm"})
    assert report["toy_gauge"] == {"offset": 9.0, "before": 1.0}
    assert report["sections"]["toy"]["keys"] == ["toy_gauge", "toy_rows"]


def _result() -> CalibrationResult:
    n = 2
    return CalibrationResult(
        x=np.zeros(n), parameters=None, cost=0.0, residuals=np.zeros((1, 1)), success=True,
        status=1, message="", nit=0, nfev=0, rank=n, singular_values=np.ones(n),
        null_space=np.zeros((n, 0)), scales=np.ones(n), weak_space=np.zeros((n, 0)),
        weak_std=np.zeros(0), covariance=np.zeros((n, n)), std=np.zeros(n),
        residual_variance=1.0, dof=1)


def test_typed_fields_and_no_free_form_dictionary():
    """The generic part is typed and a section's fields are its own: the former free-form
    ``extras`` dictionary is gone."""
    result = _result()
    assert result.machine is None and result.unidentifiable == [] and result.sections == {}
    result.machine = "calibrated"
    result.add_section(ToySection(1e-3, [1.0]))
    assert result.machine == "calibrated" and result.noise is None
    assert result.section(ToySection).offset_m == 1e-3        # a section's field
    assert not hasattr(result, "extras")                      # not free-form any more
    assert result.section(ToySection).reads == [1.0]
    blank = dataclasses.replace(result, **blank_details())
    assert blank.sections == {} and all(getattr(blank, k) in (None, []) for k in DETAILS)
    assert result.sections                                   # the original keeps its own


def test_real_calibration_indexes_its_section():
    """A ballbar calibration's report indexes the ballbar's section: its set-ups as keys and the
    console rows ("setup N") from the section."""
    from pkmcal.calibration import calibrate
    from pkmcal.instruments.distance import DistanceSection
    from pkmcal.instruments.registry import INSTRUMENTS
    from pkmcal.machines import default_hexaslide

    machine = default_hexaslide()
    inst = INSTRUMENTS["distance"]
    true = machine.with_parameters(machine.u + np.random.default_rng(1).normal(
        0.0, 2e-5, machine.u.size))
    data, _, _ = inst.simulate(machine, true, 150, None, np.random.default_rng(2),
                               {"scenario": "distance"})
    calibration = calibrate(machine, data)
    section = calibration.result.section(DistanceSection)
    assert section is not None
    entry = calibration.report["sections"]["distance"]
    assert entry["keys"] == ["setups"]
    assert len(entry["summary"]) == len(section.setups) == len(calibration.report["setups"])
    assert [label for label, _ in entry["summary"]] == [
        f"setup {g + 1}" for g in range(len(section.setups))]
