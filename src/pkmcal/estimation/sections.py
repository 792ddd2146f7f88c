"""Typed sections of a calibration result: what an instrument's fit adds to the generic result.

A :class:`~pkmcal.estimation.estimator.CalibrationResult` carries the fields every fit has
(the calibrated ``machine``, the ``problem``, ``unidentifiable``, ``noise``, ``outliers``,
``residual_test``, ...) as typed attributes, and what one instrument adds (a tracker's
registration and targets, a motion-capture system's frames, a ballbar's mountings, a probe's
bed, a constraint link's length) as a *section*: a small dataclass declared in the
instrument's own module, kept in ``result.sections`` under the instrument's registry name.

Every section follows one small protocol (:class:`ResultSection`), so the report, the
console summary and the HTML page render any instrument's section without knowing it:
``as_report(units)`` gives the section's JSON-ready keys (merged into the calibration report,
:func:`sections_report`) and ``summary_rows(units)`` its ``(label, text)`` rows.

There is no free-form dictionary: a value a fit needs to keep is a field of the result or of
its instrument's section.
"""

from __future__ import annotations

from typing import ClassVar, Protocol, runtime_checkable

__all__ = ["ResultSection", "Section", "DETAILS", "blank_details",
           "sections_report", "add_sections", "section_rows"]


@runtime_checkable
class ResultSection(Protocol):
    """What an instrument's section of a calibration result offers (a structural protocol).

    Attributes
    ----------
    instrument : str
        The instrument's registry name: the key of the section in ``result.sections``.
    title : str
        The section's heading in the report and the HTML page.
    """

    instrument: ClassVar[str]
    title: ClassVar[str]

    def as_report(self, units: dict | None = None) -> dict:
        """JSON-ready keys of the calibration report (lengths in ``units["length"]``)."""

    def summary_rows(self, units: dict | None = None) -> list[tuple[str, str]]:
        """``(label, text)`` rows for a person (console summary, HTML)."""


class Section:
    """A convenient base of a section dataclass: no report keys and no rows unless the
    subclass says. Subclasses set :attr:`instrument` and :attr:`title`."""

    instrument: ClassVar[str] = ""
    title: ClassVar[str] = ""

    def as_report(self, units: dict | None = None) -> dict:
        return {}

    def summary_rows(self, units: dict | None = None) -> list[tuple[str, str]]:
        return []


#: the generic part of a result (fields every fit may have), in the order of the dataclass;
#: :func:`blank_details` gives their empty values
DETAILS = ("machine", "problem", "method", "unidentifiable", "model", "start_model", "noise",
           "outliers", "weighted", "weighted_residuals", "used", "robust", "residual_test",
           "untested", "extensions", "poorly_determined", "rebuild_problem")


def blank_details() -> dict:
    """The generic fields and the sections empty (a fit's copy that is not yet a calibration:
    ``dataclasses.replace(result, **blank_details())``)."""
    return {**{name: None for name in DETAILS}, "unidentifiable": [], "sections": {}}


def sections_report(sections: dict, units: dict | None = None) -> dict:
    """The report keys of a result's sections, and their index ``sections``: per instrument
    its title, the report keys it wrote and its summary rows (how the console and the HTML page
    show any section).

    Parameters
    ----------
    sections : dict
        ``result.sections``: instrument name -> section.
    units : dict, optional
        The machine file's units (``length``, ``angle``).

    Returns
    -------
    dict
        The sections' keys, then ``"sections"``: ``{name: {"title", "keys", "summary"}}``
        (empty when there are no sections).
    """
    out: dict = {}
    index: dict = {}
    for name, section in sections.items():
        keys = dict(section.as_report(units))
        out.update(keys)
        index[str(name)] = {"title": str(section.title or name), "keys": list(keys),
                            "summary": [[str(label), str(text)]
                                        for label, text in section.summary_rows(units)]}
    if index:
        out["sections"] = index
    return out


def add_sections(report: dict, sections: dict, units: dict | None = None,
                 metadata: dict | None = None) -> dict:
    """Add a result's sections to its report: the keys a section gives that the instrument's
    flow has not written already (a flow may write a richer one, e.g. with the fit "before"
    beside it) and the index ``sections`` (:func:`sections_report`); with ``metadata`` (the
    calibrated machine file's ``calibration:`` mapping) the sections' summary rows there too,
    as ``sections: {name: ["label: text", ...]}``.

    Returns
    -------
    dict
        ``report``.
    """
    for key, value in sections_report(sections, units).items():
        if key == "sections":
            report[key] = value
        else:
            report.setdefault(key, value)
    if metadata is not None:
        rows = {name: [f"{label}: {text}" for label, text in entry["summary"]]
                for name, entry in report.get("sections", {}).items() if entry["summary"]}
        if rows:
            metadata["sections"] = rows
    return report


def section_rows(report: dict) -> list[tuple[str, str]]:
    """The summary rows of every section a report indexes (``report["sections"]``), in order."""
    return [(label, text) for entry in (report.get("sections") or {}).values()
            for label, text in entry.get("summary", [])]
