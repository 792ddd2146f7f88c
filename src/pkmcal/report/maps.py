"""The pictures of a calibration's answer (issue 36), from the report's ``outcome.map``
(:func:`pkmcal.analysis.outcome.calibration_outcome`): figures people already read.

* A printer: its bed seen from above, as the bed-mesh views of Mainsail, Fluidd and
  OctoPrint's Bed Visualizer show it - the predicted nozzle height error over the print disk
  with the values in force (signed, diverging colours), and with the new values (their 1-sigma
  uncertainty, a size: sequential colours), on the same limits, the range in the title; the
  probe points on top, coloured by their residuals before and after on the same scale.
* Other machines: the workspace's points seen from above, coloured by the position error of the
  machine file's model and of the calibrated one (1 sigma), one colour scale.

Every axis names its quantity and unit; every colour bar too.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

__all__ = ["bed_maps", "measured_points", "workspace_maps"]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _arr(values) -> np.ndarray:
    return np.asarray([np.nan if v is None else v for v in values], float)


#: probe points up to this many carry their residual as a label (the after panel)
LABELLED = 60


def _range_text(v: np.ndarray, unit: str, sign: bool = True) -> str:
    from ..units import format_number

    v = v[np.isfinite(v)]
    if not v.size:
        return "no values"
    return (f"range {format_number(v.min(), 3, sign=sign)} .. "
            f"{format_number(v.max(), 3, sign=sign)} {unit}")


def bed_maps(pmap: Mapping):
    """The bed maps of a printer (see the module docstring).

    Parameters
    ----------
    pmap : mapping
        ``outcome.map`` of kind ``bed``: ``grid_mm``, ``before_um``, ``after_std_um`` (flat,
        row by row in y), ``radius_mm``, optional ``points`` (``x_mm``, ``y_mm``,
        ``before_um``, ``after_um``).

    Returns
    -------
    matplotlib.figure.Figure
        Two panels side by side, one colour bar.
    """
    plt = _plt()
    g = np.asarray(pmap["grid_mm"], float)
    n = g.size
    before = _arr(pmap["before_um"]).reshape(n, n)
    after = _arr(pmap["after_std_um"]).reshape(n, n)
    pts = pmap.get("points") or {}
    px, py = _arr(pts.get("x_mm", [])), _arr(pts.get("y_mm", []))
    pb, pa = _arr(pts.get("before_um", [])), _arr(pts.get("after_um", []))
    scale = max([np.nanmax(np.abs(v)) for v in (before, after, pb, pa)
                 if v.size and np.isfinite(v).any()] + [1e-3])
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.9), layout="constrained")
    panels = ((before, pb, "with the values in force: predicted height error",
               "probe residuals, values in force"),
              (after, pa, "with the new values: height uncertainty (1 sigma)",
               "probe residuals, new values"))
    meshes = []
    for ax, (field, resid, title, label) in zip(axes, panels, strict=True):
        # the error is signed (diverging colours about 0); the uncertainty is a size: its own
        # sequential colours on the same limits
        signed = not meshes
        meshes.append(ax.pcolormesh(g, g, field, cmap="RdBu_r" if signed else "Purples",
                                    vmin=-scale if signed else 0.0, vmax=scale,
                                    shading="nearest"))
        ax.add_patch(plt.Circle((0, 0), float(pmap["radius_mm"]), fill=False, color="k",
                                lw=0.8))
        if px.size:
            ax.scatter(px, py, c=resid, cmap="RdBu_r", vmin=-scale, vmax=scale, s=46,
                       edgecolors="k", linewidths=0.8, label=label + " [um]")
            if len(meshes) == 2 and px.size <= LABELLED:
                # what remains is small beside the colour scale: its numbers, in um
                from ..units import format_number

                for x, y, r in zip(px, py, resid, strict=True):
                    if np.isfinite(r):
                        ax.annotate(format_number(r, 2, sign=True), (x, y), fontsize=7,
                                    xytext=(4, 4), textcoords="offset points")
            ax.legend(loc="lower left", fontsize=8, framealpha=0.85)
        ax.set_title(f"{title}\nmap {_range_text(field, 'um')}"
                     + (f"; points {_range_text(resid, 'um')}" if px.size else ""),
                     fontsize=9.5)
        ax.set_xlabel("x on the bed [mm]")
        ax.set_ylabel("y on the bed [mm]")
        ax.set_aspect("equal")
    fig.colorbar(meshes[0], ax=axes[0], shrink=0.85,
                 label="nozzle height error [um] (+: too high)")
    fig.colorbar(meshes[1], ax=axes[1], shrink=0.85,
                 label="height uncertainty, 1 sigma [um]")
    return fig


def workspace_maps(pmap: Mapping):
    """The position error over the workspace before and after (see the module docstring).

    Parameters
    ----------
    pmap : mapping
        ``outcome.map`` of kind ``workspace``: ``x_mm``, ``y_mm``, ``before_um``,
        ``after_um``.

    Returns
    -------
    matplotlib.figure.Figure
        Two panels side by side, one colour bar.
    """
    plt = _plt()
    x, y = _arr(pmap["x_mm"]), _arr(pmap["y_mm"])
    before, after = _arr(pmap["before_um"]), _arr(pmap["after_um"])
    unit = "um"                         # the unit of every residual and accuracy figure
    top = max(float(np.nanmax(np.r_[before, after, 1e-9])), 1e-9)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), layout="constrained")
    sc = None
    order = np.argsort(_arr(pmap.get("z_mm", np.zeros(len(x)))))   # upper points on top
    for ax, v, title in ((axes[0], before, "machine file's model"),
                         (axes[1], after, "calibrated (1-sigma uncertainty)")):
        sc = ax.scatter(x[order], y[order], c=v[order], cmap="viridis", vmin=0, vmax=top,
                        s=16)
        ax.set_title(f"position error, {title}\n{_range_text(v, unit, sign=False)}",
                     fontsize=9.5)
        ax.set_xlabel("x [mm]")
        ax.set_ylabel("y [mm]")
        ax.set_aspect("equal", adjustable="datalim")
    fig.colorbar(sc, ax=list(axes), shrink=0.9, label=f"position error [{unit}]")
    return fig


def measured_points(pmap: Mapping):
    """The error at each measured point, before and after: how far the machine file's model
    puts the tool from where the calibrated model does for the row's readings, and the
    calibrated model's 1-sigma there.

    Parameters
    ----------
    pmap : mapping
        ``outcome.map`` with ``measured_points`` (``before_um``, ``after_um``, one per row).

    Returns
    -------
    matplotlib.figure.Figure or None
        One panel, rows in file order; None without ``measured_points``.
    """
    measured = pmap.get("measured_points")
    if not isinstance(measured, Mapping):
        return None
    plt = _plt()
    before, after = _arr(measured["before_um"]), _arr(measured["after_um"])
    k = np.arange(1, before.size + 1)
    fig, ax = plt.subplots(figsize=(11, 3.2), layout="constrained")
    ax.semilogy(k, np.where(before > 0, before, np.nan), "o", ms=3.5,
                label=f"machine file's model ({_range_text(before, 'um', sign=False)})")
    ax.semilogy(k, np.where(after > 0, after, np.nan), "s", ms=3.5,
                label=f"calibrated, 1 sigma ({_range_text(after, 'um', sign=False)})")
    ax.set_xlabel("measured point (row of the data, in order) [count]")
    ax.set_ylabel("position error [um]")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return fig
