"""Parameters a calibration determines only weakly: one rule for every machine and instrument.

A parameter can be identifiable (not along the null space) and still be determined with a
standard deviation far beyond what a calibration is for: a Delta printer's arm lengths fitted
from bed heights with a standard deviation of a millimetre, a rail direction of a Hexa Slide
known to a few hundredths of a degree. Every calibration (the calibration layer's common end,
:func:`pkmcal.calibration.run._finish`, whatever the machine, instrument or number of files)
names such parameters by this one rule (:func:`poorly_determined`) and says so in one warning
(:func:`poorly_determined_warning`).

**The rule.** A free machine parameter is *poorly determined* when its standard deviation,
as a displacement at the machine's scale, exceeds :data:`POOR_FRACTION` of the machine's
size ``L`` (:meth:`~pkmcal.machines.base.Machine.characteristic_length`, the length that
scales lengths against angles in the identification):

- a length: ``std > POOR_FRACTION * L``;
- an angle, a slope or a ratio: ``std * L > POOR_FRACTION * L``, i.e. ``std > POOR_FRACTION``
  (rad or 1): an angle beyond 0.023 deg on every machine.

``POOR_FRACTION = 4e-4`` (one part in 2500 of the machine's size) is 0.1 mm on a 250 mm
printer - ten times a bed probe's default repeatability and the order of a printer's useful
accuracy, the threshold bed-probe calibrations warned by before the rule was shared - and
0.18 mm on the 450 mm Hexa Slide, 0.12 mm on a 300 mm Delta robot. A machine twice the size
accepts twice the length, as its accuracy budget and its build tolerances scale with it; an
angle moves points at the machine's scale by ``std * L``, so its limit is the same fraction.

The rule is about the parameter alone, not the machine's accuracy: strongly correlated
parameters can each be poorly determined while their combination - and so the predicted
accuracy over the workspace, which the report gives from the full covariance - is good. The
warning names the strongest correlation for that reason; what to measure next comes from the
instruments that measured (:attr:`~pkmcal.instruments.base.Instrument.measure_next`).

The standard deviation used is the marginal one of the fit's covariance (the identifiable part
for a parameter that also moves along the null space: ``combined``) or, when larger, that of a
weakly identifiable direction it moves along (left at its start value by the fit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MEASURE_NEXT", "POOR_FRACTION", "PoorParameter", "poor_limit", "poorly_determined",
           "poorly_determined_section", "poorly_determined_warning"]

#: the fraction of the machine's size (its characteristic length) beyond which a parameter's
#: standard deviation, as a displacement at the machine's scale, makes it poorly determined
#: (see the module docstring): 0.1 mm on a 250 mm printer, 0.023 deg for an angle
POOR_FRACTION = 4e-4

#: what to measure next when the instruments that measured say nothing of their own
MEASURE_NEXT = ("more poses where they tell most (pkmcal select-poses), over more of the "
                "workspace and its orientations, or another instrument (distances or points)")

#: the rule in words, as the report's ``poorly_determined`` section states it
RULE_WORDS = ("a free parameter whose standard deviation at the machine's scale (a length's; "
              "an angle's, slope's or ratio's times the characteristic length) exceeds "
              f"{POOR_FRACTION:g} of the characteristic length (1/{1 / POOR_FRACTION:.0f} of "
              "the machine's size; an angle: "
              f"{np.degrees(POOR_FRACTION):.2g} deg)")


def poor_limit(length: float) -> float:
    """The displacement (m) beyond which a parameter is poorly determined on a machine of
    characteristic length ``length`` (m): ``POOR_FRACTION * length``."""
    return POOR_FRACTION * float(length)


@dataclass
class PoorParameter:
    """A fitted parameter beyond the rule of :func:`poorly_determined`.

    Attributes
    ----------
    name : str
        The parameter.
    std : float
        Its standard deviation, internal units (m, rad, 1).
    kind : str
        ``length``, ``angle``, ``slope`` or ``ratio``.
    partner : str or None
        The parameter it correlates most strongly with (None when it correlates with none).
    correlation : float
        That correlation.
    combined : bool, optional
        The parameter also moves along an unidentifiable direction: its standard deviation is
        that of its identifiable part (the minimum-norm covariance), the value itself is fixed
        only in combination with others.
    """

    name: str
    std: float
    kind: str
    partner: str | None
    correlation: float
    combined: bool = False

    def size(self, length: float) -> float:
        """The standard deviation as a displacement at the machine's scale, m."""
        return self.std if self.kind == "length" else self.std * length

    def text(self, unit_length: str = "mm", unit_angle: str = "deg") -> str:
        """The parameter in words, in the given units.

        Parameters
        ----------
        unit_length : str, optional
            Length unit of the text.
        unit_angle : str, optional
            Angle unit of the text.

        Returns
        -------
        str
            ``"leg1.dl2: std 1.2 mm, correlation +0.98 with leg1.da.x"``.
        """
        from ..units import ANGLE, LENGTH

        if self.kind == "length":
            value = f"{self.std / LENGTH[unit_length]:.3g} {unit_length}"
        elif self.kind == "angle":
            value = f"{self.std / ANGLE[unit_angle]:.3g} {unit_angle}"
        else:
            value = f"{self.std:.3g}"
        corr = ("" if self.partner is None else
                f", correlation {self.correlation:+.3f} with {self.partner}")
        combined = " (its identifiable part)" if self.combined else ""
        return f"{self.name}: std {value}{combined}{corr}"


