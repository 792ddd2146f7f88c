"""One self-contained HTML file from a calibration report (``pkmcal report``, issue 6).

The input is the JSON report ``pkmcal calibrate`` writes beside the calibrated machine file
(the "JSON twin"); the HTML has no external resource: styles inline, plots as embedded PNG
(base64). Sections appear when the report has the data: summary, provenance (command and
versions), residuals (table, histogram of normalised residuals against N(0, 1)), before/after
accuracy, distance ratios (Delta), identifiability (words, singular values), parameters
(nominal, identified, change, standard deviation, unit) and their changes in standard
deviations.
"""

from __future__ import annotations

import base64
import html
import io
from collections.abc import Mapping

import numpy as np

STYLE = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2em auto;
max-width:1100px;color:#222;line-height:1.4}
h1{font-size:1.6em;border-bottom:2px solid #446;padding-bottom:.2em}
h2{font-size:1.25em;margin-top:1.6em;color:#335}
table{border-collapse:collapse;margin:.5em 0;font-size:.9em}
td,th{border:1px solid #ccc;padding:.25em .6em;text-align:left;vertical-align:top}
th{background:#eef}
td.num{text-align:right;font-variant-numeric:tabular-nums}
.ok{color:#070;font-weight:bold}.bad{color:#b00;font-weight:bold}
img{max-width:100%;border:1px solid #ddd;margin:.5em 0}
code{background:#f4f4f4;padding:0 .2em}
.small{font-size:.85em;color:#555}
"""


def _e(x) -> str:
    return html.escape(str(x))


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        if not np.isfinite(v):
            return "-"
        return f"{v:.6g}"
    if isinstance(v, list):
        if len(v) <= 6 and all(isinstance(x, (int, float)) for x in v):
            return ", ".join(_fmt(x) for x in v)
        return f"({len(v)} values)"
    return str(v)


def _kv_table(rows) -> str:
    body = "".join(f"<tr><th>{_e(k)}</th><td>{_e(_fmt(v))}</td></tr>" for k, v in rows)
    return f"<table>{body}</table>"


def _flat(d: Mapping, prefix: str = ""):
    """Scalar leaves of a nested mapping as ``(dotted key, value)``."""
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            yield from _flat(v, key + ".")
        elif not (isinstance(v, list) and len(v) > 6):
            yield key, v


def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    return f'<img alt="plot" src="data:image/png;base64,{data}">'


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _residual_plot(values) -> str:
    plt = _plt()
    r = np.asarray(values, float)
    r = r[np.isfinite(r)]
    fig, ax = plt.subplots(figsize=(6.5, 3.6))
    ax.hist(r, bins=min(60, max(10, r.size // 15)), density=True, alpha=0.7,
            label=f"{r.size} normalised residuals")
    x = np.linspace(min(-4.0, r.min()), max(4.0, r.max()), 200)
    ax.plot(x, np.exp(-x**2 / 2) / np.sqrt(2 * np.pi), "k-", lw=1.2, label="N(0, 1)")
    ax.set_xlabel("residual / assumed noise std")
    ax.set_ylabel("density")
    ax.legend(fontsize=8)
    return _png(fig)


def _singular_plot(s, rank) -> str:
    plt = _plt()
    s = np.asarray(s, float)
    fig, ax = plt.subplots(figsize=(6.5, 3.2))
    idx = np.arange(1, s.size + 1)
    ax.semilogy(idx[:rank], s[:rank], "o", ms=4, label="identifiable")
    if s.size > rank:
        ax.semilogy(idx[rank:], np.maximum(s[rank:], s[0] * 1e-17), "x", color="C3",
                    label="unidentifiable")
    ax.set_xlabel("index")
    ax.set_ylabel("singular value (scaled J)")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    return _png(fig)


def _change_plot(params) -> str:
    plt = _plt()
    names = [p["name"] for p in params]
    z = []
    for p in params:
        std = p.get("std")
        ch = _change(p)
        z.append(ch / std if (std and ch is not None and std > 0) else np.nan)
    z = np.asarray(z, float)
    fig, ax = plt.subplots(figsize=(max(6.5, 0.12 * len(names)), 3.4))
    ax.bar(np.arange(len(z)), np.nan_to_num(z), color=np.where(np.abs(z) > 3, "C3", "C0"))
    ax.axhline(3, color="k", lw=0.6, ls=":")
    ax.axhline(-3, color="k", lw=0.6, ls=":")
    ax.set_xticks(np.arange(len(z)))
    ax.set_xticklabels(names, rotation=90, fontsize=6)
    ax.set_ylabel("change / std")
    ax.set_title("identified - nominal, in standard deviations (|.| > 3: significant)",
                 fontsize=9)
    return _png(fig)


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
    ax.legend(fontsize=8)
    return _png(fig)


def _change(p):
    try:
        return float(p["identified"]) - float(p["nominal"])
    except (KeyError, TypeError, ValueError):
        return None


def _parameters_table(params) -> str:
    head = ("<tr><th>parameter</th><th>unit</th><th>nominal</th><th>identified</th>"
            "<th>change</th><th>std</th><th>change/std</th></tr>")
    rows = []
    for p in params:
        ch, std = _change(p), p.get("std")
        z = ch / std if (ch is not None and std) else None
        cls = ' class="num"'
        flag = " bad" if (z is not None and abs(z) > 3) else ""
        rows.append(
            f"<tr><td>{_e(p['name'])}</td><td>{_e(p.get('unit', ''))}</td>"
            f"<td{cls}>{_e(_fmt(p.get('nominal')))}</td>"
            f"<td{cls}>{_e(_fmt(p.get('identified')))}</td>"
            f"<td{cls}>{_e(_fmt(ch))}</td><td{cls}>{_e(_fmt(std))}</td>"
            f'<td class="num{flag}">{_e(_fmt(z))}</td></tr>')
    return f"<table>{head}{''.join(rows)}</table>"


def _before_after(res: Mapping) -> str:
    """Rows 'quantity | before | after' from a residuals section, when it has both."""
    rows = []
    if "before_rms_um" in res and "rms_um" in res:
        rows.append(("RMS residual [um]", res["before_rms_um"], res["rms_um"]))
    b, a = res.get("before_calibration"), res.get("after_calibration")
    if isinstance(b, Mapping) and isinstance(a, Mapping):
        for k in b:
            if k in a and not isinstance(b[k], (list, Mapping)):
                rows.append((k, b[k], a[k]))
    if not rows:
        return ""
    body = "".join(f"<tr><td>{_e(k)}</td><td class=num>{_e(_fmt(x))}</td>"
                   f"<td class=num>{_e(_fmt(y))}</td></tr>" for k, x, y in rows)
    note = _e(res.get("before", ""))
    return (f"<h2>Before / after calibration</h2><p class=small>before: {note}</p>"
            f"<table><tr><th>quantity</th><th>before</th><th>after</th></tr>{body}</table>")


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
    title = title or f"pkmcal calibration report: {report.get('calibrated_file', '')}"
    parts = [f"<h1>{_e(title)}</h1>"]
    conv = report.get("convergence", {}) or {}
    ok = bool(conv.get("success"))
    parts.append(
        f"<p>Status: <span class={'ok' if ok else 'bad'}>"
        f"{'converged' if ok else 'not converged'}</span> - {_e(conv.get('message', ''))}</p>")
    summary_keys = ("machine_file", "data_file", "calibrated_file", "measurement", "method",
                    "measurements", "used", "date", "noise", "noise_sigma_um")
    parts.append("<h2>Summary</h2>" + _kv_table(
        [(k, report[k]) for k in summary_keys if k in report]
        + [(f"convergence.{k}", v) for k, v in conv.items() if k != "success"]))
    ident = report.get("identifiability") or {}
    if ident:
        rank, n = ident.get("identifiable"), ident.get("free_parameters")
        items = "".join(f"<li><b>{_e(d.get('dimension'))} x {_e(d.get('name'))}</b>: "
                        f"{_e(d.get('description', ''))}</li>"
                        for d in ident.get("unidentifiable", []))
        parts.append(f"<h2>Identifiability</h2><p>{_e(rank)} of {_e(n)} free parameter "
                     f"directions identified; condition number "
                     f"{_e(_fmt(ident.get('condition_number')))} (scaled Jacobian).</p>"
                     + (f"<p>Not identifiable from these data:</p><ul>{items}</ul>"
                        if items else ""))
        if ident.get("singular_values"):
            parts.append(_singular_plot(ident["singular_values"], int(rank or 0)))
    res = report.get("residuals") or {}
    if res:
        parts.append("<h2>Residuals</h2>" + _kv_table(list(_flat(
            {k: v for k, v in res.items() if k not in ("before_calibration",
                                                       "after_calibration")}))))
        normalised = report.get("normalised_residuals")
        if normalised:
            parts.append(_residual_plot(normalised))
        parts.append(_before_after(res))
    ratio = report.get("distance_ratio")
    if isinstance(ratio, Mapping) and isinstance(ratio.get("before"), Mapping):
        parts.append("<h2>Distance ratios (seed 001 Fig. 6)</h2>"
                     f"<p>{_e(ratio.get('pairs'))} pairs ({_e(ratio.get('pairs_from', ''))});"
                     " FK distance / tracker distance x 100 %, independent of frames.</p>"
                     + _ratio_plot(ratio))
    validation = report.get("validation")
    if isinstance(validation, Mapping):
        parts.append("<h2>Held-out validation</h2>" + _kv_table(list(_flat(validation))))
    for key in ("link_length", "registration", "frames", "identifiable_combinations"):
        if isinstance(report.get(key), Mapping):
            parts.append(f"<h2>{_e(key.replace('_', ' '))}</h2>"
                         + _kv_table(list(_flat(report[key]))))
    params = report.get("parameters") or []
    if params:
        parts.append("<h2>Parameters</h2><p class=small>Standard deviations from the "
                     "covariance of the estimate (scaled by the residual variance); "
                     "unidentifiable directions keep the machine file's values.</p>"
                     + _change_plot(params) + _parameters_table(params))
    prov = report.get("provenance") or {}
    if prov:
        parts.append("<h2>Provenance</h2>" + _kv_table(list(prov.items())))
    body = "\n".join(p for p in parts if p)
    return (f"<!DOCTYPE html><html lang=en><head><meta charset=utf-8><title>{_e(title)}"
            f"</title><style>{STYLE}</style></head><body>{body}</body></html>\n")
