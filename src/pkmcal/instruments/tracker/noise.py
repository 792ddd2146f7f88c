"""The laser tracker's noise model (:class:`TrackerNoise`, Leica-type: half the MPE along and
across the beam, anisotropic per point) and the words of its ``--noise`` option."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputError


@dataclass(frozen=True)
class TrackerNoise:
    """Standard deviations of a laser tracker (half the MPE by default), SI units.

    Attributes
    ----------
    distance : float, optional
        Along the beam, m.
    transverse : float, optional
        Across the beam, constant part, m.
    transverse_per_m : float, optional
        Across the beam, per metre of range (m/m).
    """

    distance: float = 5e-6            # along the beam
    transverse: float = 7.5e-6        # across the beam, constant part
    transverse_per_m: float = 3e-6    # across the beam, per metre of range

    def _beam(self, m):
        """Beam directions ``r`` (K, 3; +z at the tracker's origin, where there is none), the
        projector on them ``rr`` (K, 3, 3) and the transverse std ``st`` (K,)."""
        m = np.asarray(m, float)
        rng = np.linalg.norm(m, axis=-1)
        r = np.where(rng[..., None] > 0, m / np.where(rng > 0, rng, 1.0)[..., None],
                     np.array([0.0, 0.0, 1.0]))
        return (r, r[..., :, None] * r[..., None, :],
                self.transverse + self.transverse_per_m * rng)

    def covariance(self, m):
        """Per-point covariance in the tracker frame.

        Parameters
        ----------
        m : array_like, shape (K, 3)
            Tracker points, m, tracker frame.

        Returns
        -------
        ndarray, shape (K, 3, 3)
            Covariance of each point, m^2.
        """
        _, rr, st = self._beam(m)
        return self.distance**2 * rr + (st**2)[..., None, None] * (np.eye(3) - rr)

    def whitening(self, m):
        """Whitening matrices ``W`` with ``W^T W = Cov^-1``, rows along the beam first.

        Row 0 is along the beam (``r / s_d``), rows 1-2 across it (two unit vectors normal
        to the beam, ``/ s_t``, range-dependent): each whitened residual component belongs to
        one noise group (:meth:`groups`).

        Parameters
        ----------
        m : array_like, shape (K, 3)
            Tracker points, m, tracker frame.

        Returns
        -------
        ndarray, shape (K, 3, 3)
            Whitening matrix of each point, 1/m.
        """
        r, _, st = self._beam(m)
        # a vector normal to the beam: the axis least aligned with it, projected
        axis = np.eye(3)[np.argmin(np.abs(r), axis=-1)]
        t1 = axis - np.sum(axis * r, -1)[..., None] * r
        t1 /= np.linalg.norm(t1, axis=-1)[..., None]
        t2 = np.cross(r, t1)
        return np.stack([r / self.distance, t1 / st[..., None], t2 / st[..., None]], -2)

    def groups(self, m):
        """Noise groups of the whitened components (:meth:`whitening`'s rows).

        Parameters
        ----------
        m : array_like, shape (K, 3)
            Tracker points, m, tracker frame.

        Returns
        -------
        labels : ndarray of int, shape (K, 3)
            0 along the beam, 1 across it.
        keys, names : list of str
            The groups.
        assumed : ndarray, shape (2,)
            Along the beam, and the RMS across it over the points, m.
        kinds : list of str
            Both ``"length"``.
        """
        _, _, st = self._beam(m)
        K = len(np.asarray(m))
        across = float(np.sqrt(np.mean(st**2))) if K else self.transverse
        return (np.tile([0, 1, 1], (K, 1)), ["along", "across"],
                ["tracker along the beam", "tracker across the beam"],
                np.array([self.distance, across]), ["length", "length"])

    def sample(self, m, rng):
        """Noise vectors for tracker points, drawn from :meth:`covariance`.

        Parameters
        ----------
        m : array_like, shape (K, 3)
            Tracker points, m, tracker frame.
        rng : numpy.random.Generator
            Random generator.

        Returns
        -------
        ndarray, shape (K, 3)
            Noise to add to the points, m.
        """
        m = np.asarray(m, float)
        L = np.linalg.cholesky(self.covariance(m))
        return np.einsum("kij,kj->ki", L, rng.standard_normal(m.shape))


def tracker_noise_arg(text: str | None, allow_none: bool, machine=None):
    """The tracker noise model of ``--noise``: leica (default), none, or a length.

    Parameters
    ----------
    text : str or None
        ``leica`` or None (the default model), ``none``, or a length for isotropic noise.
    allow_none : bool
        Whether ``none`` (exact points, a simulation) is allowed.
    machine : Machine, optional
        The length is checked against its size when given.

    Returns
    -------
    tuple
        ``(TrackerNoise or None, description)``.

    Raises
    ------
    InputError
        When the text is not a noise model allowed here.
    """
    from ...plausibility import check_option_scale
    from ...units import parse_quantity

    if text is None or text.strip().lower() == "leica":
        return TrackerNoise(), "leica (5 um along the beam, 7.5 um + 3 um/m across)"
    if text.strip().lower() == "none":
        if not allow_none:
            raise InputError("--noise none: the calibration weighs the points by their noise; "
                             "give leica or a length such as 10um")
        return None, "none"
    sigma = parse_quantity(text, "length", "--noise")
    if sigma == 0 and allow_none:
        return None, "none"
    if not sigma > 0:
        raise InputError(f"--noise: must be > 0 (a standard deviation), leica or none; got "
                         f"{text}")
    if machine is not None:
        check_option_scale(sigma, machine, "--noise", "noise", text)
    return TrackerNoise(sigma, sigma, 0.0), f"isotropic {sigma * 1e6:.4g} um"


def _tracker_noise_text(model) -> str:
    """Words of a :class:`~pkmcal.instruments.tracker.TrackerNoise` given as an object."""

    if model == TrackerNoise():
        return tracker_noise_arg(None, allow_none=False)[1]
    if model.distance == model.transverse and model.transverse_per_m == 0:
        return f"isotropic {model.distance * 1e6:.4g} um"
    return (f"{model.distance * 1e6:.4g} um along the beam, {model.transverse * 1e6:.4g} um + "
            f"{model.transverse_per_m * 1e6:.4g} um/m across")
