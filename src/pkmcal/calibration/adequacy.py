"""Model adequacy: the checks a metrologist makes when the residuals exceed the noise.

Residuals far above what the instruments' noise explains mean the noise was assumed too small
or the model lacks errors the machine has. Which one shows in their *structure*: noise is
unrelated to anything measured, a model error is a function of where the machine was. For each
residual column (a leg's reading, a measured coordinate, ...) this module fits the residual
against every regressor the data offer — each joint reading and the platform pose (position
x, y, z and orientation as a rotation vector about the mean orientation) — by a line and by a
parabola, and tests them by F-tests (line against a constant, parabola against the line);
p-values are Bonferroni-adjusted over all the tests made. The strongest pattern (the largest
share of a column's residual variance explained by a significant trend) is named in the
verdict.

Everything works from the calibration problem's noise groups and its data (``data.q``, the
pose in the state or the data); nothing depends on the machine type. The F-tests treat the
residuals of a row as independent observations; the fit has removed what its parameters can
express (e.g. a linear trend of a leg's residual in its own reading, absorbed by the gain), so
the p-values are approximate and conservative for such trends.

:func:`model_adequacy` returns the JSON-ready ``model_adequacy`` section of a calibration
report; :func:`add_to_report` adds it (never raising: a problem it cannot read gets none).
"""

from __future__ import annotations

import numpy as np

from ..estimation.acceptance import (
    FAILED_ALARMING,
    FAILED_SMALL,
    MAX_NOISE_FACTOR,
    residual_verdict,
)
from ..estimation.distributions import f_sf

__all__ = ["ALPHA", "FAR_ABOVE", "add_to_report", "model_adequacy", "trend_tests"]

#: family-wise significance level of the trend tests (Bonferroni over all tests)
ALPHA = 0.01
#: residuals more than this many times the assumed noise are "far above" it (the residual
#: verdict's threshold, :data:`~pkmcal.estimation.acceptance.MAX_NOISE_FACTOR`)
FAR_ABOVE = MAX_NOISE_FACTOR
#: the residual verdicts of a failed test
FAILED = (FAILED_SMALL, FAILED_ALARMING)
#: fewest rows for trend tests
MIN_ROWS = 8
#: strongest trends listed in the report
TOP = 10


def _fit_ss(x: np.ndarray, y: np.ndarray, degree: int) -> tuple[float, np.ndarray]:
    """Residual sum of squares and coefficients of a polynomial fit (x centred and scaled)."""
    A = np.vander(x, degree + 1, increasing=True)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    e = y - A @ coef
    return float(e @ e), coef


def trend_tests(y, x) -> dict:
    """Linear and quadratic trend of residuals ``y`` against a regressor ``x``.

    Parameters
    ----------
    y : array_like, shape (n,)
        Residuals (finite).
    x : array_like, shape (n,)
        Regressor.

    Returns
    -------
    dict
        ``linear_p`` (F-test of the line against a constant), ``quadratic_p`` (the parabola
        against the line), ``explained_linear`` and ``explained_quadratic`` (share of the
        residuals' sum of squares about their mean removed by the line, by the parabola),
        ``slope`` (residual per unit of ``x``) and ``curvature`` (per unit squared, of the
        parabola in ``x``); NaN where ``x`` does not vary.
    """
    y = np.asarray(y, float)
    x = np.asarray(x, float)
    n = len(y)
    nan = {"linear_p": float("nan"), "quadratic_p": float("nan"),
           "explained_linear": float("nan"), "explained_quadratic": float("nan"),
           "slope": float("nan"), "curvature": float("nan")}
    span = float(np.std(x))
    if n < 4 or not span > 1e-12 * max(1.0, float(np.max(np.abs(x)))):
        return nan
    mu = float(np.mean(x))
    t = (x - mu) / span
    ss0 = float(np.sum((y - y.mean()) ** 2))
    if not ss0 > 0:
        return nan
    ss1, c1 = _fit_ss(t, y, 1)
    ss2, c2 = _fit_ss(t, y, 2)
    f1 = (ss0 - ss1) / max(ss1 / (n - 2), 1e-300)
    f2 = (ss1 - ss2) / max(ss2 / (n - 3), 1e-300)
    return {"linear_p": f_sf(max(f1, 0.0), 1, n - 2),
            "quadratic_p": f_sf(max(f2, 0.0), 1, n - 3),
            "explained_linear": max(0.0, 1.0 - ss1 / ss0),
            "explained_quadratic": max(0.0, 1.0 - ss2 / ss0),
            "slope": float(c1[1] / span), "curvature": float(c2[2] / span**2)}


