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
import io
import re
from collections.abc import Mapping

import numpy as np

from ..units import format_um

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
        return f"{v:.6g}" if np.isfinite(v) else "-"
    return str(v)


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


def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    return f'<img alt="plot" src="data:image/png;base64,{data}">'


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


def _residual_plot(r, how: str) -> str:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.2, 3.6))
    ax.hist(r, bins=min(60, max(10, r.size // 15)), density=True, alpha=0.7,
            label=f"{r.size} standardised residuals")
    lim = max(4.0, float(np.max(np.abs(r))) if r.size else 4.0)
    x = np.linspace(-lim, lim, 200)
    ax.plot(x, np.exp(-x**2 / 2) / np.sqrt(2 * np.pi), "k-", lw=1.2, label="N(0, 1)")
    ax.set_xlabel("standardised residual [1] (leverage-corrected)" if how.startswith("lev")
                  else "standardised residual [1] (dof-corrected)", fontsize=10)
    ax.set_ylabel("density [1/unit]", fontsize=10)
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
            f"<td class=num>{t.chi2:.5g}</td><td class=unit>1</td></tr>"
            f"<tr><th>degrees of freedom</th><td class=num>{t.dof}</td>"
            f"<td class=unit>count</td></tr>"
            f"<tr><th>chi2 / dof</th><td class=num>{t.ratio:.4g}</td>"
            f"<td class=unit>1</td></tr>"
            f"<tr><th>largest chi2 / dof expected (99.9 %)</th><td class=num>{t.upper:.4g}"
            f"</td><td class=unit>1</td></tr>"
            f"<tr><th>noise ratio: residuals over the assumed noise, sqrt(chi2 / dof)</th>"
            f"<td class=num>{t.noise_ratio:.4g}</td><td class=unit>1</td></tr></table>"
            f"<p class=verdict>Residual test <span class={ok}>{_e(words)}</span>: "
            f"{_e(rest)}{_e(note)}.{_e(sigma)}</p>")


def _singular_plot(s, rank) -> str:
    plt = _plt()
    s = np.asarray(s, float)
    fig, ax = plt.subplots(figsize=(6.2, 3.2))
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


def _group(name: str) -> str:
    return name.split(".", 1)[0]


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
        ax.set_yticks(y, [p["name"].split(".", 1)[-1] if "." in p["name"] else p["name"]
                          for p in ps], fontsize=9)
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
            f"<td{cls}>{_e(_num(p.get('nominal')))}</td>"
            f"<td{cls}>{_e(_num(p.get('identified')))}</td>"
            f"<td{cls}>{_e(_num(ch))}</td>{std_cell}"
            f"<td class=small>{_e(note)}</td></tr>")
    return f"<table>{head}{''.join(rows)}</table>"


def _combinations_section(report) -> str:
    combos = _combinations(report)
    if not combos:
        return ""
    desc = (report.get("identifiable_combinations") or {}).get("description", "")
    rows = []
    for c in combos:
        z = c["value"] / c["std"] if (c["std"] and not c["gauge"]) else None
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
            "<th>change / std [1]</th><th>note</th></tr>" + "".join(rows) + "</table>")


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
    fig, ax = plt.subplots(figsize=(5.5, 3.2))
    labels = [k for k in ("before", "after", "after_two_step") if isinstance(ratio.get(k), dict)]
    for i, k in enumerate(labels):
        st = ratio[k]
        ax.errorbar([i], [st["mean"]], yerr=[[st["mean"] - st["min"]], [st["max"] - st["mean"]]],
                    fmt="o", capsize=6, label=f"{k}: std {st['std']:.3g} %")
    ax.axhline(100, color="k", lw=0.6)
    ax.set_xticks(range(len(labels)))
    ax.set_xticklabels(labels)
    ax.set_ylabel("distance ratio [%] (mean, range)")
    ax.legend(fontsize=9)
    return _png(fig)


