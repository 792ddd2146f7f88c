"""Plots (matplotlib, Agg backend: no display needed). Imported only by commands that plot."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def png_bytes(fig, dpi: int) -> bytes:
    """``fig`` rendered as PNG at ``dpi``, the figure closed.

    A figure with a layout engine is laid out here once, at ``dpi``, then drawn once:
    ``savefig`` would lay it out in a draw of its own (rendering nothing) before the drawing,
    for the same pixels (~12 % of a report's time). One without is cropped to its tight box.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure (closed on return).
    dpi : int
        Dots per inch.

    Returns
    -------
    bytes
        The PNG file's bytes.
    """
    import io

    buf = io.BytesIO()
    try:
        engine = fig.get_layout_engine()
        if engine is None:
            fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
        else:
            fig.set_dpi(dpi)
            engine.execute(fig)
            fig.set_layout_engine(None)
            fig.savefig(buf, format="png", dpi=dpi, bbox_inches=None)
    finally:
        plt.close(fig)
    return buf.getvalue()


def _save(fig, path: Path) -> Path:
    """Render ``fig`` as PNG and write it atomically (staged with the command's other
    outputs: :func:`pkmcal.io.atomic.atomic_write_bytes`)."""
    from ..io.atomic import atomic_write_bytes

    return atomic_write_bytes(Path(path), png_bytes(fig, 120))


def plot_sweep(points, path, xlabel: str, title: str, extra=None, extra_label: str = ""):
    """Calibrated position and orientation error against a study variable, log-log.

    Mean +/- one standard deviation over seeds, position in um and orientation in urad against
    the variable in um; the identity line for reference.

    Parameters
    ----------
    points : sequence of SweepPoint
        The main curve (:func:`~pkmcal.analysis.sweeps.constraint_link_sweep`), values in SI.
    path : str or os.PathLike
        Output PNG file.
    xlabel : str
        Label of the study variable's axis.
    title : str
        Figure title.
    extra : sequence of SweepPoint, optional
        A second curve, drawn dashed.
    extra_label : str, optional
        Legend label of ``extra``.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4), layout="constrained")
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
    """Histogram of residuals per actuator.

    Parameters
    ----------
    residuals_um : array_like, shape (K, n_joints)
        Residuals, um.
    path : str or os.PathLike
        Output PNG file.
    title : str, optional
        Axes title.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    r = np.atleast_2d(residuals_um)
    fig, ax = plt.subplots(figsize=(6, 4), layout="constrained")
    for j in range(r.shape[1]):
        ax.hist(r[:, j], bins=30, histtype="step", label=f"q{j + 1}")
    ax.set_xlabel("residual [um]")
    ax.set_ylabel("count")
    ax.set_title(title)
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_parameter_errors(names, before, after, std, path, unit_scale, unit_label):
    """Parameter deviations from truth before and after calibration (gauge-aligned).

    Absolute values on a log axis, with the reported standard deviations as markers.

    Parameters
    ----------
    names : sequence of str
        Parameter names.
    before : array_like, shape (n,)
        Nominal minus true values, internal units.
    after : array_like, shape (n,)
        Calibrated (gauge-aligned) minus true values, internal units.
    std : array_like, shape (n,) or None
        Reported standard deviations, internal units.
    path : str or os.PathLike
        Output PNG file.
    unit_scale : float
        Factor applied to every value before plotting.
    unit_label : str
        Label of the value axis.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    fig, ax = plt.subplots(figsize=(12, 4), layout="constrained")
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
    """Seed 001 Fig. 6: distance ratio of neighbouring grid points, before and after calibration.

    The ratio [%] is model distance / tracker distance x 100, per pair; the 100 % line is drawn
    for reference.

    Parameters
    ----------
    panels : list of tuple
        ``(panel title, {label: (ratios, style)})`` per panel; styles such as ``"--"``
        (before) and ``"-"`` (after).
    path : str or os.PathLike
        Output PNG file.
    title : str, optional
        Figure title.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    fig, axes = plt.subplots(1, len(panels), figsize=(6 * len(panels), 4), squeeze=False,
                             layout="constrained")
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


def _shade_envelope(ax, x, lo, hi, color, label=None):
    """Fill between ``lo`` and ``hi`` where they differ (an undetermined side)."""
    wide = np.asarray(hi) > np.asarray(lo)
    if np.any(wide):
        ax.fill_between(x, lo, hi, where=wide, color=color, alpha=0.25, lw=0, label=label,
                        step=None, interpolate=False)


def plot_link_forces(x, forces, path, xlabel: str = "angle [deg]",
                     title: str = "leg forces (tension positive)", undetermined=None):
    """Seed 003 Fig. 6: the six leg forces (tension positive) along the trajectory.

    Samples where a force is within the tolerance of zero (side undetermined) are marked.

    Parameters
    ----------
    x : array_like, shape (K,)
        Abscissa (e.g. the angle on the circle, deg).
    forces : array_like, shape (K, 6)
        Leg forces, N.
    path : str or os.PathLike
        Output PNG file.
    xlabel : str, optional
        Label of the abscissa; ticks every 45 when it starts with "angle".
    title : str, optional
        Axes title.
    undetermined : array_like of bool, shape (K, 6), optional
        Samples to mark.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    x = np.asarray(x, float)
    f = np.asarray(forces, float)
    fig, ax = plt.subplots(figsize=(8, 4.5), layout="constrained")
    for i in range(f.shape[1]):
        (line,) = ax.plot(x, f[:, i], lw=1.4, label=f"f{i + 1}")
        if undetermined is not None:
            m = np.asarray(undetermined)[:, i]
            if np.any(m):
                ax.plot(x[m], f[m, i], "o", ms=4, mfc="none", color=line.get_color())
    ax.axhline(0.0, color="k", lw=0.6, alpha=0.6)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("leg force [N]  (+ tension, - compression)")
    ax.set_title(title + ("; o = side undetermined" if undetermined is not None
                          and np.any(undetermined) else ""), fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, ncol=6)
    if xlabel.startswith("angle"):
        ax.set_xticks(np.arange(0, 361, 45))
    return _save(fig, path)