def _column_names(groups, m: int) -> list[str]:
    """A name per residual column: the group's name, and the column's place in it (x, y, z
    for three columns of one group, else 1, 2, ...)."""
    labels = np.asarray(groups.labels)[0] if groups is not None else np.zeros(m, int)
    names = []
    for j in range(m):
        g = int(labels[j])
        members = np.flatnonzero(labels == g)
        base = groups.names[g] if groups is not None else "residuals"
        if len(members) == 1:
            names.append(base)
            continue
        k = int(np.flatnonzero(members == j)[0])
        names.append(f"{base} {'xyz'[k] if len(members) == 3 else k + 1}")
    return names


def _rotvec_about_mean(R) -> np.ndarray:
    from ..kinematics import rotvec_from_matrix

    U, _, Vt = np.linalg.svd(np.sum(R, axis=0))       # chordal mean orientation
    mean = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    return rotvec_from_matrix(np.einsum("ji,kjl->kil", mean, R))


def regressors(problem, state, K: int) -> dict:
    """What the residuals are tested against: each joint reading, and the platform pose.

    Parameters
    ----------
    problem : object
        The calibration problem (its ``data.q``; the pose from ``state.P``/``state.R``, else
        ``data.P``/``data.R``).
    state : object
        The estimate's state.
    K : int
        Rows of the residuals.

    Returns
    -------
    dict
        Name -> ``(values (K,), unit kind)``; unit kind ``"reading"``, ``"length"`` or
        ``"angle"`` (SI values).
    """
    data = getattr(problem, "data", None)
    out: dict = {}
    q = getattr(data, "q", None)
    if q is not None and np.ndim(q) == 2 and len(q) == K:
        for j in range(np.shape(q)[1]):
            out[f"reading {j + 1}"] = (np.asarray(q, float)[:, j], "reading")
    P = getattr(state, "P", None)
    R = getattr(state, "R", None)
    if P is None or np.shape(P) != (K, 3):
        P, R = getattr(data, "P", None), getattr(data, "R", None)
    if P is not None and np.shape(P) == (K, 3):
        for j, c in enumerate("xyz"):
            out[f"position {c}"] = (np.asarray(P, float)[:, j], "length")
    if R is not None and np.shape(R) == (K, 3, 3):
        phi = _rotvec_about_mean(np.asarray(R, float))
        if np.max(np.ptp(phi, axis=0)) > 1e-9:
            for j, c in enumerate("xyz"):
                out[f"rotation {c}"] = (phi[:, j], "angle")
    return out