def poorly_determined(result, n_machine: int, length: float,
                      limit: float | None = None) -> list[PoorParameter]:
    """The fitted machine parameters the rule of this module calls poorly determined.

    Parameters
    ----------
    result : CalibrationResult
        A calibration (``std``, ``covariance``, ``null_space``, ``weak_space``, ``weak_std``,
        ``scales``, ``parameters``).
    n_machine : int
        Number of machine parameters (the first in ``result.parameters``).
    length : float
        The machine's characteristic length, m.
    limit : float, optional
        The displacement at the machine's scale, m; default :func:`poor_limit` of ``length``.

    Returns
    -------
    list of PoorParameter
        Largest displacement at the machine's scale first.
    """
    limit = poor_limit(length) if limit is None else float(limit)
    params = result.parameters
    cov = np.asarray(result.covariance, float)
    std = np.asarray(result.std, float)
    scales = np.asarray(result.scales, float)
    N = np.asarray(result.null_space, float)
    W = np.asarray(result.weak_space, float)
    weak_std = np.asarray(result.weak_std, float)
    free = np.asarray(params.free, bool)
    out = []
    for i in range(n_machine):
        if not free[i]:
            continue
        combined = bool(N.ndim == 2 and N.shape[1] and np.linalg.norm(N[i]) > 1e-6)
        s = float(std[i])
        if W.ndim == 2 and W.shape[1] and np.linalg.norm(W[i]) > 1e-6:
            s = max(s, float(np.max(np.abs(W[i]) * weak_std)) * scales[i])
        kind = params.kinds[i]
        size = s if kind == "length" else s * length
        if not size > limit:
            continue
        partner, best = None, 0.0
        for j in range(len(params.names)):
            if j == i or not free[j] or std[j] <= 0 or std[i] <= 0:
                continue
            # a correlation is in [-1, 1]; rounding takes it past (-1.0000000000000002),
            # which the report's reader rightly refuses (issue 37)
            c = float(np.clip(cov[i, j] / (std[i] * std[j]), -1.0, 1.0))
            if abs(c) > abs(best):
                partner, best = params.names[j], float(c)
        out.append(PoorParameter(params.names[i], s, kind, partner, best, combined))
    out.sort(key=lambda p: -p.size(length))
    return out


def poorly_determined_section(poor: list[PoorParameter], length: float, units: dict,
                              measure_next: str) -> dict:
    """The report's ``poorly_determined`` section.

    Parameters
    ----------
    poor : list of PoorParameter
        The parameters (:func:`poorly_determined`).
    length : float
        The machine's characteristic length, m.
    units : dict
        The file's units (``length``; a length's std is in it, an angle's in rad).
    measure_next : str
        What to measure to fix them, in words.

    Returns
    -------
    dict
        ``threshold_mm``, ``fraction``, ``characteristic_length_mm``, ``rule``,
        ``measure_next``, ``parameters`` (name, std, kind, correlated_with, correlation).
    """
    from ..units import LENGTH

    fl = LENGTH[units["length"]]
    return {
        "threshold_mm": poor_limit(length) * 1e3,
        "fraction": POOR_FRACTION,
        "characteristic_length_mm": float(length) * 1e3,
        "rule": RULE_WORDS,
        "measure_next": measure_next,
        "parameters": [{"name": p.name, "std": p.std / (fl if p.kind == "length" else 1.0),
                        "kind": p.kind, "correlated_with": p.partner,
                        "correlation": p.correlation} for p in poor]}


def poorly_determined_warning(poor: list[PoorParameter], source: str, instrument: str,
                              length: float, measure_next: str,
                              units: dict | None = None) -> list[str]:
    """The one warning of :func:`poorly_determined` parameters (empty when none): how many,
    the largest, that the report lists them all, and what to measure next.

    Parameters
    ----------
    poor : list of PoorParameter
        The parameters, largest first.
    source : str
        The data, named first in the warning.
    instrument : str
        The instrument(s) that measured, in words.
    length : float
        The machine's characteristic length, m (the limit, :func:`poor_limit`).
    measure_next : str
        What to measure to fix them.
    units : dict, optional
        ``{"length": ..., "angle": ...}`` of the text; default mm and deg.

    Returns
    -------
    list of str
        No warning, or one line.
    """
    if not poor:
        return []
    from ..units import ANGLE, LENGTH

    units = units or {"length": "mm", "angle": "deg"}
    limit = (f"{poor_limit(length) / LENGTH[units['length']]:.3g} {units['length']}, an angle "
             f"{POOR_FRACTION / ANGLE[units['angle']]:.2g} {units['angle']}")
    n = len(poor)
    which = (f"{poor[0].text(units['length'], units['angle'])}" if n == 1 else
             f"largest: {poor[0].text(units['length'], units['angle'])}; the report lists "
             "them all")
    return [f"{source}: {n} parameter(s) poorly determined by these {instrument} "
            f"measurements (standard deviation beyond {limit}, at the machine's scale): "
            f"{which}; to fix them, measure {measure_next}"]
