"""Plots (matplotlib, Agg backend: no display needed). Imported only by commands that plot."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def _save(fig, path: Path) -> Path:
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp.png")
    fig.savefig(tmp, dpi=120, bbox_inches="tight")
    plt.close(fig)
    tmp.replace(path)
    return path


def plot_sweep(points, path, xlabel: str, title: str, extra=None, extra_label: str = ""):
    """Calibrated position (um) and orientation (urad) error against a study variable (um),
    log-log, mean +/- one standard deviation over seeds; the identity line for reference."""
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    for pts, label, style in ((points, "maximum likelihood", "o-"),
                              (extra, extra_label, "s--")):
        if not pts:
            continue
        x = np.array([p.value for p in pts]) * 1e6
        for ax, mean, std, scale in (
                (ax1, "position_mean", "position_std", 1e6),
                (ax2, "orientation_mean", "orientation_std", 1e6)):
            m = np.array([getattr(p, mean) for p in pts]) * scale
            s = np.array([getattr(p, std) for p in pts]) * scale
            ax.errorbar(x, m, yerr=s, fmt=style, capsize=3, label=label)
    x = np.array([p.value for p in points]) * 1e6
    ax1.plot(x, x, "k:", lw=1, label="error = variable")
    for ax, ylabel in ((ax1, "mean position error after calibration [um]"),
                       (ax2, "mean orientation error after calibration [urad]")):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title)
    return _save(fig, path)


def plot_residuals(residuals_um, path, title: str = "joint residuals after calibration"):
    """Histogram of residuals (um) per actuator."""
    r = np.atleast_2d(residuals_um)
    fig, ax = plt.subplots(figsize=(6, 4))
    for j in range(r.shape[1]):
        ax.hist(r[:, j], bins=30, histtype="step", label=f"q{j + 1}")
    ax.set_xlabel("residual [um]")
    ax.set_ylabel("count")
    ax.set_title(title)
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_parameter_errors(names, before, after, std, path, unit_scale, unit_label):
    """Parameter deviations from truth before and after calibration (gauge-aligned)."""
    fig, ax = plt.subplots(figsize=(12, 4))
    x = np.arange(len(names))
    ax.bar(x - 0.2, np.abs(before) * unit_scale, 0.4, label="nominal - true")
    ax.bar(x + 0.2, np.abs(after) * unit_scale, 0.4, label="calibrated - true")
    if std is not None:
        ax.plot(x + 0.2, np.asarray(std) * unit_scale, "k_", ms=8, label="reported std")
    ax.set_yscale("log")
    ax.set_xticks(x, names, rotation=90, fontsize=6)
    ax.set_ylabel(unit_label)
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_distance_ratio(panels, path, title: str = "distance ratio of neighbouring points"):
    """Seed 001 Fig. 6: distance ratio [%] (model distance / tracker distance x 100) of
    neighbouring grid points, per pair, before (dashed) and after (solid) calibration.

    ``panels``: list of ``(panel title, {label: (ratios, style)})``; styles such as ``"--"``
    (before) and ``"-"`` (after). The 100 % line is drawn for reference.
    """
    fig, axes = plt.subplots(1, len(panels), figsize=(6 * len(panels), 4), squeeze=False)
    for ax, (panel_title, curves) in zip(axes[0], panels, strict=True):
        for label, (ratios, style) in curves.items():
            r = np.asarray(ratios, float)
            ax.plot(np.arange(1, r.size + 1), r, style, lw=1.2, marker=".", ms=4,
                    label=f"{label} (std {np.std(r):.3g} %)")
        ax.axhline(100.0, color="k", lw=0.6, alpha=0.5)
        ax.set_xlabel("pair of neighbouring points")
        ax.set_ylabel("distance ratio [%]")
        ax.set_title(panel_title, fontsize=10)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title)
    return _save(fig, path)