def model_adequacy(result, length_factor: float = 1e-6, angle_factor: float = 1e-6,
                   units: tuple = ("um", "urad"), alpha: float = ALPHA,
                   verdict=None) -> dict | None:
    """The model-adequacy checks of a calibration (see the module docstring).

    Parameters
    ----------
    result : CalibrationResult
        A calibration (``problem``, its residuals whitened by the assumed noise,
        ``noise`` when the levels were estimated).
    length_factor, angle_factor : float, optional
        SI value of one display unit of lengths and angles.
    units : tuple of str, optional
        Their names.
    alpha : float, optional
        Family-wise significance level of the trend tests.
    verdict : ResidualVerdict, optional
        The residual verdict (default :func:`~pkmcal.estimation.acceptance.residual_verdict`
        of ``result``): whether the residuals agree with the noise is stated as it says.

    Returns
    -------
    dict or None
        JSON-ready: ``noise_ratio`` (the verdict's: ``sqrt(chi2 / dof)`` against the assumed
        noise; None when the residuals are not tested), ``far_above_noise`` (the verdict
        failed by at least :data:`FAR_ABOVE`), ``residual_verdict`` (the verdict's status),
        ``groups`` (per noise group: RMS, assumed, used), ``columns`` (per residual column:
        RMS and its strongest trend), ``trends`` (the strongest significant ones), ``tests``,
        ``alpha``, ``findings`` (what the trend tests found, in words), ``verdict`` (the
        residual verdict's sentence, then the findings); None when the result has no problem
        or residuals to examine.
    """
    from ..estimation.variance import noise_groups_of

    problem = result.problem
    r = np.asarray(result.residuals, float)
    if problem is None or r.ndim != 2 or r.size == 0:
        return None
    K, m = r.shape
    groups = noise_groups_of(problem)
    if groups is not None and np.shape(groups.labels) != (K, m):
        groups = None
    used = np.asarray(np.ones((K, m), bool) if result.used is None else result.used, bool)
    if used.shape != (K, m):
        used = np.ones((K, m), bool)
    rows = np.all(used & np.isfinite(r), axis=1)

    def display(kind):
        # residuals of a problem without noise groups are whitened by the method's weights
        # only (a method that takes some measurements as exact): not by the noise model
        return ((length_factor, units[0]) if kind == "length" else
                (angle_factor, units[1]) if kind == "angle" else
                (1.0, "residual / the method's weight"))

    # residuals in SI (whitened x the assumed level of their group), and in display units
    if groups is not None:
        labels = np.asarray(groups.labels, int)
        sigma = groups.assumed[labels]
        kinds = [groups.kinds[int(labels[0, j])] for j in range(m)]
        noise = result.noise
        used_sigma = (noise.sigma if noise is not None and len(noise.sigma) == len(groups.keys)
                      else groups.assumed)
    else:
        labels, sigma, kinds = np.zeros((K, m), int), np.ones((K, m)), [None] * m
        used_sigma = None
    phys = r * sigma
    names = _column_names(groups, m)
    ok = rows[:, None] & np.isfinite(r)
    verdict = verdict if verdict is not None else residual_verdict(result)
    ratio = verdict.noise_ratio
    out_groups = []
    for g in range(len(groups.keys) if groups is not None else 1):
        sel = ok & (labels == g)
        f, unit = display(groups.kinds[g] if groups is not None else None)
        rms = float(np.sqrt(np.mean(phys[sel] ** 2))) if sel.any() else float("nan")
        entry = {"name": groups.names[g] if groups is not None else "residuals",
                 "unit": unit, "rms": rms / f, "count": int(sel.sum())}
        if groups is not None:
            entry.update(key=groups.keys[g], assumed=float(groups.assumed[g]) / f,
                         used=float(used_sigma[g]) / f)
        out_groups.append(entry)
    # trend tests: every residual column against every regressor
    regs = regressors(problem, result.state, K) if rows.sum() >= MIN_ROWS else {}
    raw = []
    for j in range(m):
        y = phys[rows, j]
        for name, (x, _kind) in regs.items():
            t = trend_tests(y, x[rows])
            if np.isfinite(t["linear_p"]):
                raw.append((j, name, t))
    n_tests = 2 * len(raw)
    columns = []
    trends = []
    for j, name, t in raw:
        for shape, p, explained in (("linear", t["linear_p"], t["explained_linear"]),
                                    ("quadratic", t["quadratic_p"], t["explained_quadratic"])):
            p_adj = min(1.0, p * n_tests)
            if p_adj < alpha:
                trends.append({"residual": names[j], "against": name, "shape": shape,
                               "explained": explained, "p": p, "p_adjusted": p_adj,
                               "column": j})
    trends.sort(key=lambda d: (-d["explained"], d["p"]))
    for j in range(m):
        sel = ok[:, j]
        f, unit = display(kinds[j])
        col = {"name": names[j], "unit": unit,
               "rms": float(np.sqrt(np.mean(phys[sel, j] ** 2))) / f if sel.any()
               else float("nan")}
        best = next((d for d in trends if d["column"] == j), None)
        if best is not None:
            col["strongest_trend"] = {k: v for k, v in best.items() if k != "column"}
        columns.append(col)
    far = verdict.status == FAILED_ALARMING
    section = {
        "noise_ratio": ratio, "far_above_noise": far, "far_above": FAR_ABOVE,
        "residual_verdict": verdict.status,
        "groups": out_groups, "columns": columns,
        "trends": [{k: v for k, v in d.items() if k != "column"} for d in trends[:TOP]],
        "significant_trends": len(trends), "tests": n_tests, "alpha": alpha,
        "regressors": list(regs),
        "method": "per residual column, least-squares line and parabola against each joint "
                  "reading and each pose coordinate; F-tests (line vs constant, parabola vs "
                  "line), Bonferroni over all tests",
    }
    section["findings"] = _findings(section, result.extensions)
    section["verdict"] = f"residual test {verdict.sentence()}; {section['findings']}"
    return section


