"""What a constraint-link calibration adds to its result (:class:`ConstraintLinkSection`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from ...estimation.sections import Section
from .start import StartReport


@dataclass
class ConstraintLinkSection(Section):
    """What a constraint-link calibration adds to its result
    (``result.sections["constraint_link"]``): the link length, where the method started, the
    rows left out and the start strategy's report.

    Attributes
    ----------
    link_length, assumed : float or None
        The link length identified (or held) and the machine file's, m.
    estimated : bool
        Whether the link length was estimated.
    std : float or None
        Its standard deviation, m (estimated only).
    dropped_rows : ndarray of int
        File rows left out (no pose for the start geometry; ``'ml'``: no pose found that
        explains them with the calibrated geometry).
    start : StartReport or None
        ``'ml'``: what the start strategy did.
    warnings : list of str or None
        ``'ml'``: sentences for the user (rows left out or retried, and why).
    start_from : str or None
        The paper's methods: where they started (:data:`PAPER_METHOD_START`).
    sweeps : int or None
        ``per_chain``: the sweeps made.
    """

    instrument: ClassVar[str] = "constraint_link"
    title: ClassVar[str] = "link length"

    link_length: float | None = None
    assumed: float | None = None
    estimated: bool = False
    std: float | None = None
    dropped_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    start: StartReport | None = None
    warnings: list | None = None
    start_from: str | None = None
    sweeps: int | None = None

    @classmethod
    def of(cls, result) -> ConstraintLinkSection:
        """The result's section (attached, empty, when it has none yet)."""
        section = result.section(cls)
        if section is None:
            section = cls()
            result.add_section(section)
        return section

    def as_report(self, units=None) -> dict:
        from ...units import LENGTH

        if self.link_length is None:
            return {}
        unit = (units or {}).get("length", "mm")
        fl = LENGTH[unit]
        return {"link_length": {
            "value": self.link_length / fl, "assumed": self.assumed / fl, "unit": unit,
            "estimated": bool(self.estimated),
            "std": self.std / fl if self.estimated and self.std is not None else None}}

    def summary_rows(self, units=None) -> list:
        lc = self.as_report(units).get("link_length")
        if lc is None:
            return []
        if lc["estimated"]:
            std = f" +/- {lc['std']:.3g} {lc['unit']}" if lc["std"] is not None else ""
            return [("link length Lc", f"{lc['value']:.9g} {lc['unit']} (estimated{std}; "
                     f"machine file {lc['assumed']:.9g} {lc['unit']})")]
        return [("link length Lc", f"{lc['value']:.9g} {lc['unit']} (fixed: machine file)")]
