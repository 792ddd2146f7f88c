"""Calibration from bed-probe heights, and what heights fix only weakly.

The instrument's model is :class:`~pkmcal.instruments.ProbeModel`: the bed is the plane
``z = bed.z + bed.tilt_x x + bed.tilt_y y`` (base frame) and each row is the nozzle's height
above it, along z, at the readings where the probe triggered (``probe_z``, 0 for a probe that
triggers on nozzle contact). The machine's parameters and the bed are estimated together by
the shared estimator (:func:`~pkmcal.instruments.fit_instrument`): the bed starts from a plane
fit on the machine file's model, then the bed alone is fitted, then everything.

What heights cannot fix is found in the numerical null space and named
(:mod:`pkmcal.instruments.problem`): a frame motion of the machine that the bed plane
absorbs (a translation along z of the base frame - on a printer, every endstop shifted by the
same amount - with ``bed.z``, a tilt of the base frame with the bed's tilt), the motions no
height sees at all (translations and turns in the bed's plane), a vertical scale about the bed
(invisible while every probe point lies on the bed: probing at a second height sees it;
:func:`~pkmcal.instruments.registry.height_groups`) and the parameter combinations nothing
explains.

What heights fix only *weakly* is another matter: a parameter may be determined, but with a
standard deviation far beyond what a calibration is for (a Delta printer's arm lengths, fitted
from heights with a standard deviation of the order of a millimetre, nearly equal to a change
of the radius). :func:`poorly_determined` names every such parameter with its standard
deviation, its strongest correlation and what to measure next; the threshold is
:data:`POOR_STD`: a parameter whose standard deviation moves points at the machine's scale by
more than 0.1 mm (lengths: std above 0.1 mm; angles and ratios: std times the characteristic
length above 0.1 mm), ten times the probe's default repeatability and the order of a 3D
printer's useful accuracy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..estimation.rank import RTOL
from ..instruments import InstrumentData, IsotropicNoise, fit_instrument
from ..instruments.bed import BED_TILT_CHOICES, TILT_REDUNDANCY, BedChoice, bed_choice

__all__ = ["BED_TILT_CHOICES", "MEASURE_NEXT", "POOR_STD", "TILT_REDUNDANCY", "BedChoice",
           "PoorParameter", "bed_choice", "calibrate_probe", "poorly_determined",
           "poorly_determined_warnings"]
from ..estimation.estimator import CalibrationResult
from ..machines.base import Machine

#: the displacement at the machine's scale (m) beyond which a fitted parameter's standard
#: deviation makes it poorly determined (see the module docstring)
POOR_STD = 1e-4
#: what to measure next, per instrument that measured (what heights cannot give: lengths)
MEASURE_NEXT = {
    "probe": "distances (a ballbar, or caliper distances between features of a printed "
             "object, as Klipper's enhanced DELTA_CALIBRATE) or points (a laser tracker)",
}


@dataclass
class PoorParameter:
    """A fitted parameter whose standard deviation is beyond :data:`POOR_STD`.

    Attributes
    ----------
    name : str
        The parameter.
    std : float
        Its standard deviation, internal units (m, rad, 1).
    kind : str
        ``length``, ``angle`` or ``ratio``.
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
                      threshold: float = POOR_STD) -> list[PoorParameter]:
    """The fitted machine parameters whose standard deviation is beyond ``threshold``.

    A parameter counts when it is free and its standard deviation - a length's, or an angle's
    or ratio's times ``length`` - exceeds ``threshold``; for a parameter that also moves along
    the null space (named by :func:`~pkmcal.identifiability.name_null_space`) that is the
    standard deviation of its identifiable part (``combined``: a linear Delta's arm trim, of
    which the data see only the sum with the common arm length). A parameter along a weakly
    identifiable direction (left at its start value) counts as well, with that direction's
    standard deviation when it is larger.

    Parameters
    ----------
    result : CalibrationResult
        A calibration (``std``, ``covariance``, ``null_space``, ``weak_space``, ``scales``).
    n_machine : int
        Number of machine parameters (the first in ``result.parameters``).
    length : float
        The machine's characteristic length, m.
    threshold : float, optional
        The displacement at the machine's scale, m (:data:`POOR_STD`).

    Returns
    -------
    list of PoorParameter
        Largest (scaled) standard deviation first.
    """
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
        combined = bool(N.shape[1] and np.linalg.norm(N[i]) > 1e-6)
        s = float(std[i])
        if W.shape[1] and np.linalg.norm(W[i]) > 1e-6:
            s = max(s, float(np.max(np.abs(W[i]) * weak_std)) * scales[i])
        kind = params.kinds[i]
        size = s if kind == "length" else s * length
        if not size > threshold:
            continue
        partner, best = None, 0.0
        for j in range(len(params.names)):
            if j == i or not free[j] or std[j] <= 0 or std[i] <= 0:
                continue
            c = cov[i, j] / (std[i] * std[j])
            if abs(c) > abs(best):
                partner, best = params.names[j], float(c)
        out.append(PoorParameter(params.names[i], s, kind, partner, best, combined))
    out.sort(key=lambda p: -(p.std if p.kind == "length" else p.std * length))
    return out