def _findings(section: dict, extensions=None) -> str:
    """What the trend tests (and the model extensions tried) found, in words."""
    trends = section["trends"]
    if trends:
        t = trends[0]
        shape = "curved" if t["shape"] == "quadratic" else "linear"
        pattern = (f"strongest systematic pattern: {t['residual']} against {t['against']} "
                   f"({shape}, explains {t['explained']:.0%} of its residual variance, "
                   f"p = {t['p_adjusted']:.2g} adjusted); {section['significant_trends']} of "
                   f"{section['tests']} trend tests significant: the model lacks an error the "
                   "machine has (or the instrument drifts)")
    elif section["tests"]:
        pattern = (f"no significant trend against the readings or the pose "
                   f"({section['tests']} tests)" + (": the excess behaves like noise (the "
                                                    "instruments noisier than assumed, or "
                                                    "errors no reading or pose coordinate "
                                                    "explains)" if section[
                                                        "residual_verdict"] in FAILED
                                                    else ""))
    else:
        pattern = "too few rows for trend tests"
    text = pattern
    if extensions is not None and getattr(extensions, "trials", None):
        adopted = list(getattr(extensions, "adopted", []))
        text += ("; model extension adopted by cross-validation: " + ", ".join(adopted)
                 if adopted else "; no model extension predicted held-out rows better")
    return text


def add_to_report(result, report: dict, verdict=None) -> None:
    """Add the ``model_adequacy`` section to a calibration report (nothing when the result
    cannot be examined; never raises for a problem it cannot read).

    Parameters
    ----------
    result : CalibrationResult
        The calibration.
    report : dict
        The report, changed in place.
    verdict : ResidualVerdict, optional
        The residual verdict the report states (default: that of ``result``).
    """
    units = report.get("units") or {}
    from ..units import ANGLE, LENGTH

    lu, au = units.get("length", "um"), units.get("angle", "urad")
    fl = LENGTH.get(lu, 1e-6) if lu in LENGTH else 1e-6
    fa = ANGLE.get(au, 1e-6) if au in ANGLE else 1e-6
    try:
        section = model_adequacy(result, fl, fa, (lu if lu in LENGTH else "um",
                                                  au if au in ANGLE else "urad"),
                                 verdict=verdict)
    except (ValueError, TypeError, AttributeError, IndexError, np.linalg.LinAlgError):
        section = None
    if section is not None:
        report["model_adequacy"] = section