def plot_pose_errors(x, dx, dx_min, dx_max, path, xlabel: str = "angle [deg]",
                     title: str = "pose error from joint clearance"):
    """Seed 003 Fig. 7: position and orientation errors along the trajectory.

    Position errors dx, dy, dz [um] and orientation errors drx, dry, drz [urad]; where a leg
    force is near zero the envelope of both sides is shaded (the line is the value with those
    joints centred).

    Parameters
    ----------
    x : array_like, shape (K,)
        Abscissa (e.g. the angle on the circle, deg).
    dx : array_like, shape (K, 6)
        Pose errors ``[dp (m), dOmega (rad)]``.
    dx_min : array_like, shape (K, 6)
        Lower envelope, same units.
    dx_max : array_like, shape (K, 6)
        Upper envelope, same units.
    path : str or os.PathLike
        Output PNG file.
    xlabel : str, optional
        Label of the abscissa; ticks every 45 when it starts with "angle".
    title : str, optional
        Title of the upper axes.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    x = np.asarray(x, float)
    dx, lo, hi = (np.asarray(v, float) * 1e6 for v in (dx, dx_min, dx_max))
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 7), sharex=True, layout="constrained")
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, cols, names, unit in ((ax1, range(3), ("dx", "dy", "dz"), "um"),
                                  (ax2, range(3, 6), ("drx", "dry", "drz"), "urad")):
        for c, name, color in zip(cols, names, colors, strict=False):
            ax.plot(x, dx[:, c], lw=1.4, color=color, label=name)
            _shade_envelope(ax, x, lo[:, c], hi[:, c], color,
                            label=f"{name} envelope" if np.any(hi[:, c] > lo[:, c]) else None)
        ax.axhline(0.0, color="k", lw=0.6, alpha=0.6)
        ax.set_ylabel(f"{'position' if unit == 'um' else 'orientation'} error [{unit}]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, ncol=3)
    ax2.set_xlabel(xlabel)
    if xlabel.startswith("angle"):
        ax2.set_xticks(np.arange(0, 361, 45))
    ax1.set_title(title, fontsize=10)
    return _save(fig, path)


def plot_error_map(x, y, panels, path, title: str = "pose error over the workspace",
                   overlay=None):
    """Error maps over a horizontal workspace slice, one panel per map.

    Parameters
    ----------
    x : array_like, shape (nx,)
        Grid positions along X, mm.
    y : array_like, shape (ny,)
        Grid positions along Y, mm.
    panels : sequence of tuple
        ``(panel title, values (ny, nx), colour-bar label)`` per panel.
    path : str or os.PathLike
        Output PNG file.
    title : str, optional
        Figure title.
    overlay : array_like, shape (K, 2), optional
        Path in mm (e.g. the trajectory) drawn on every panel.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    n = len(panels)
    cols = min(n, 2)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(6 * cols, 4.8 * rows), squeeze=False,
                             layout="constrained")
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    for ax, (panel_title, values, label) in zip(axes.flat, panels, strict=False):
        mesh = ax.pcolormesh(x, y, np.asarray(values, float), shading="auto", cmap="viridis")
        fig.colorbar(mesh, ax=ax, label=label)
        if overlay is not None:
            o = np.asarray(overlay, float)
            ax.plot(o[:, 0], o[:, 1], "w-", lw=1.2)
        ax.set_aspect("equal")
        ax.set_xlabel("x [mm]")
        ax.set_ylabel("y [mm]")
        ax.set_title(panel_title, fontsize=9)
    fig.suptitle(title)
    return _save(fig, path)