def poorly_determined_warnings(poor: list[PoorParameter], source, instrument: str = "probe",
                               units: dict | None = None,
                               threshold: float = POOR_STD, shown: int = 4) -> list[str]:
    """One warning in words for the :func:`poorly_determined` parameters (empty when none).

    Parameters
    ----------
    poor : list of PoorParameter
        The parameters, largest standard deviation first.
    source : str
        The data, named in the warning.
    instrument : str, optional
        The instrument that measured (what to measure next: :data:`MEASURE_NEXT`).
    units : dict, optional
        ``{"length": ..., "angle": ...}`` of the text; default mm and deg.
    threshold : float, optional
        The threshold used, m.
    shown : int, optional
        How many parameters the warning names (the report lists all).

    Returns
    -------
    list of str
        No warning, or one naming the worst ``shown`` parameters and how many there are.
    """
    if not poor:
        return []
    units = units or {"length": "mm", "angle": "deg"}
    from ..units import LENGTH

    limit = f"{threshold / LENGTH[units['length']]:.3g} {units['length']}"
    nxt = MEASURE_NEXT.get(instrument, "another instrument (distances or points)")
    named = "; ".join(p.text(units["length"], units["angle"]) for p in poor[:shown])
    more = (f"; and {len(poor) - shown} more (the report's poorly_determined lists them)"
            if len(poor) > shown else "")
    return [f"{source}: {len(poor)} parameter(s) poorly determined by these {instrument} "
            f"measurements (standard deviation beyond {limit} at the machine's scale): "
            f"{named}{more}; to fix them, measure {nxt}"]


def calibrate_probe(machine: Machine, data: InstrumentData, noise=None, rtol: float = RTOL,
                    fit_machine: bool = True, bed: BedChoice | str = "auto",
                    **options) -> CalibrationResult:
    """Identify the machine's parameters (and the bed plane) from probe heights.

    Parameters
    ----------
    machine : Machine
        Start geometry; not modified.
    data : InstrumentData
        ``kind="probe"``: readings at the triggers and the nozzle's heights above the bed
        there (m).
    noise : IsotropicNoise, optional
        The probe's repeatability along z (default
        :data:`~pkmcal.instruments.registry.PROBE_SIGMA`, 10 um).
    rtol : float, optional
        Rank tolerance.
    fit_machine : bool, optional
        False fits the bed alone with the machine file's model (the "before calibration"
        baseline).
    bed : BedChoice or str, optional
        The bed's unknowns (:func:`bed_choice`; a string is its ``choice``).
    **options
        Passed to :func:`~pkmcal.estimation.estimator.levenberg_marquardt`.

    Returns
    -------
    CalibrationResult
        With ``extras``: ``problem``, ``machine`` (calibrated, with ``probe_bed``: ``(height,
        tilt_x, tilt_y)``), ``model``, ``start_model``, ``bed``, ``unidentifiable`` and
        ``poorly_determined`` (:func:`poorly_determined`).

    Raises
    ------
    InputError
        When the data are not probe heights, there are fewer than 3 rows (the bed plane), or
        the machine file's model cannot reproduce some readings.
    """
    from ..instruments.registry import PROBE_SIGMA

    noise = IsotropicNoise(PROBE_SIGMA) if noise is None else noise
    if data.kind != "probe":
        raise InputError(f"{data.source}: {data.kind} data, not probe heights")
    if len(data) < 3:
        raise InputError(f"{data.source}: {len(data)} probe height(s); at least 3 points not "
                         "on one line are needed")
    if isinstance(bed, str):
        bed = bed_choice(machine, data, noise, bed, rtol=rtol)
    result = fit_instrument(machine, data, bed.model(), noise, fit_machine=fit_machine,
                            rtol=rtol, **options)
    result.extras["bed_choice"] = bed
    # the null directions named with the probe's own words (a vertical scale about the bed)
    from ..identifiability import name_null_space, name_weak_directions
    from ..instruments.registry import ProbeProblem

    problem = ProbeProblem.__new__(ProbeProblem)
    problem.__dict__.update(result.extras["problem"].__dict__)
    groups = problem.null_groups(result.state, result.scales, result.null_space)
    result.extras["problem"] = problem
    result.extras["unidentifiable"] = (
        name_null_space(result.null_space, problem.parameters, groups)
        + name_weak_directions(result, problem.parameters))
    bed = tuple(float(v) for v in result.state.nuisance.values[:3])
    result.extras["machine"].probe_bed = bed
    result.extras["bed"] = bed
    n_machine = len(machine.parameters)
    result.extras["poorly_determined"] = (
        poorly_determined(result, n_machine, machine.characteristic_length())
        if fit_machine else [])
    return result
