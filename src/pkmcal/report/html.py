"""One self-contained HTML file from a calibration report (``pkmcal report``, issue 6).

The input is the JSON report ``pkmcal calibrate`` writes beside the calibrated machine file
(the "JSON twin"); the HTML has no external resource: styles inline, plots as embedded PNG
(base64). Sections appear when the report has the data: summary, identifiability (words,
singular values), residuals (table; histogram of the standardised residuals, leverage-corrected,
against N(0, 1); the residual verdict the report states, :func:`verdict_html`), before/after
accuracy, distance ratios (Delta), registration and frames, parameters (nominal, identified,
change, standard deviation, unit; one panel per chain or leg) and the identifiable combinations
of parameters that are not identifiable one by one.

Every number is shown with its unit (a unit column, or the unit in the column's header); vectors
are written out with their axis names, rotations as an angle about an axis.
"""

from __future__ import annotations

import base64
import html
import re
from collections.abc import Mapping

import numpy as np

from ..units import format_um
from .answer import DIGITS, accuracy_unit, answer_rows, length_text, number

STYLE = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2em auto;
max-width:1100px;color:#222;line-height:1.4;padding:0 1em}
h1{font-size:1.6em;border-bottom:2px solid #446;padding-bottom:.2em}
h2{font-size:1.25em;margin-top:1.6em;color:#335}
table{border-collapse:collapse;margin:.5em 0;font-size:.9em}
td,th{border:1px solid #ccc;padding:.25em .6em;text-align:left;vertical-align:top}
th{background:#eef}
td.num{text-align:right;font-variant-numeric:tabular-nums}
td.unit{color:#555}
.ok{color:#070;font-weight:bold}.bad{color:#b00;font-weight:bold}
td.gauge{color:#888;font-style:italic}
img{max-width:100%;border:1px solid #ddd;margin:.5em 0}
code{background:#f4f4f4;padding:0 .2em}
.small{font-size:.85em;color:#555}
.side{display:flex;flex-wrap:wrap;gap:1.5em;align-items:flex-start}
.side>div{flex:1 1 300px}
.verdict{padding:.4em .7em;border-left:4px solid #446;background:#f6f6fb}
.answer{font-size:1.15em;padding:.5em .8em;margin:.6em 0;border-left:6px solid #888;
background:#f6f6f6}
.answer.passed{border-color:#070;background:#eef8ee}
.answer.failed{border-color:#b00;background:#fbeeee}
.answer.untested{border-color:#b80;background:#fbf6e8}
pre.next{background:#f4f4f4;padding:.5em .8em;margin:.3em 0;white-space:pre-wrap}
"""

#: share of a parameter's unit vector in the null space above which the parameter is not
#: identifiable by itself (structural zeros are ~1e-15; real components are > 0.05)
GAUGE_SHARE = 1e-3
#: |change| / std above which a change is flagged significant
SIGNIFICANT = 3.0

#: unit suffixes of report keys -> shown unit
_SUFFIX_UNITS = {"_um": "um", "_deg": "deg", "_urad": "urad", "_percent": "%", "_mm": "mm",
                 "_m": "m", "_rad": "rad"}
#: counts: key -> what is counted
_COUNTS = {"count": "residuals", "dof": "degrees of freedom", "pairs": "pairs",
           "used": "rows", "measurements": "rows", "held_out": "rows", "iterations":
           "iterations", "evaluations": "evaluations", "status": "code", "fk_failed": "rows",
           "seed": "seed", "sweeps": "sweeps", "significant_trends": "trends",
           "tests": "tests", "column": "column"}
#: dimensionless quantities: key -> unit text
_RATIOS = {"residual_variance": "x assumed variance (chi2/dof)",
           "noise_scale": "x assumed noise std (noise ratio, sqrt(chi2/dof))",
           "held_out_over_calibration": "ratio",
           "holdout": "share or rows", "estimated": "", "fixed": "", "robust": "",
           # model_adequacy (calibration.adequacy)
           "noise_ratio": "x assumed noise std (noise ratio, sqrt(chi2/dof))",
           "far_above": "x assumed noise std (noise ratio)",
           "over_assumed": "RMS / assumed noise std, not corrected for the fitted unknowns",
           "explained": "share of variance",
           "p": "probability", "p_adjusted": "probability", "alpha": "probability",
           "statistic": "chi-square", "threshold_p": "probability"}
#: keys whose value is a length in the section's "unit"
_LENGTH_KEYS = re.compile(r"(^|_)(value|assumed|std|translation|translation_change|rms|max|"
                          r"before_rms|after_rms|calibration_rms|max_after|leg_length_rms|"
                          r"leg_length_max|position_rms|position_max|leg_length_rms_per_leg|"
                          r"smr_offset)$")
_AXES = ("x", "y", "z")


def _e(x) -> str:
    return html.escape(str(x))


def _num(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return number(v, DIGITS) if np.isfinite(v) else "-"
    return str(v)


def _config(v) -> str:
    """A value as a machine file or a firmware's configuration holds it: 6 decimals."""
    if not _is_number(v) or not np.isfinite(v):
        return "-"
    return f"{float(v):.6f}"


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _is_rotation(v) -> bool:
    return (isinstance(v, list) and len(v) == 3
            and all(isinstance(r, list) and len(r) == 3 and all(_is_number(x) for x in r)
                    for r in v))


def _rotation_text(R) -> str:
    """A rotation matrix as 'angle deg about (axis)'."""
    from ..kinematics import rotvec_from_matrix

    rv = np.asarray(rotvec_from_matrix(np.asarray(R, float)), float)
    angle = float(np.linalg.norm(rv))
    if angle < 1e-12:
        return "0 deg (identity)"
    axis = rv / angle
    return (f"{np.degrees(angle):.6g} deg about axis ("
            + ", ".join(f"{a:.4f}" for a in axis) + ")")


def _label_unit(key: str, section_unit: str = "") -> tuple[str, str]:
    """``(label, unit)`` of a report key: the unit from the key's suffix, the section's unit
    for lengths, the thing counted for counts."""
    if key in _COUNTS:
        return key.replace("_", " "), _COUNTS[key]
    if key in _RATIOS:
        return key.replace("_", " "), _RATIOS[key]
    for suffix, unit in _SUFFIX_UNITS.items():
        if key.endswith(suffix):
            return key[: -len(suffix)].replace("_", " "), unit
    if section_unit and _LENGTH_KEYS.search(key):
        return key.replace("_", " "), section_unit
    return key.replace("_", " "), ""


def _vector_text(key: str, v: list) -> str:
    """A numeric vector with the names of its entries (axes, joints, legs)."""
    if "per_axis" in key or (len(v) == 3 and ("translation" in key or key.endswith(".x")
                                               or key in ("rotation",))):
        names = _AXES
    elif "per_column" in key:
        names = [f"q{i + 1}" for i in range(len(v))]
    elif "per_leg" in key:
        names = [f"leg {i + 1}" for i in range(len(v))]
    elif len(v) == 3:
        names = _AXES
    else:
        return ", ".join(_num(x) for x in v)
    return ", ".join(f"{n} {_num(x)}" for n, x in zip(names, v, strict=False))


def _value_text(key: str, v) -> str:
    """Readable text of any report value (never a raw dictionary or list)."""
    if isinstance(v, list):
        if not v:
            return "none"
        if _is_rotation(v):
            return _rotation_text(v)
        if all(_is_number(x) for x in v):
            if key in ("rows", "outlier_rows", "dropped_rows", "not_reached") or \
                    all(isinstance(x, int) for x in v):
                return ", ".join(str(x) for x in v)
            return _vector_text(key, v)
        if all(isinstance(x, Mapping) for x in v):
            return "; ".join(", ".join(f"{_label_unit(k)[0]} {_num(val)}"
                                       + (f" {_label_unit(k)[1]}" if _label_unit(k)[1] and
                                          _is_number(val) else "")
                                       for k, val in x.items()) for x in v)
        return ", ".join(_num(x) for x in v)
    if isinstance(v, Mapping):
        return "; ".join(f"{k}: {_value_text(k, x)}" for k, x in v.items())
    return _num(v)


def _rows(d: Mapping, prefix: str = "", section_unit: str = ""):
    """``(label, value text, unit, numeric)`` rows of a (nested) report section."""
    unit = d.get("unit", section_unit) if isinstance(d.get("unit", ""), str) else section_unit
    for k, v in d.items():
        if k == "unit" and isinstance(v, str):
            continue
        if isinstance(v, Mapping):
            yield from _rows(v, f"{prefix}{k.replace('_', ' ')}: ", unit)
            continue
        label, u = _label_unit(k, unit)
        if _is_rotation(v):
            u = "deg"
        numeric = _is_number(v) or (isinstance(v, list) and bool(v) and
                                    (all(_is_number(x) for x in v) or _is_rotation(v)))
        if k in ("rows", "outlier_rows", "dropped_rows", "not_reached"):
            u = "file rows"
        yield f"{prefix}{label}", _value_text(k, v), u, numeric


def _kv_table(rows) -> str:
    """quantity | value | unit."""
    body = "".join(
        f"<tr><th>{_e(k)}</th><td{' class=num' if num else ''}>{_e(text)}</td>"
        f"<td class=unit>{_e(unit)}</td></tr>" for k, text, unit, num in rows)
    return f"<table><tr><th>quantity</th><th>value</th><th>unit</th></tr>{body}</table>"


def plot_axes(fig) -> list[dict]:
    """What each visible panel of a figure shows on its axes.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure.

    Returns
    -------
    list of dict
        Per panel ``{"x": label, "y": label, "x_numeric": bool, "y_numeric": bool}``, per
        colour bar ``{"colour": label}`` (numeric axes name a unit in brackets; categorical
        ones, e.g. parameter names, name what they list).
    """
    from matplotlib.ticker import LogFormatter, ScalarFormatter

    def numeric(axis) -> bool:
        # numbers on the axis (a unit is due) unless its ticks were given names
        return isinstance(axis.get_major_formatter(), (ScalarFormatter, LogFormatter))

    out = []
    for ax in fig.axes:
        if not ax.get_visible():
            continue
        colorbar = getattr(ax, "_colorbar", None)
        if colorbar is not None:
            label = ax.get_ylabel() or ax.get_xlabel()
            out.append({"colour": " ".join(label.split())})
            continue
        out.append({"x": " ".join(ax.get_xlabel().split()),
                    "y": " ".join(ax.get_ylabel().split()),
                    "x_numeric": numeric(ax.xaxis), "y_numeric": numeric(ax.yaxis)})
    return out


def _png(fig) -> str:
    """The figure as an embedded PNG; its ``alt`` text and ``data-axes`` say what its axes
    show (:func:`plot_axes`)."""
    from .plots import png_bytes

    axes = plot_axes(fig)
    data = base64.b64encode(png_bytes(fig, 100)).decode("ascii")
    alt = "; ".join(f"colour: {a['colour']}" if "colour" in a else f"x: {a['x']}, y: {a['y']}"
                    for a in axes)
    # one panel per " | ", its axes as "x=...; y=..." ("x#=" a categorical axis)
    coded = " | ".join(
        f"colour={a['colour']}" if "colour" in a else
        f"x{'' if a['x_numeric'] else '#'}={a['x']}; y{'' if a['y_numeric'] else '#'}={a['y']}"
        for a in axes)
    return (f'<img alt="plot ({_e(alt)})" data-axes="{_e(coded)}" '
            f'src="data:image/png;base64,{data}">')


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _standardised(report) -> tuple[np.ndarray, str] | None:
    """Standardised residuals and how they were corrected."""
    st = report.get("standardised_residuals")
    if st:
        r = np.asarray([np.nan if v is None else v for v in st], float)
        return r[np.isfinite(r)], ("leverage-corrected: residual / (assumed std x "
                                   "sqrt(1 - h_ii)), h_ii from the hat matrix of the fit")
    normalised = report.get("normalised_residuals")
    dof = (report.get("residuals") or {}).get("dof")
    if not normalised:
        return None
    r = np.asarray([np.nan if v is None else v for v in normalised], float)
    r = r[np.isfinite(r)]
    if dof and dof > 0 and r.size:
        return r / np.sqrt(dof / r.size), (f"global correction: residual / (assumed std x "
                                           f"sqrt(dof / N)), dof {dof}, N {r.size} (this "
                                           "report has no per-residual leverages)")
    return r, "residual / assumed std (no degrees-of-freedom correction available)"


def _assumed_scale(report) -> tuple[float, str]:
    """``(factor, words)`` that turns residuals over the noise levels the fit used into
    residuals over the assumed noise: with one noise level estimated from these residuals,
    its ratio to the assumed (a histogram over the estimate is N(0, 1) by construction and
    would hide a failed test); 1 otherwise."""
    levels = report.get("noise_model")
    if not (isinstance(levels, Mapping) and levels.get("estimated")):
        return 1.0, "over the assumed noise"
    groups = [g for g in levels.get("groups") or [] if isinstance(g, Mapping)]
    if len(groups) == 1 and _is_number(groups[0].get("ratio")) and groups[0]["ratio"] > 0:
        return float(groups[0]["ratio"]), "over the assumed noise"
    return 1.0, ("over the noise levels estimated from these residuals (N(0, 1) by "
                 "construction: the residual test compares them with the assumed noise)")


def _residual_plot(r, how: str, scale: float = 1.0, over: str = "") -> str:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.2, 3.6), layout="constrained")
    r = np.asarray(r, float) * scale
    ax.hist(r, bins=min(60, max(10, r.size // 15)), density=True, alpha=0.7,
            label=f"{r.size} standardised residuals")
    lim = max(4.0, float(np.max(np.abs(r))) if r.size else 4.0)
    x = np.linspace(-lim, lim, 200)
    ax.plot(x, np.exp(-x**2 / 2) / np.sqrt(2 * np.pi), "k-", lw=1.2, label="N(0, 1)")
    ax.set_xlabel(("standardised residual [1] (leverage-corrected)" if how.startswith("lev")
                   else "standardised residual [1] (dof-corrected)")
                  + ("" if over == "over the assumed noise" or not over
                     else "\nover the estimated noise levels"), fontsize=10)
    ax.set_ylabel("density [1/residual std]", fontsize=10)
    ax.set_title("leverage-corrected: r / (sigma sqrt(1 - h_ii))" if how.startswith("lev")
                 else "global dof correction: r / (sigma sqrt(dof/N))", fontsize=10)
    ax.legend(fontsize=9)
    return _png(fig)


def verdict_html(report) -> str:
    """The residual verdict a report states, as HTML: the chi-square test's numbers and the
    verdict's sentence (:func:`~pkmcal.estimation.acceptance.report_verdict`; the HTML never
    tests the residuals itself).

    Parameters
    ----------
    report : mapping
        A calibration report (``acceptance.residuals``; ``noise_sigma_um`` when given).

    Returns
    -------
    str
        A table (when tested) and a paragraph of class ``verdict``.
    """
    from ..estimation.acceptance import PASSED, report_verdict

    verdict = report_verdict(report)
    section = (report.get("acceptance") or {}).get("residuals") or {}
    note = f"; {section['note']}" if section.get("note") else ""
    ok = "ok" if verdict.status == PASSED else "bad"
    words, rest = verdict.sentence().split(": ", 1)
    if not verdict.tested:
        return (f"<p class=verdict>Residual test <b>{_e(words)}</b>: {_e(rest)}{_e(note)}."
                "</p>")
    t = verdict.test
    sigma = ""
    if verdict.status != PASSED and _is_number(report.get("noise_sigma_um")):
        sigma = (f" At that noise ratio the noise would be "
                 f"{format_um(report['noise_sigma_um'] * verdict.noise_ratio, 3)} (assumed "
                 f"{format_um(report['noise_sigma_um'], 3)}).")
    return (f"<table><tr><th>quantity</th><th>value</th><th>unit</th></tr>"
            f"<tr><th>chi-square (sum of squared residual / assumed noise std)</th>"
            f"<td class=num>{number(t.chi2)}</td><td class=unit>1</td></tr>"
            f"<tr><th>degrees of freedom</th><td class=num>{t.dof}</td>"
            f"<td class=unit>count</td></tr>"
            f"<tr><th>chi2 / dof</th><td class=num>{number(t.ratio)}</td>"
            f"<td class=unit>1</td></tr>"
            f"<tr><th>largest chi2 / dof expected (99.9 %)</th><td class=num>{number(t.upper)}"
            f"</td><td class=unit>1</td></tr>"
            f"<tr><th>noise ratio: residuals over the assumed noise, sqrt(chi2 / dof)</th>"
            f"<td class=num>{number(t.noise_ratio)}</td><td class=unit>1</td></tr></table>"
            f"<p class=verdict>Residual test <span class={ok}>{_e(words)}</span>: "
            f"{_e(rest)}{_e(note)}.{_e(sigma)}</p>")


def _singular_plot(s, rank) -> str:
    plt = _plt()
    s = np.asarray(s, float)
    fig, ax = plt.subplots(figsize=(6.2, 3.2), layout="constrained")
    idx = np.arange(1, s.size + 1)
    ax.semilogy(idx[:rank], s[:rank], "o", ms=4, label="identifiable")
    if s.size > rank:
        ax.semilogy(idx[rank:], np.maximum(s[rank:], s[0] * 1e-17), "x", color="C3",
                    label="unidentifiable")
    ax.set_xlabel("index [count]")
    ax.set_ylabel("singular value [1] (scaled J)")
    ax.legend(fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    return _png(fig)


def _change(p):
    try:
        return float(p["identified"]) - float(p["nominal"])
    except (KeyError, TypeError, ValueError):
        return None


def _null_basis(report) -> tuple[list[str], np.ndarray] | None:
    """Orthonormal basis of the unidentifiable directions, rows named by parameter (SI)."""
    cov = report.get("covariance")
    if not isinstance(cov, Mapping):
        return None
    wf = cov.get("with_frames")
    if isinstance(wf, Mapping) and wf.get("null_space") is not None:
        names, N = wf["parameters"], wf["null_space"]
    elif cov.get("null_space") is not None:
        names, N = cov["parameters"], cov["null_space"]
    else:
        return None
    N = np.asarray(N, float)
    if N.ndim != 2 or N.shape[1] == 0:
        return list(names), np.zeros((len(names), 0))
    U, s, _ = np.linalg.svd(N, full_matrices=False)
    return list(names), U[:, s > 1e-12 * max(float(s.max(initial=0.0)), 1e-300)]


def gauge_parameters(report) -> set[str]:
    """Parameters that are not identifiable one by one (their unit vector has a sizeable
    component in the report's null space).

    Parameters
    ----------
    report : mapping
        A calibration report with ``covariance.null_space`` (and, for the measurement frames,
        ``covariance.with_frames.null_space``).

    Returns
    -------
    set of str
        Names of the parameters whose change depends on the gauge (the machine file's values
        along the unidentifiable directions); empty when the report has no null space.
    """
    basis = _null_basis(report)
    if basis is None:
        return set()
    names, Q = basis
    share = np.linalg.norm(Q, axis=1) if Q.size else np.zeros(len(names))
    return {n for n, v in zip(names, share, strict=True) if v > GAUGE_SHARE}


def _covariance(report) -> tuple[list[str], np.ndarray] | None:
    cov = report.get("covariance")
    if not isinstance(cov, Mapping):
        return None
    wf = cov.get("with_frames")
    src = wf if isinstance(wf, Mapping) else cov
    return list(src["parameters"]), np.asarray(src["matrix"], float)


def _si_factor(unit: str) -> float:
    """File length unit -> metres."""
    return {"mm": 1e-3, "m": 1.0, "um": 1e-6}.get(unit, float("nan"))


def _combinations(report) -> list[dict]:
    """Identifiable combinations named in the report (Delta: db - da per leg), per component,
    with their standard deviation from the covariance and whether the null space touches them."""
    combos = report.get("identifiable_combinations")
    if not isinstance(combos, Mapping):
        return []
    unit = (report.get("units") or {}).get("length", "")
    f = _si_factor(unit)
    cov = _covariance(report)
    basis = _null_basis(report)
    out = []
    for key, value in combos.items():
        m = re.fullmatch(r"\s*(\S+)\s*-\s*(\S+)\s*", key)
        if not (m and isinstance(value, list) and all(_is_number(v) for v in value)):
            continue
        plus, minus = m.groups()
        for axis, v in zip(_AXES, value, strict=False):
            row = {"name": f"{plus}.{axis} - {minus}.{axis}", "value": float(v), "unit": unit,
                   "std": None, "gauge": False}
            a, b = f"{plus}.{axis}", f"{minus}.{axis}"
            if cov is not None and a in cov[0] and b in cov[0]:
                names, C = cov
                c = np.zeros(len(names))
                c[names.index(a)], c[names.index(b)] = 1.0, -1.0
                var = float(c @ C @ c)
                row["std"] = float(np.sqrt(max(var, 0.0)) / f) if np.isfinite(f) else None
            if basis is not None and basis[1].size and a in basis[0] and b in basis[0]:
                names, Q = basis
                c = np.zeros(len(names))
                c[names.index(a)], c[names.index(b)] = 1.0, -1.0
                row["gauge"] = bool(np.linalg.norm(Q.T @ c) / np.sqrt(2) > GAUGE_SHARE)
            out.append(row)
    return out


def _split_name(name: str) -> tuple[str, str]:
    """``(panel, label)`` of a parameter: the chain, leg or frame, and the rest; a file's
    instrument unknowns (``bar.csv:setup1.pivot.x``) keep their file name whole."""
    head, _, rest = name.rpartition(":")
    if "." not in rest:
        return (head or rest), rest
    group, label = rest.split(".", 1)
    return (f"{head}:{group}" if head else group), label


def _group(name: str) -> str:
    return _split_name(name)[0]


def _change_plot(params, gauge: set[str]) -> str:
    """change / std per parameter, one horizontal panel per chain / leg / frame."""
    plt = _plt()
    groups: dict[str, list] = {}
    for p in params:
        groups.setdefault(_group(p["name"]), []).append(p)
    # groups of fixed parameters only (e.g. the link length when not estimated): no panel
    groups = {g: ps for g, ps in groups.items() if any(p.get("std") is not None for p in ps)}
    if not groups:
        return ""
    names = list(groups)
    ncol = min(3, len(names))
    nrow = -(-len(names) // ncol)
    per = max(len(g) for g in groups.values())
    fig, axes = plt.subplots(nrow, ncol, figsize=(11, nrow * (0.6 + 0.26 * per)),
                             squeeze=False, layout="constrained")
    for ax in axes.flat[len(names):]:
        ax.set_visible(False)
    for ax, g in zip(axes.flat, names, strict=False):
        ps = groups[g]
        y = np.arange(len(ps))[::-1]
        z = []
        for p in ps:
            ch, std = _change(p), p.get("std")
            ok = p["name"] not in gauge and ch is not None and std and std > 0
            z.append(ch / std if ok else np.nan)
        z = np.asarray(z, float)
        colors = np.where(np.abs(np.nan_to_num(z)) > SIGNIFICANT, "C3", "C0")
        ax.barh(y, np.nan_to_num(z), color=colors, height=0.7)
        for yi, zi, p in zip(y, z, ps, strict=True):
            if not np.isfinite(zi):
                why = "not identifiable alone" if p["name"] in gauge else "fixed / no std"
                ax.text(0.02, yi, why, transform=ax.get_yaxis_transform(), va="center",
                        fontsize=8, color="#666", style="italic",
                        bbox={"facecolor": "white", "edgecolor": "none", "pad": 0.5})
        ax.axvline(SIGNIFICANT, color="k", lw=0.6, ls=":")
        ax.axvline(-SIGNIFICANT, color="k", lw=0.6, ls=":")
        ax.axvline(0, color="k", lw=0.6)
        ax.set_yticks(y, [_split_name(p["name"])[1] for p in ps], fontsize=9)
        ax.set_ylabel("parameter", fontsize=9)
        ax.set_ylim(-0.7, per - 0.3)
        ax.set_title(g, fontsize=10)
        ax.tick_params(axis="x", labelsize=8)
        ax.set_xlabel("change / std [1]", fontsize=9)
        ax.grid(True, axis="x", alpha=0.3)
    fig.suptitle("identified - nominal in standard deviations (|.| > 3: significant; grey: "
                 "not identifiable alone, see the combinations)", fontsize=10)
    return _png(fig)


def _parameters_table(params, gauge: set[str]) -> str:
    head = ("<tr><th>parameter</th><th>unit</th><th>nominal</th><th>identified</th>"
            "<th>change</th><th>std</th><th>change / std [1]</th><th>note</th></tr>")
    rows = []
    for p in params:
        ch, std = _change(p), p.get("std")
        undetermined = p["name"] in gauge
        z = ch / std if (ch is not None and std and not undetermined) else None
        flag = " bad" if (z is not None and abs(z) > SIGNIFICANT) else ""
        note = ("not identifiable alone" if undetermined else ("fixed" if std is None else ""))
        cls = ' class="num"'
        std_cell = ('<td class="num gauge">-</td><td class="num gauge">-</td>' if undetermined
                    else f'<td{cls}>{_e(_num(std))}</td><td class="num{flag}">{_e(_num(z))}</td>')
        rows.append(
            f"<tr><td>{_e(p['name'])}</td><td>{_e(p.get('unit', ''))}</td>"
            f"<td{cls}>{_e(_config(p.get('nominal')))}</td>"
            f"<td{cls}>{_e(_config(p.get('identified')))}</td>"
            f"<td{cls}>{_e(_num(ch))}</td>{std_cell}"
            f"<td class=small>{_e(note)}</td></tr>")
    return f"<table>{head}{''.join(rows)}</table>"


def _si_of(p: Mapping) -> float:
    """A parameter's file unit -> SI."""
    from ..units import ANGLE, LENGTH

    unit = p.get("unit", "")
    return {"length": LENGTH, "angle": ANGLE}.get(p.get("kind", ""), {}).get(unit, 1.0)


def gauge_fixed(report) -> tuple[list[str], list[dict]] | None:
    """Identifiable combinations wherever single parameters are not, for any machine: the
    unidentifiable directions (k of them) only choose a frame or a common offset, so holding k
    parameters at the machine file's values (the pivots of the null space: the parameters
    those directions move most independently) determines every other one. Returns the held
    parameters and, per other parameter the null space moves, its change from the machine
    file with those held and its standard deviation (``T C T^T`` with ``T`` the projection
    that restores the held values); None when there is no null space or covariance.

    Parameters
    ----------
    report : mapping
        A calibration report (``covariance`` with ``null_space``, ``parameters``).

    Returns
    -------
    tuple or None
        ``(held names, rows)``; a row: ``name``, ``unit``, ``change``, ``std`` (file units).
    """
    from scipy.linalg import qr

    basis, cov = _null_basis(report), _covariance(report)
    if basis is None or cov is None or basis[1].size == 0 or basis[0] != cov[0]:
        return None
    names, Q = basis
    C = cov[1]
    params = {p["name"]: p for p in report.get("parameters") or []}
    if not all(n in params and _is_number(params[n].get("nominal"))
               and _is_number(params[n].get("identified")) for n in names):
        return None
    k = Q.shape[1]
    # pivots on the null space with lengths per characteristic length (angles as they are)
    L = max([abs(float(params[n]["nominal"]) * _si_of(params[n])) for n in names
             if params[n].get("kind") == "length"] + [1.0])
    w = np.array([1.0 / L if params[n].get("kind") == "length" else 1.0 for n in names])
    _, _, piv = qr((Q * w[:, None]).T, pivoting=True)
    held = list(piv[:k])
    QF = Q[held]
    if np.linalg.cond(QF) > 1e10:
        return None
    si = np.array([_si_of(params[n]) for n in names])
    nominal = np.array([float(params[n]["nominal"]) for n in names]) * si
    identified = np.array([float(params[n]["identified"]) for n in names]) * si
    a = np.linalg.solve(QF, nominal[held] - identified[held])
    fixed = identified + Q @ a
    E = np.zeros((k, len(names)))
    E[np.arange(k), held] = 1.0
    T = np.eye(len(names)) - Q @ np.linalg.solve(QF, E)
    std = np.sqrt(np.clip(np.diag(T @ C @ T.T), 0.0, None))
    moved = np.linalg.norm(Q, axis=1) > GAUGE_SHARE
    rows = [{"name": n, "unit": params[n].get("unit", ""),
             "change": float((fixed[i] - nominal[i]) / si[i]), "std": float(std[i] / si[i])}
            for i, n in enumerate(names) if moved[i] and i not in held
            and params[n].get("std") is not None]
    return [names[i] for i in held], rows


def _gauge_fixed_table(report) -> str:
    fixed = gauge_fixed(report)
    if fixed is None or not fixed[1]:
        return ""
    held, rows = fixed
    body = []
    for r in rows:
        z = r["change"] / r["std"] if r["std"] > 0 else None
        flag = " bad" if (z is not None and abs(z) > SIGNIFICANT) else ""
        body.append(f"<tr><td>{_e(r['name'])}</td><td>{_e(r['unit'])}</td>"
                    f"<td class=num>{_e(_num(r['change']))}</td>"
                    f"<td class=num>{_e(_num(r['std']))}</td>"
                    f'<td class="num{flag}">{_e(_num(z))}</td></tr>')
    return ("<p>The data fix these parameters only together: holding "
            f"<b>{_e(', '.join(held))}</b> at the machine file's values (they choose the "
            "frame or offset the data cannot see) determines each of the others, with the "
            "change and standard deviation below.</p>"
            "<table><tr><th>parameter (with those held)</th><th>unit</th><th>change</th>"
            "<th>std</th><th>change / std [1]</th></tr>" + "".join(body) + "</table>")


def _combinations_section(report) -> str:
    combos = _combinations(report)
    generic = _gauge_fixed_table(report)
    if not combos:
        return ("<h2>Identifiable combinations</h2>" + generic) if generic else ""
    desc = (report.get("identifiable_combinations") or {}).get("description", "")
    rows = []
    for c in combos:
        z = c["value"] / c["std"] if c["std"] else None
        flag = " bad" if (z is not None and abs(z) > SIGNIFICANT) else ""
        note = ("up to the common offset named above (moved by an unidentifiable direction)"
                if c["gauge"] else "")
        rows.append(f"<tr><td>{_e(c['name'])}</td><td>{_e(c['unit'])}</td>"
                    f"<td class=num>{_e(_num(c['value']))}</td>"
                    f"<td class=num>{_e(_num(c['std']))}</td>"
                    f'<td class="num{flag}">{_e(_num(z))}</td>'
                    f"<td class=small>{_e(note)}</td></tr>")
    return ("<h2>Identifiable combinations</h2>"
            f"<p>{_e(desc)}. The parameters these combine are not identifiable one by one "
            "(their std is shown as '-'); the combinations are, with the standard deviations "
            "below (from the covariance). The change is from the machine file's values "
            "(zero).</p>"
            "<table><tr><th>combination</th><th>unit</th><th>change</th><th>std</th>"
            "<th>change / std [1]</th><th>note</th></tr>" + "".join(rows) + "</table>"
            + generic)


def _before_after(res: Mapping) -> str:
    """Rows 'quantity | before | after | unit' from a residuals section, when it has both."""
    rows = []
    if "before_rms_um" in res and "rms_um" in res:
        rows.append(("RMS residual", res["before_rms_um"], res["rms_um"], "um", "rms_um"))
    b, a = res.get("before_calibration"), res.get("after_calibration")
    unit = res.get("unit", "") if isinstance(res.get("unit", ""), str) else ""
    if isinstance(b, Mapping) and isinstance(a, Mapping):
        for k in b:
            if k in a and not isinstance(b[k], Mapping):
                label, u = _label_unit(k, unit)
                rows.append((label, b[k], a[k], u, k))
    if not rows:
        return ""
    body = "".join(f"<tr><td>{_e(label)}</td><td class=num>{_e(_value_text(k, x))}</td>"
                   f"<td class=num>{_e(_value_text(k, y))}</td><td class=unit>{_e(u)}</td>"
                   "</tr>" for label, x, y, u, k in rows)
    note = _e(res.get("before", ""))
    return (f"<h2>Before / after calibration</h2><p class=small>before: {note}</p>"
            "<table><tr><th>quantity</th><th>before</th><th>after</th><th>unit</th></tr>"
            f"{body}</table>")


def _ratio_plot(ratio) -> str:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.5, 3.2), layout="constrained")
    labels = [k for k in ("before", "after", "after_two_step") if isinstance(ratio.get(k), dict)]
    for i, k in enumerate(labels):
        st = ratio[k]
        ax.errorbar([i], [st["mean"]], yerr=[[st["mean"] - st["min"]], [st["max"] - st["mean"]]],
                    fmt="o", capsize=6, label=f"{k}: std {st['std']:.3g} %")
    ax.axhline(100, color="k", lw=0.6)
    ax.set_xticks(range(len(labels)))
    ax.set_xticklabels(labels)
    ax.set_xlabel("model (before / after calibration)")
    ax.set_ylabel("distance ratio [%] (mean, range)")
    ax.legend(fontsize=9)
    return _png(fig)


def _instrument_sections(report) -> str:
    """Sections of the newer kinds: the files of a joint fit and what each adds, and the
    parameters the data determine poorly (with what to measure next)."""
    parts = []
    files = report.get("files")
    if isinstance(files, list) and files:
        rows = "".join(
            f"<tr><td>{_e(f.get('label', f.get('file')))}</td><td>{_e(f.get('measurement'))}"
            f"</td><td>{_e(f.get('measurements'))}</td><td>{_e(f.get('noise', ''))}</td>"
            f"<td>{_num((f.get('residuals') or {}).get('before_rms_um'))}</td>"
            f"<td>{_num((f.get('residuals') or {}).get('rms_um'))}</td></tr>"
            for f in files if isinstance(f, Mapping))
        parts.append("<h2>Files fitted together</h2><table><tr><th>file</th><th>kind</th>"
                     "<th>rows</th><th>noise</th><th>RMS before (um)</th><th>RMS after (um)"
                     f"</th></tr>{rows}</table>")
    contributions = report.get("contributions")
    if isinstance(contributions, Mapping) and contributions.get("summary"):
        summary = contributions["summary"]
        lines = summary if isinstance(summary, list) else [summary]
        parts.append("<h2>What each file adds</h2><ul>"
                     + "".join(f"<li>{_e(line)}</li>" for line in lines) + "</ul>")
    poor = report.get("poorly_determined")
    if isinstance(poor, Mapping) and poor.get("parameters"):
        from ..units import ANGLE

        units = report.get("units") or {}
        angle = units.get("angle", "deg")

        def std_unit(q):
            # lengths in the file's unit; angles stored in rad, shown in the file's unit
            if q.get("kind") == "angle" and _is_number(q.get("std")):
                return _num(q["std"] / ANGLE.get(angle, 1.0)), angle
            if q.get("kind") == "length":
                return _num(q.get("std")), units.get("length", "")
            return _num(q.get("std")), "1"

        rows = "".join(
            f"<tr><td>{_e(q.get('name'))}</td><td class=num>{_e(std_unit(q)[0])}</td>"
            f"<td>{_e(std_unit(q)[1])}</td>"
            f"<td>{_e(q.get('correlated_with') or '')}</td><td class=num>"
            f"{_num(q.get('correlation'))}</td></tr>"
            for q in poor["parameters"] if isinstance(q, Mapping))
        rule = (f" Poorly determined, by the rule of every calibration: {_e(poor['rule'])}"
                + (f", {_num(poor['threshold_mm'])} mm on this machine"
                   if _is_number(poor.get("threshold_mm")) else "") + "."
                if isinstance(poor.get("rule"), str) else "")
        parts.append("<h2>Poorly determined</h2><p>Determined by these data only to the "
                     "standard deviations below; to fix them, measure "
                     f"{_e(poor.get('measure_next', ''))}.{rule}</p>"
                     "<table><tr><th>parameter</th><th>std</th><th>unit</th><th>most "
                     f"correlated with</th><th>correlation [1]</th></tr>{rows}</table>")
    return "".join(parts)


#: reports written before the results had typed sections (no ``sections`` index): their
#: instrument keys, shown the same way
_UNINDEXED_KEYS = ("link_length", "registration", "frames", "setups", "bed")


def _list_table(items: list) -> str:
    """A table of a list of flat records (one row each, one column per key)."""
    records = [r for r in items if isinstance(r, Mapping)]
    columns = list(dict.fromkeys(k for r in records for k in r))
    head = "".join(f"<th>{_e(c)}</th>" for c in columns)

    def cell(c, v) -> str:
        if isinstance(v, list):
            return ", ".join(_num(x) for x in v)
        return "" if v is None else _value_text(c, v)

    body = "".join("<tr>" + "".join(f"<td>{_e(cell(c, r.get(c)))}</td>" for c in columns)
                   + "</tr>" for r in records)
    return f"<table><tr>{head}</tr>{body}</table>"


def _result_sections(report) -> list[str]:
    """Each instrument's typed section of the result (``report["sections"]``: its title,
    summary rows and report keys), rendered the same way whatever the instrument."""
    index = report.get("sections")
    if not isinstance(index, Mapping):
        index = {k: {"title": k.replace("_", " "), "keys": [k], "summary": []}
                 for k in _UNINDEXED_KEYS if k in report}
    out = []
    for name, entry in index.items():
        if not isinstance(entry, Mapping):
            continue
        rows = [r for r in entry.get("summary") or [] if isinstance(r, list) and len(r) == 2]
        parts = []
        if rows:
            parts.append("<table>" + "".join(f"<tr><th>{_e(label)}</th><td>{_e(text)}</td></tr>"
                                             for label, text in rows) + "</table>")
        keys = [k for k in entry.get("keys") or [] if isinstance(k, str) and k in report]
        for key in keys:
            value = report[key]
            head = f"<h3>{_e(key.replace('_', ' '))}</h3>" if len(keys) > 1 else ""
            if isinstance(value, Mapping):
                parts.append(head + _kv_table(list(_rows(value))))
            elif isinstance(value, list) and value and all(isinstance(v, Mapping)
                                                           for v in value):
                parts.append(head + _list_table(value))
            elif value is not None:
                label, unit = _label_unit(key)
                parts.append(_kv_table([(label, _value_text(key, value), unit,
                                         _is_number(value))]))
        if parts:
            out.append(f"<h2>{_e(entry.get('title') or name)}</h2>" + "".join(parts))
    return out


def _summary_rows(report, conv):
    keys = ("machine_file", "data_file", "calibrated_file", "measurement", "method",
            "measurements", "used", "date", "reading_unit", "noise", "noise_sigma_um",
            "smr_offset", "dropped_rows", "outlier_rows")
    units = (report.get("units") or {}).get("length", "")
    for k in keys:
        if k not in report:
            continue
        v = report[k]
        if isinstance(v, Mapping):
            yield from _rows(v, f"{k}: ", units)
            continue
        label, u = _label_unit(k, units)
        if k == "noise_sigma_um":
            label = "assumed noise std"
        if k in ("dropped_rows", "outlier_rows"):
            u = "file rows"
        yield label, _value_text(k, v), u, _is_number(v)
    for k, v in conv.items():
        if k != "success":
            label, u = _label_unit(k)
            yield f"convergence: {label}", _value_text(k, v), u, _is_number(v)


#: lengths of the model-adequacy groups shown in um (one unit for residuals on the page)
_TO_UM = {"m": 1e6, "mm": 1e3, "um": 1.0}


def _adequacy_section(adequacy: Mapping) -> str:
    """The model-adequacy checks: a table per residual group (RMS, assumed and used noise in
    one unit), the trend tests' findings in words (the verdict itself is stated once, under
    Residuals)."""
    from ..estimation.acceptance import VERDICT_WORDS

    parts = ["<h2>Model adequacy</h2>"]
    groups = [g for g in adequacy.get("groups") or [] if isinstance(g, Mapping)]

    def size(g, key):
        f = _TO_UM.get(g.get("unit", ""))
        v = g.get(key)
        if not _is_number(v):
            return "-"
        return _num(float(v) * f) if f else _num(v)

    def unit(g):
        return "um" if g.get("unit", "") in _TO_UM else g.get("unit", "")

    if groups:
        rows = "".join(
            f"<tr><td>{_e(g.get('name'))}</td><td class=num>{_e(size(g, 'rms'))}</td>"
            f"<td class=num>{_e(size(g, 'assumed'))}</td><td class=num>{_e(size(g, 'used'))}"
            f"</td><td>{_e(unit(g))}</td><td class=num>{_e(g.get('count', '-'))}</td></tr>"
            for g in groups)
        parts.append("<table><tr><th>residual group</th><th>RMS residual</th><th>assumed "
                     "noise</th><th>noise used in the fit</th><th>unit</th><th>residuals "
                     "[count]</th></tr>" + rows + "</table>")
    columns = [c for c in adequacy.get("columns") or [] if isinstance(c, Mapping)]
    if columns and len(groups) <= 1:
        rows = "".join(f"<tr><td>{_e(c.get('name'))}</td><td class=num>{_e(size(c, 'rms'))}"
                       f"</td><td>{_e(unit(c))}</td></tr>" for c in columns)
        parts.append("<table><tr><th>residual column</th><th>RMS residual</th><th>unit</th>"
                     "</tr>" + rows + "</table>")
    kv = []
    if _is_number(adequacy.get("noise_ratio")):
        kv.append(("noise ratio (residuals over the assumed noise)",
                   _num(adequacy["noise_ratio"]), "x assumed noise std", True))
    verdict = adequacy.get("residual_verdict")
    if verdict in VERDICT_WORDS:
        kv.append(("residual test", VERDICT_WORDS[verdict], "", False))
    for key, label, what in (("significant_trends", "significant trends", "trends"),
                             ("tests", "trend tests", "tests"), ("alpha", "significance level",
                                                                 "probability")):
        if _is_number(adequacy.get(key)):
            kv.append((label, _num(adequacy[key]), what, True))
    for key in ("method", "findings"):
        if isinstance(adequacy.get(key), str):
            kv.append((key, adequacy[key], "", False))
    if kv:
        parts.append(_kv_table(kv))
    trends = [t for t in adequacy.get("trends") or [] if isinstance(t, Mapping)]
    if trends:
        parts.append("<p>Trends:</p><ul>" + "".join(
            f"<li>{_e(_value_text('trend', [t]))}</li>" for t in trends) + "</ul>")
    return "".join(parts)


def _noise_section(report) -> str:
    """The noise levels (assumed, estimated), the outlier rows and the model checks."""
    out = []
    levels = report.get("noise_model")
    if isinstance(levels, Mapping) and isinstance(levels.get("groups"), list):
        rows = "".join(
            f"<tr><td>{_e(g.get('name'))}</td><td>{_e(_num(g.get('assumed')))}</td>"
            f"<td>{_e(_num(g.get('sigma')))}"
            + (f" &plusmn; {_e(_num(g.get('std')))}" if g.get("std") is not None else "")
            + f"</td><td>{_e(g.get('unit'))}</td><td>{_e(_num(g.get('ratio')))}</td>"
            f"<td>{_e(g.get('status'))}</td><td>{_e(_num(g.get('redundancy')))}</td>"
            f"<td>{_e(_num(g.get('capacity')))}</td></tr>"
            for g in levels["groups"] if isinstance(g, Mapping))
        out.append("<h2>Noise levels</h2><p class=small>" + _e(levels.get("method", ""))
                   + ". Estimated where the data can check them (capacity, the group's "
                   "redundancy were its level far above the others', at least "
                   + _e(_num(levels.get("min_redundancy"))) + "); held where given.</p>"
                   "<table><tr><th>group</th><th>assumed</th><th>used</th><th>unit</th>"
                   "<th>used / assumed [1]</th><th>status</th><th>redundancy [count]</th>"
                   "<th>capacity [count]</th></tr>"
                   + rows + "</table>")
    outliers = report.get("outliers")
    if isinstance(outliers, Mapping) and outliers.get("flagged"):
        rows = "".join(f"<tr><td>{_e(f.get('row'))}</td><td>{_e(_num(f.get('statistic')))}"
                       f"</td><td>{_e(f.get('dof'))}</td><td>{_e(_num(f.get('p')))}</td>"
                       f"<td>{'yes' if f.get('left_out') else 'no'}</td></tr>"
                       for f in outliers["flagged"] if isinstance(f, Mapping))
        out.append("<h2>Outlier rows</h2><p class=small>" + _e(outliers.get("test", ""))
                   + f"; p below {_e(_num(outliers.get('threshold_p')))}.</p><table><tr>"
                   "<th>row</th><th>statistic [1]</th><th>dof [count]</th><th>p [1]</th>"
                   "<th>left out</th>"
                   "</tr>" + rows + "</table>")
    adequacy = report.get("model_adequacy")
    if isinstance(adequacy, Mapping):
        out.append(_adequacy_section(adequacy))
    extensions = report.get("model_extensions")
    if isinstance(extensions, Mapping) and isinstance(extensions.get("trials"), list):
        # what was tried, judged on held-out rows: the loss with and without, and the verdict
        rows = "".join(
            f"<tr><td>{_e(t.get('name'))}</td><td>{_e(t.get('description', ''))}</td>"
            f"<td>{_e(_num(t.get('cv_loss_baseline')))}</td><td>{_e(_num(t.get('cv_loss')))}"
            f"</td><td>{_e(_num(t.get('cv_gain')))} &plusmn; {_e(_num(t.get('cv_se')))}</td>"
            f"<td>{'yes' if t.get('adopted') else 'no'}</td><td>{_e(t.get('why', ''))}</td>"
            "</tr>" for t in extensions["trials"] if isinstance(t, Mapping))
        out.append("<h2>Model extensions</h2><p class=small>"
                   + _e(extensions.get("criterion", "")) + ".</p><table><tr><th>extension</th>"
                   "<th>what</th><th>held-out loss, plain model [whitened SS per row]</th>"
                   "<th>with it [whitened SS per row]</th><th>gain [whitened SS per row]</th>"
                   "<th>adopted</th><th>why</th></tr>" + rows + "</table>")
    return "".join(out)


_VERDICT_CLASS = {"passed": "passed", "not-tested": "untested", "failed-small": "untested"}


def _answer_section(report) -> str:
    """The answer first (issue 36): the residual test's verdict (never "converged" above a
    failed test), the accuracy before and after, what changed, the next commands, and the
    pictures (the bed maps of a printer, the workspace's error of other machines)."""
    from ..estimation.acceptance import VERDICT_WORDS, report_verdict

    verdict = report_verdict(report)
    outcome = report.get("outcome") if isinstance(report.get("outcome"), Mapping) else None
    cls = _VERDICT_CLASS.get(verdict.status, "failed")
    head = (outcome["verdict"]["headline"] if outcome else
            f"Calibration {VERDICT_WORDS[verdict.status]}: {verdict.sentence().split(': ', 1)[-1]}")
    parts = ["<section id=answer>",
             f"<p class='answer {cls}' id=verdict>{_e(head)}.</p>"]
    if outcome is None:
        return "".join(parts) + "</section>"
    acc = outcome.get("accuracy") or {}
    b, a = acc.get("before") or {}, acc.get("after") or {}
    held = outcome.get("held_out_rows") or {}
    held_rows = held.get("files") or ([held] if held else [])
    unit, f = accuracy_unit(b.get("rms"), b.get("max"), a.get("rms"), a.get("max"),
                            *[h.get("before_rms") for h in held_rows],
                            *[h.get("after_rms") for h in held_rows])
    rows = []
    what = ""
    if b.get("rms") is not None or a.get("rms") is not None:
        what = f"{acc.get('quantity')} over {acc.get('where')}, predicted"
        rows.append(("RMS", b.get("rms"), a.get("rms")))
        rows.append(("largest", b.get("max"), a.get("max")))
        if b.get("lowest") is not None:
            rows.append(("range with the values in force (lowest .. highest)",
                         None, None, f"{length_text(b['lowest'], unit, f, True)} .. "
                                     f"{length_text(b['highest'], unit, f, True)}"))
    for h in held_rows:
        rows.append((f"held-out rows ({h.get('rows')}, not in the fit): RMS residual of the "
                     "measurements", h.get("before_rms"), h.get("after_rms")))
    body = []
    for row in rows:
        if len(row) == 4:
            body.append(f"<tr><th>{_e(row[0])}</th><td class=num colspan=2>{_e(row[3])}</td>"
                        "</tr>")
            continue
        label, x, y = row
        body.append(f"<tr><th>{_e(label)}</th>"
                    f"<td class=num>{_e(number(None if x is None else x * f))}</td>"
                    f"<td class=num>{_e(number(None if y is None else y * f))}</td></tr>")
    if body:
        note = ("before: where the machine file's values put the tool against where the "
                "calibrated model says it goes"
                + (f" (known to +- {length_text(b['std'], unit, f)}, the calibrated model's "
                   "uncertainty)" if b.get("std") is not None else "")
                + "; after: the calibrated values' own uncertainty (1 sigma, from the "
                "parameters' covariance)" + (f"; {acc['aligned']}" if acc.get("aligned")
                                             else ""))
        parts.append("<table id=accuracy>"
                     + (f"<caption style='text-align:left'><b>Accuracy</b>: {_e(what)}"
                        "</caption>" if what else "")
                     + "<tr><th>accuracy</th><th>with the machine file's "
                     f"values (before) [{unit}]</th><th>calibrated (after) [{unit}]</th></tr>"
                     + "".join(body) + f"</table><p class=small>{_e(note)}.</p>")
    elif acc.get("why"):
        parts.append(f"<p>{_e(acc['why'])}</p>")
    for label, text in answer_rows(outcome):
        if label == "what changed":
            parts.append(f"<p><b>What changed:</b> {_e(text)}.</p>")
    steps = outcome.get("next") or []
    if steps:
        parts.append("<p><b>Next:</b></p><pre class=next>" + "\n".join(
            f"{_e(st['command'])}\n    # {_e(st['why'])}" for st in steps) + "</pre>")
    firmware = outcome.get("firmware") or []
    if firmware:
        fw = "".join(
            f"<tr><td>{_e(c['name'])}</td><td class=num>{_e(_config(c['before']))}</td>"
            f"<td class=num>{_e(_config(c['after']))}</td><td>{_e(c['unit'])}</td>"
            f"<td class=num>{_e(number(c['change'], sign=True))}</td></tr>"
            for c in firmware)
        parts.append("<p><b>Firmware values</b> (as the configuration holds them, per "
                     "stepper):</p><table><tr><th>value</th><th>in force</th><th>new</th>"
                     "<th>unit</th><th>change</th></tr>"
                     + fw + "</table>")
    pmap = outcome.get("map")
    if isinstance(pmap, Mapping):
        from .maps import bed_maps, measured_points, workspace_maps

        if pmap.get("kind") == "bed":
            parts.append("<h2>The bed</h2><p class=small>Seen from above, as bed-mesh views "
                         "show it: the nozzle's height error over the print disk predicted "
                         "with the values in force and the uncertainty with the new values, "
                         "on one colour scale; the probe points coloured by their residuals "
                         "(measured - predicted height).</p>" + _png(bed_maps(pmap)))
        else:
            parts.append("<h2>Error over the workspace</h2><p class=small>Seen from above: "
                         "the position error of the machine file's model and the "
                         "calibrated model's uncertainty (1 sigma), one colour scale.</p>"
                         + _png(workspace_maps(pmap)))
            fig = measured_points(pmap)
            if fig is not None:
                parts.append("<p class=small>At each measured point: how far the machine "
                             "file's model puts the tool from where the calibrated model "
                             "does for that row's readings, and the calibrated model's "
                             "uncertainty there.</p>" + _png(fig))
    return "".join(parts) + "</section>"


def _details_rows(report, conv):
    """The internals: files, method, convergence in words."""
    files = [f for f in report.get("files") or [] if isinstance(f, Mapping)]
    for row in _summary_rows(report, {}):
        if files and row[0] == "measurement":
            row = ("measurement", ", ".join(f"{f.get('measurement')} ({f.get('label')})"
                                            for f in files), "", False)
        elif files and row[0] == "method":
            row = ("method", "one fit of every file: one geometry, each file's own "
                             "instrument unknowns", "", False)
        yield row
    if conv:
        words = f"{conv.get('message', '')}".strip() or ("converged" if conv.get("success")
                                                          else "not converged")
        yield "convergence", words, "", False
        if conv.get("iterations") is not None:
            yield "iterations", str(conv["iterations"]), "iterations", True
        if conv.get("evaluations") is not None:
            yield "model evaluations", str(conv["evaluations"]), "evaluations", True


def build_html(report: Mapping, title: str | None = None) -> str:
    """The HTML text of a calibration report.

    Parameters
    ----------
    report : mapping
        The JSON report ``pkmcal calibrate`` writes (sections are shown when present).
    title : str, optional
        Page title; default names the calibrated file.

    Returns
    -------
    str
        A self-contained HTML document (inline styles, plots as embedded PNG).
    """
    title = title or f"pkmcal calibration report: {report.get('calibrated_file') or ''}"
    parts = [f"<h1>{_e(title)}</h1>", _answer_section(report)]
    conv = report.get("convergence", {}) or {}
    details = ["<div id=details></div><h2>Details</h2>"
               + _kv_table(list(_details_rows(report, conv)))]
    ident = report.get("identifiability") or {}
    if ident:
        rank, n = ident.get("identifiable"), ident.get("free_parameters")
        items = "".join(f"<li><b>{_e(d.get('dimension'))} x {_e(d.get('name'))}</b>: "
                        f"{_e(d.get('description', ''))}</li>"
                        for d in ident.get("unidentifiable", []))
        weak = "".join(f"<li><b>{_e(d.get('name'))}</b>: {_e(d.get('description', ''))}</li>"
                       for d in ident.get("weakly_identifiable", []) or [])
        details.append(f"<h2>Identifiability</h2><p>{_e(rank)} of {_e(n)} free parameter "
                     f"directions identified; condition number "
                     f"{_e(_num(ident.get('condition_number')))} (scaled Jacobian).</p>"
                     + (f"<p>Not identifiable from these data:</p><ul>{items}</ul>"
                        if items else "")
                     + (f"<p>Weakly identifiable (counted above, left at the machine file's "
                        f"values):</p><ul>{weak}</ul>" if weak else ""))
        if ident.get("singular_values"):
            details.append(_singular_plot(ident["singular_values"], int(rank or 0)))
    res = report.get("residuals") or {}
    if res:
        unit = res.get("unit", "") if isinstance(res.get("unit", ""), str) else ""
        parts.append("<h2>Residuals</h2>" + _kv_table(list(_rows(
            {k: v for k, v in res.items() if k not in ("before_calibration",
                                                       "after_calibration")}, "", unit))))
        st = _standardised(report)
        text = verdict_html(report)
        if st is not None and st[0].size:
            scale, over = _assumed_scale(report)
            parts.append(
                "<div class=side><div>" + _residual_plot(*st, scale, over) + "</div><div>"
                "<p><b>Standardised residuals</b> ("
                + _e(st[1]) + f"), each {_e(over)}: N(0, 1) for a correct fit with "
                "that noise. The fit absorbs part of every residual (the poses and the "
                "identified parameters): raw residual / assumed std would look too narrow for "
                "a correct fit.</p>" + text + "</div></div>")
        else:
            parts.append(text)
        parts.append(_before_after(res))
    details.append(_noise_section(report))
    ratio = report.get("distance_ratio")
    if isinstance(ratio, Mapping) and isinstance(ratio.get("before"), Mapping):
        parts.append("<h2>Distance ratios (seed 001 Fig. 6)</h2>"
                     f"<p>{_e(ratio.get('pairs'))} pairs ({_e(ratio.get('pairs_from', ''))});"
                     " FK distance / tracker distance x 100 %, independent of frames.</p>"
                     + _kv_table([(f"{k}: {s}", f"{v:.3f}" if _is_number(v) else "-",
                                   "%", True)
                                  for k in ("before", "after", "after_two_step")
                                  if isinstance(ratio.get(k), Mapping)
                                  for s, v in ratio[k].items()])
                     + _ratio_plot(ratio))
    validation = report.get("validation")
    if isinstance(validation, Mapping):
        parts.append("<h2>Held-out validation</h2>" + _kv_table(list(_rows(validation))))
    parts.append(_instrument_sections(report))
    details += _result_sections(report)
    params = report.get("parameters") or []
    gauge = gauge_parameters(report)
    parts.append(_combinations_section(report))
    if params:
        n_gauge = sum(p["name"] in gauge for p in params)
        levels = report.get("noise_model")
        how = ("with the noise levels estimated from the residuals (see Noise levels)"
               if isinstance(levels, Mapping) and levels.get("estimated")
               else "scaled by the residual variance")
        parts.append(
            "<h2>Parameters</h2><p class=small>Standard deviations from the covariance of the "
            f"estimate ({how}); unidentifiable directions keep the machine file's values."
            + (f" {n_gauge} of {len(params)} parameters lie partly along an unidentifiable "
               "direction (listed under Identifiability): each of them is not identifiable by "
               "itself, so its change shows only where the calibration put it, and its std and "
               "change/std are '-' (only combinations of them are determined"
               + ("; see Identifiable combinations" if report.get("identifiable_combinations")
                  else "") + ")." if n_gauge else "")
            + "</p>" + _change_plot(params, gauge) + _parameters_table(params, gauge))
    prov = report.get("provenance") or {}
    if prov:
        details.append("<h2>Provenance</h2>" + _kv_table(
            [(k, _value_text(k, v), "", False) for k, v in prov.items()]))
    body = "\n".join(p for p in parts + details if p)
    return (f"<!DOCTYPE html><html lang=en><head><meta charset=utf-8><title>{_e(title)}"
            f"</title><style>{STYLE}</style></head><body>{body}</body></html>\n")