def plot_prediction_map(slices, path, title: str, plan=None, centre=None):
    """Predicted error over workspace slices and, optionally, where the planned measurements are.

    Parameters
    ----------
    slices : sequence of tuple
        ``(panel title, a (n,) mm, b (m,) mm, values (m, n), a label, b label, colour-bar
        label)`` per panel.
    path : str or os.PathLike
        Output PNG file.
    title : str
        Figure title.
    plan : array_like, shape (K, 3), optional
        Planned positions, mm, drawn in an extra panel (x, y; colour z).
    centre : array_like, shape (3,), optional
        Home position, mm, drawn as a cross with the 0.1 m workspace square.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    n = len(slices) + (plan is not None)
    fig, axes = plt.subplots(1, n, figsize=(5.4 * n, 4.6), squeeze=False, layout="constrained")
    for ax, (panel_title, a, b, values, la, lb, label) in zip(axes.flat, slices, strict=False):
        mesh = ax.pcolormesh(a, b, np.asarray(values, float), shading="auto", cmap="viridis")
        fig.colorbar(mesh, ax=ax, label=label)
        ax.set_aspect("equal")
        ax.set_xlabel(la)
        ax.set_ylabel(lb)
        ax.set_title(panel_title, fontsize=9)
    if plan is not None:
        ax = axes.flat[-1]
        p = np.asarray(plan, float)
        sc = ax.scatter(p[:, 0], p[:, 1], c=p[:, 2], s=10, cmap="plasma")
        fig.colorbar(sc, ax=ax, label="z [mm]")
        if centre is not None:
            c = np.asarray(centre, float)
            ax.plot(c[0], c[1], "k+", ms=10)
            sq = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1], [-1, -1]]) * 50.0 + c[:2]
            ax.plot(sq[:, 0], sq[:, 1], "k--", lw=1, label="workspace (x, y)")
            ax.legend(fontsize=7, loc="upper right")
        ax.set_aspect("equal")
        ax.set_xlabel("x [mm]")
        ax.set_ylabel("y [mm]")
        ax.set_title(f"{len(p)} planned measurement positions", fontsize=9)
    fig.suptitle(title)
    return _save(fig, path)