def _instrument_sections(report) -> str:
    """Sections of the newer kinds: the files of a joint fit and what each adds, ballbar
    mountings, and the parameters the data determine poorly (with what to measure next)."""
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
    setups = report.get("setups")
    if isinstance(setups, list) and setups:
        rows = "".join(
            f"<tr><td>{_e(u.get('setup'))}</td><td>{_e(u.get('rows'))}</td>"
            f"<td>{_e(', '.join(_num(v) for v in u.get('pivot', [])))}</td>"
            f"<td>{_e(', '.join(_num(v) for v in u.get('ball', [])))}</td>"
            f"<td>{_e(u.get('unit', ''))}</td></tr>" for u in setups if isinstance(u, Mapping))
        parts.append("<h2>Ballbar mountings</h2><table><tr><th>setup</th><th>rows</th>"
                     "<th>pivot (base)</th><th>ball (platform)</th><th>unit</th></tr>"
                     f"{rows}</table>")
    poor = report.get("poorly_determined")
    if isinstance(poor, Mapping) and poor.get("parameters"):
        unit = (report.get("units") or {}).get("length", "")
        rows = "".join(
            f"<tr><td>{_e(q.get('name'))}</td><td>{_num(q.get('std'))}</td>"
            f"<td>{_e(q.get('correlated_with') or '')}</td><td>{_num(q.get('correlation'))}"
            "</td></tr>" for q in poor["parameters"] if isinstance(q, Mapping))
        parts.append("<h2>Poorly determined</h2><p>Determined by these data only to the "
                     f"standard deviations below (lengths in {_e(unit)}, angles in the file's "
                     f"unit); to fix them, measure {_e(poor.get('measure_next', ''))}.</p>"
                     "<table><tr><th>parameter</th><th>std</th><th>most correlated with</th>"
                     f"<th>correlation</th></tr>{rows}</table>")
    return "".join(parts)


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
        out.append("<h2>Model adequacy</h2>" + _kv_table(list(_rows(adequacy))))
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
    parts = [f"<h1>{_e(title)}</h1>"]
    conv = report.get("convergence", {}) or {}
    ok = bool(conv.get("success"))
    parts.append(
        f"<p>Status: <span class={'ok' if ok else 'bad'}>"
        f"{'converged' if ok else 'not converged'}</span> - {_e(conv.get('message', ''))}</p>")
    parts.append("<h2>Summary</h2>" + _kv_table(list(_summary_rows(report, conv))))
    ident = report.get("identifiability") or {}
    if ident:
        rank, n = ident.get("identifiable"), ident.get("free_parameters")
        items = "".join(f"<li><b>{_e(d.get('dimension'))} x {_e(d.get('name'))}</b>: "
                        f"{_e(d.get('description', ''))}</li>"
                        for d in ident.get("unidentifiable", []))
        weak = "".join(f"<li><b>{_e(d.get('name'))}</b>: {_e(d.get('description', ''))}</li>"
                       for d in ident.get("weakly_identifiable", []) or [])
        parts.append(f"<h2>Identifiability</h2><p>{_e(rank)} of {_e(n)} free parameter "
                     f"directions identified; condition number "
                     f"{_e(_num(ident.get('condition_number')))} (scaled Jacobian).</p>"
                     + (f"<p>Not identifiable from these data:</p><ul>{items}</ul>"
                        if items else "")
                     + (f"<p>Weakly identifiable (counted above, left at the machine file's "
                        f"values):</p><ul>{weak}</ul>" if weak else ""))
        if ident.get("singular_values"):
            parts.append(_singular_plot(ident["singular_values"], int(rank or 0)))
    res = report.get("residuals") or {}
    if res:
        unit = res.get("unit", "") if isinstance(res.get("unit", ""), str) else ""
        parts.append("<h2>Residuals</h2>" + _kv_table(list(_rows(
            {k: v for k, v in res.items() if k not in ("before_calibration",
                                                       "after_calibration")}, "", unit))))
        st = _standardised(report)
        text = verdict_html(report)
        if st is not None and st[0].size:
            levels = report.get("noise_model")
            noise = ("the noise levels used (estimated from these residuals: see Noise "
                     "levels)" if isinstance(levels, Mapping) and levels.get("estimated")
                     else "the assumed noise")
            parts.append(
                "<div class=side><div>" + _residual_plot(*st) + "</div><div>"
                "<p><b>Standardised residuals</b> ("
                + _e(st[1]) + f"), each over {_e(noise)}: N(0, 1) for a correct fit with "
                "that noise. The fit absorbs part of every residual (the poses and the "
                "identified parameters): raw residual / assumed std would look too narrow for "
                "a correct fit.</p>" + text + "</div></div>")
        else:
            parts.append(text)
        parts.append(_before_after(res))
    parts.append(_noise_section(report))
    ratio = report.get("distance_ratio")
    if isinstance(ratio, Mapping) and isinstance(ratio.get("before"), Mapping):
        parts.append("<h2>Distance ratios (seed 001 Fig. 6)</h2>"
                     f"<p>{_e(ratio.get('pairs'))} pairs ({_e(ratio.get('pairs_from', ''))});"
                     " FK distance / tracker distance x 100 %, independent of frames.</p>"
                     + _kv_table([(f"{k}: {s}", _num(v), "%", True)
                                  for k in ("before", "after", "after_two_step")
                                  if isinstance(ratio.get(k), Mapping)
                                  for s, v in ratio[k].items()])
                     + _ratio_plot(ratio))
    validation = report.get("validation")
    if isinstance(validation, Mapping):
        parts.append("<h2>Held-out validation</h2>" + _kv_table(list(_rows(validation))))
    parts.append(_instrument_sections(report))
    for key in ("link_length", "registration", "frames", "bed"):
        if isinstance(report.get(key), Mapping):
            parts.append(f"<h2>{_e(key.replace('_', ' '))}</h2>"
                         + _kv_table(list(_rows(report[key]))))
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
        parts.append("<h2>Provenance</h2>" + _kv_table(
            [(k, _value_text(k, v), "", False) for k, v in prov.items()]))
    body = "\n".join(p for p in parts if p)
    return (f"<!DOCTYPE html><html lang=en><head><meta charset=utf-8><title>{_e(title)}"
            f"</title><style>{STYLE}</style></head><body>{body}</body></html>\n")
