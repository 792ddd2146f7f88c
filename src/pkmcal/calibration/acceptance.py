"""The common end of every calibration (:func:`finish`): covariance, residual verdict, noise
and outlier report, acceptance checks, weakly determined parameters and provenance, whatever
the machine, the instruments and the number of files."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..estimation.sections import add_sections
from ..instruments.flow import FlowContext, fit_with_baseline, report_head
from ..instruments.setups import Setups
from ..paths import path_text
from .provenance import file_units, provenance
from .result import Calibration
from .tolerances import tolerance_report


def _acceptance(result, nominal, calibrated, source, method, warnings: list,
                verdict=None) -> dict:
    """The believability checks of a converged calibration (the residual verdict of
    :func:`~pkmcal.estimation.acceptance.residual_verdict`; size of the changes against the
    machine's scale): warnings in words with the usual causes (appended to ``warnings``; each
    opens with the verdict's sentence), and the report's ``acceptance`` section."""
    from ..estimation.acceptance import (
        FAILED_ALARMING,
        GROSS_RESIDUAL,
        MAX_NOISE_FACTOR,
        parameter_changes,
        residual_verdict,
    )

    out = {}
    noise = result.noise
    verdict = verdict if verdict is not None else residual_verdict(result, method)
    out["residuals"] = verdict.as_dict()
    test = verdict.test
    if verdict.status == FAILED_ALARMING:
        gross = None
        if noise is not None and calibrated is not None:
            # the residuals' size in metres, per group of lengths: tens of micrometres on a
            # printer are a noisier probe or a missing effect, not swapped columns
            size = [float(s) * (test.noise_ratio if st != "estimated" else 1.0)
                    for s, k, st in zip(noise.sigma, noise.kinds, noise.status, strict=True)
                    if k == "length"]
            if size:
                gross = max(size) > GROSS_RESIDUAL * calibrated.characteristic_length()
        if noise is not None and noise.estimated:
            high = [f"{name} {ratio:.3g}x the assumed" for name, ratio, status
                    in zip(noise.names, noise.ratio, noise.status, strict=True)
                    if status == "estimated" and ratio >= MAX_NOISE_FACTOR]
            high = ", ".join(high) or f"none {MAX_NOISE_FACTOR:g}x the assumed"
            warnings.append(
                f"{path_text(source)}: {_failed_words(verdict)}: the noise levels estimated "
                f"from the residuals ({high}) weigh the fit and its standard deviations. If "
                "the instruments are not that noisy, the model misses something: see the "
                "report's residual checks (per "
                "reading, per pose, against each reading) and its model_adequacy section" + (
                    ", and look for swapped columns, a wrong unit or outlier rows"
                    if gross is not False else ", and look for outlier rows"))
        elif gross is False and noise is not None \
                and all(st == "assumed" for st in noise.status):
            # too few rows to estimate any level (Klipper's 7 heights for 6 unknowns): the
            # residuals' size is shown, not taken for a fault of the data
            out["residuals"]["note"] = (
                "the data leave too few equations to estimate the noise, so whether the "
                "instrument or the model is worse than assumed cannot be told")
        else:
            warnings.append(f"{path_text(source)}: {_failed_words(verdict)}: usual causes: "
                            f"{test.causes(gross)}")
    if nominal is not None:
        changes = parameter_changes(nominal, calibrated)
        out["parameter_changes"] = {"suspicious": changes.suspicious}
        if changes.suspicious:
            warnings.append(f"{path_text(source)}: {changes.message()}")
    return out


def _failed_words(verdict) -> str:
    """The failed residual test as a warning opens: its ratio and a pointer to the verdict,
    which the summary's ``residual test`` row and the report state in full (said once)."""
    return (f"residual test failed, {verdict.noise_ratio:.3g}x the assumed noise (the "
            "verdict states it)")


def _state_verdict(report: dict, verdict, sigma_um=None) -> None:
    """The residuals section's numbers that compare the residuals with the noise, from the
    verdict (one definition: ``noise_scale`` is the noise ratio, ``residual_variance`` its
    square; None when the residuals are not tested)."""
    res = report.get("residuals")
    if not isinstance(res, dict):
        return
    ratio = verdict.noise_ratio
    tested = ratio is not None and math.isfinite(ratio)
    for key, value in (("residual_variance", verdict.test.ratio if tested else None),
                       ("noise_scale", ratio if tested else None),
                       ("estimated_noise_um", ratio * sigma_um if tested and sigma_um
                        else None)):
        if key in res:
            res[key] = value


def _standardised(result):
    """Leverage-corrected standardised residuals for the report (None when the problem
    cannot be evaluated again)."""
    # the problem as fitted: reweighted by the estimated noise levels when they were
    problem = result.weighted or result.problem
    if problem is None and callable(result.rebuild_problem):
        problem = result.rebuild_problem()
    if problem is None or result.state is None:
        return None
    from ..report.residuals import standardised_residuals

    if result.weighted_residuals is not None:
        result = dataclasses.replace(result, residuals=result.weighted_residuals)
    try:
        return standardised_residuals(problem, result)
    except (ValueError, np.linalg.LinAlgError):
        return None


def finish(kind: str, machine, calibrated, result, report: dict, metadata: dict, params,
           units, setups=None) -> Calibration:
    """The common end of every kind: the covariance of the machine's parameters (SI: m, rad;
    the identifiable part, frames the data cannot fix held at the start values, which
    ``pkmcal compensate`` propagates to the targets), the normalised and standardised
    residuals, the acceptance checks (their warnings) and the provenance. ``setups``: the
    calibrated file's set-ups (the given ones with the fitted ones in their place)."""
    names = list(calibrated.parameters.names)
    n = len(names)
    report["covariance"] = {
        "of": "machine parameters, SI units (m, rad, ratio), minimum-norm (identifiable "
              "part)",
        "parameters": names,
        "matrix": np.asarray(result.covariance, float)[:n, :n].tolist(),
        # unidentifiable directions (columns, same units): pose changes along them are
        # changes of frames the data cannot see, removed before predicting errors
        "null_space": (np.asarray(result.null_space, float)
                       * np.asarray(result.scales, float)[:, None])[:n].tolist(),
    }
    all_names = list(result.parameters.names)
    if len(all_names) > n and all_names[:n] == names:
        # with the measurement frames (tracker pose, motion-capture frames) and Lc: what
        # compensate needs for targets given in the instrument's frame
        report["covariance"]["with_frames"] = {
            "parameters": all_names,
            "matrix": np.asarray(result.covariance, float).tolist(),
            "null_space": (np.asarray(result.null_space, float)
                           * np.asarray(result.scales, float)[:, None]).tolist(),
        }
    # residual / std of every residual, for the report's histogram: the noise levels the fit
    # used (estimated from the residuals, or assumed / given)
    report["normalised_residuals"] = np.asarray(
        result.residuals if result.weighted_residuals is None
        else result.weighted_residuals, float).ravel().tolist()
    standardised = _standardised(result)
    if standardised is not None:
        report["standardised_residuals"] = standardised
    warnings: list[str] = []
    source = report.get("data_file", "the data")
    _noise_report(result, report, source, warnings,
                  True if result.robust is None else result.robust)
    from ..estimation.acceptance import residual_verdict
    from .adequacy import add_to_report

    # the one verdict on the residuals against the noise: every section states it
    verdict = residual_verdict(result, report.get("method"))
    _state_verdict(report, verdict, report.get("noise_sigma_um"))
    add_to_report(result, report, verdict)  # model_adequacy: residuals against readings, pose
    report["acceptance"] = _acceptance(result, machine, calibrated, source,
                                       report.get("method"), warnings, verdict)
    tolerance_report(result, calibrated, report, path_text(source), units, warnings)
    # weakly determined parameters: one rule on every machine and instrument
    warnings.extend(_weakly_determined(result, machine, report, source, units))
    # each instrument's typed section: its report keys and their index (rendered generically)
    add_sections(report, getattr(result, "sections", {}), units, metadata)
    report["provenance"] = provenance()
    return Calibration(kind=kind, machine=machine, calibrated=calibrated, result=result,
                       report=report, metadata=metadata, params=params, warnings=warnings,
                       units=units, setups=Setups(setups))


def _weakly_determined(result, machine, report: dict, source, units) -> list[str]:
    """The one rule every calibration warns by on weakly determined parameters
    (:func:`~pkmcal.identifiability.determination.poorly_determined`: a standard deviation
    beyond 1/2500 of the machine's size at its scale), whatever the machine, the instruments
    and the number of files: the report's ``poorly_determined`` section and its one warning
    (what to measure next from the instruments that measured). The size is the nominal
    machine's (the file's), as the probe's own list has it."""
    from ..identifiability.determination import (
        MEASURE_NEXT,
        poorly_determined,
        poorly_determined_section,
        poorly_determined_warning,
    )
    from ..instruments.registry import INSTRUMENTS

    length = machine.characteristic_length()
    try:
        poor = poorly_determined(result, len(machine.parameters), length)
    except (AttributeError, IndexError, ValueError, TypeError):
        return []                   # a result without a covariance of its parameters
    kinds = sorted({f.get("measurement") for f in report.get("files") or []} - {None}) \
        or [report.get("measurement", "these")]
    advice = [getattr(INSTRUMENTS.get(k), "measure_next", "") for k in kinds]
    measure = "; or ".join(dict.fromkeys(a for a in advice if a)) or MEASURE_NEXT
    report["poorly_determined"] = poorly_determined_section(poor, length, units, measure)
    return poorly_determined_warning(poor, path_text(source), " and ".join(kinds), length,
                                     measure, units)


def _noise_report(result, report: dict, source, warnings: list, robust: bool = True) -> None:
    """The noise levels (assumed, estimated) and the outlier rows of a calibration: the
    report's ``noise_model`` and ``outliers`` sections and their warnings (rows left out
    without ``robust``: those a start strategy could not fit, kept out by the outlier
    test)."""
    noise, test = result.noise, result.outliers
    if noise is not None:
        report["noise_model"] = noise.as_dict()
    if test is None:
        return
    report["outliers"] = test.as_dict()
    flagged = [test.names[i] for i in test.flagged if test.kept[i]]
    left = [test.names[i] for i in test.left_out]
    if flagged:
        shown = ", ".join(flagged[:10]) + (f" and {len(flagged) - 10} more"
                                            if len(flagged) > 10 else "")
        warnings.append(f"{path_text(source)}: "
                        f"{shown}: residuals the noise does not explain (chi-square "
                        f"test of each row, p < {test.threshold:.2g}); check "
                        f"{'them' if len(flagged) > 1 else 'it'} (a beam break, a mis-read "
                        "marker, a wrong row) or leave them out with --robust")
    if left:
        shown = ", ".join(left[:10]) + (f" and {len(left) - 10} more" if len(left) > 10 else "")
        why = ("--robust" if robust else "the start could not fit them, and the outlier "
               "test agrees")
        warnings.append(f"{path_text(source)}: "
                        f"{len(left)} row(s) left out as outliers ({why}): {shown}")


def calibration_report_head(machine, source, kind: str, method: str, units=None) -> dict:
    """The first keys of every report (``units`` last, when given)."""
    from ..report.provenance import run_date

    return report_head(run_date(), machine, source, kind, method, units)



def fit_with_nominal_baseline(machine, data, source, split, reader, fit, noise, advice: str,
                              estimate_noise: bool, robust: bool, setups=None):
    """:func:`~pkmcal.instruments.flow.fit_with_baseline` for the generic path (read with
    ``reader``; the noise estimated unless given; ``--robust``; the experiment's
    ``setups``)."""
    context = FlowContext(source=source, split=split, units=file_units(machine), date=str,
                          read=reader, setups=Setups(setups))
    return fit_with_baseline(machine, data, context, fit, noise, advice,
                             estimate_noise=estimate_noise, robust=robust)
