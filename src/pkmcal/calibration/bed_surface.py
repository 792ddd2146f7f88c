"""The bed's own shape: what probed meshes show beside the plane and no kinematics holds.

A printer's bed mesh (many probe heights over the bed) fitted with a kinematic model leaves
residuals; where they exceed the probe's noise they have a shape (a bed is not flat; a
printer's frame bends), and that shape comes back in the next session (a Klipper user who
loads the old mesh gains from it). :func:`fit_bed_surface` fits a smooth grid to them (each
data set's mean removed: every mesh has its own height offset), kept only where it is well
above the probe's repeatability; the calibration's probe set-up carries it (its ``surface``, the
calibrated file's ``bed: surface``) and ``export`` hands it over in the firmware's bed mesh with
what the firmware's kinematics cannot hold (:mod:`pkmcal.export.bed_mesh`).

The grid: ``count`` nodes per side over ``[-R, R]`` (``R`` the largest probed radius); the
values minimise ``|B v - s|^2 + SMOOTH |L v|^2`` (``B`` the bilinear weights of the probed
points, ``s`` minus their residuals, ``L`` the grid's discrete Laplacian): nodes without data
follow their neighbours smoothly.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..instruments.registry import INSTRUMENTS, measures_bed_height
from .run import register_after_step

#: nodes per side of the surface's grid
COUNT = 11
#: weight of the Laplacian (per node) against the data (per point)
SMOOTH = 0.03
#: a data set is a mesh (has a shape to fit) from this many probed points
MIN_POINTS = 25
#: a surface is kept when its sum of squares at the probed points is this many times what the
#: smoother would fit to noise alone (``df sigma^2``)
SIGNIFICANCE = 3.0
#: a surface whose largest value at the probed points is below this (m) is not kept: three
#: times the probe's repeatability (``pkmcal.instruments.probe.PROBE_SIGMA``, 10 um); the
#: smoothing leaves pure noise well below it
MIN_PEAK = 30e-6


def _bilinear(xy, radius: float, n: int) -> np.ndarray:
    f = np.clip((xy + radius) / (2 * radius) * (n - 1), 0.0, n - 1.0)
    i0 = np.clip(np.floor(f).astype(int), 0, n - 2)
    t = f - i0
    B = np.zeros((len(xy), n * n))
    rows = np.arange(len(xy))
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        w = (t[:, 0] if dx else 1 - t[:, 0]) * (t[:, 1] if dy else 1 - t[:, 1])
        np.add.at(B, (rows, (i0[:, 1] + dy) * n + i0[:, 0] + dx), w)
    return B


def _laplacian(n: int) -> np.ndarray:
    L = np.zeros((n * n, n * n))
    for j in range(n):
        for i in range(n):
            k = j * n + i
            for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                ii, jj = i + di, j + dj
                if 0 <= ii < n and 0 <= jj < n:
                    L[k, k] -= 1.0
                    L[k, jj * n + ii] += 1.0
    return L


def fit_bed_surface(calibrated, datasets, count: int = COUNT, bed=None):
    """The bed's shape from the probe data sets of a calibration (see the module docstring).

    Parameters
    ----------
    calibrated : Machine
        The calibrated machine.
    datasets : iterable
        The calibration's data; those of an instrument that measures bed heights with at
        least :data:`MIN_POINTS` rows are used (readings ``q``, nozzle heights ``values``).
    count : int, optional
        Nodes per side.
    bed : BedSetup, optional
        The calibrated bed (:class:`~pkmcal.instruments.probe.BedSetup`: its plane and any
        surface already known); None: flat at z = 0.

    Returns
    -------
    tuple or None
        ``(radius m, values (count, count) m, rms m, points)``; None without meshes or when
        the shape is below :data:`MIN_PEAK`.
    """
    from ..machines.base import bed_height_at

    xy_all, s_all = [], []
    for d in datasets:
        if not measures_bed_height(d) or len(getattr(d, "q", ())) < MIN_POINTS:
            continue
        with np.errstate(all="ignore"):
            fk = calibrated.fk(np.asarray(d.q, float))
        ok = np.asarray(fk.converged, bool) & np.all(np.isfinite(fk.P), axis=-1)
        if ok.sum() < MIN_POINTS:
            continue
        P = fk.P[ok]
        predicted = P[:, 2] - bed_height_at(None if bed is None else bed.plane, P[:, :2],
                                            None if bed is None else bed.surface)
        measured = np.asarray(d.values, float).reshape(len(d.q), -1)[ok, 0]
        s = predicted - measured                 # a bed higher by s: triggers s earlier
        xy_all.append(P[:, :2])
        s_all.append(s - s.mean())
    if not xy_all:
        return None
    xy, s = np.concatenate(xy_all), np.concatenate(s_all)
    radius = float(np.max(np.hypot(xy[:, 0], xy[:, 1])))
    if not radius > 0:
        return None
    B = _bilinear(xy, radius, count)
    L = _laplacian(count)
    A = np.vstack([B, np.sqrt(SMOOTH) * L])
    v = np.linalg.lstsq(A, np.concatenate([s, np.zeros(count * count)]), rcond=None)[0]
    fitted = B @ v
    rms = float(np.sqrt(np.mean(fitted**2)))
    # significance: fitted to pure noise of variance sigma^2 the surface's sum of squares
    # is about sigma^2 tr(H^2) <= sigma^2 tr(H) (H the smoother's hat matrix); the residual
    # scatter estimates sigma
    H = B @ np.linalg.solve(A.T @ A, B.T)
    df = float(np.trace(H))
    sigma2 = float(np.sum((s - fitted) ** 2)) / max(len(s) - df, 1.0)
    if np.max(np.abs(fitted)) <= MIN_PEAK or np.sum(fitted**2) <= SIGNIFICANCE * df * sigma2:
        return None
    return radius, v.reshape(count, count), rms, len(s)


def with_bed_surface(calibration, data):
    """A printer's bed shape beside its plane, from its probed meshes (:func:`fit_bed_surface`):
    in the calibration's probe set-up (its file's ``bed: surface``) and in the report, where
    it is significant.

    Parameters
    ----------
    calibration : Calibration
        A calibration (its ``setups``, ``report`` and ``warnings`` are completed).
    data : list
        The data it was fitted to (paths are skipped: read inside the fit).

    Returns
    -------
    Calibration
        The same object.
    """
    from pathlib import Path

    calibrated = calibration.calibrated
    if not getattr(calibrated, "frame_is_bed", False):
        return calibration
    items = [d for d in (data if isinstance(data, (list, tuple)) else [data])
             if not isinstance(d, (str, Path))]
    bed = calibration.setups.get("probe")
    fitted = fit_bed_surface(calibrated, items, bed=bed)
    if fitted is None:
        return calibration
    radius, values, rms, points = fitted
    bed = INSTRUMENTS["probe"].Setup() if bed is None else bed
    calibration.setups = calibration.setups.with_setup(
        "probe", dataclasses.replace(bed, surface=(radius, values)))
    calibration.report["bed_surface"] = {
        "of": "the bed's own shape beside its plane: the meshes' residuals under the "
              "calibrated model (each mesh's mean removed), smoothed on a square grid; "
              "export hands it over in the firmware's bed mesh",
        "radius_mm": radius * 1e3, "rms_um": rms * 1e6, "count": points,
        "values_mm": (values * 1e3).tolist()}
    calibration.warnings.append(
        f"the bed's own shape: {rms * 1e6:.3g} um RMS over {points} probed points beyond what "
        "the kinematics explain (a bed that is not flat, a frame that bends); kept in the "
        "calibrated file (bed: surface) and handed over by export in the firmware's bed mesh")
    return calibration


# every calibration passes it (a printer's bed probed in meshes: their shape)
register_after_step(with_bed_surface)
