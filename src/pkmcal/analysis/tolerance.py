"""Tolerance analysis: how manufacturing tolerances of the geometry move the platform.

The machine is built with parameters ``u + du`` (joint positions, leg offsets, ...) and
commanded with the nominal model: the readings are the nominal ``q = IK(x; u)``, and the
platform goes to ``x + dx``. To first order (seed 003 eq. 9-10 for a six-leg platform, the
same for every machine through :meth:`~pkmcal.machines.Machine.ik_jacobians`)

``dq/dx dx + dq/du du = 0``, so ``dx = S du`` with the sensitivity ``S = -(dq/dx)^-1 dq/du``.

For a Stewart platform ``dq/dx = J_p / gain`` and, on the joint errors of one leg,
``dq/du = J_s / gain``: ``S = -J_p^-1 J_s`` (eq. 10), and a leg-offset error ``dl0`` gives
``J_p^-1 dl0``.

Tolerances are **half-widths** ``t`` of the tolerance bands of named parameters (SI units):
``uniform`` errors lie in ``[-t, t]`` (standard deviation ``t / sqrt(3)``), ``normal`` errors have
standard deviation ``t / 3`` (the band is ``+/- 3 sigma``). From them:

- the worst case ``|S| t`` per pose-error component (every error at its band edge, the signs
  that add up; exact for the linear model);
- the linear covariance ``S diag(sigma^2) S^T`` (Masory & Wang 1993 style);
- a Monte Carlo over the exact closure (Stewart platforms; all samples at once) or over the
  linear model (any machine).

Pose errors are ``[dp (m), dOmega (rad)]``, ``dOmega`` the rotation vector about the base axes.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .errors import SINGULAR_RTOL, closure_pose, pose_difference

DISTRIBUTIONS = ("uniform", "normal")


@dataclass(frozen=True)
class Tolerances:
    """Tolerance half-widths of every parameter of a machine (SI), and their distribution.

    Attributes
    ----------
    names : tuple of str
        Parameter names (the machine's registry order).
    band : ndarray, shape (n,)
        Half-widths ``t``, internal units (0 for parameters without a tolerance).
    distribution : {'uniform', 'normal'}, optional
        ``"uniform"`` (``[-t, t]``) or ``"normal"`` (``sigma = t / 3``).
    """

    names: tuple[str, ...]
    band: np.ndarray
    distribution: str = "uniform"

    @property
    def sigma(self) -> np.ndarray:
        """Standard deviation of each parameter error, (n,): ``t / sqrt(3)`` or ``t / 3``."""
        return self.band / (np.sqrt(3.0) if self.distribution == "uniform" else 3.0)

    def sample(self, n: int, rng=None) -> np.ndarray:
        """Random parameter errors drawn from the tolerance bands.

        Parameters
        ----------
        n : int
            Number of error vectors.
        rng : int, numpy.random.Generator or None, optional
            Random generator or seed.

        Returns
        -------
        ndarray, shape (n, len(names))
            Errors, internal units.
        """
        rng = np.random.default_rng(rng)
        if self.distribution == "uniform":
            return rng.uniform(-1.0, 1.0, (n, self.band.size)) * self.band
        return rng.standard_normal((n, self.band.size)) * self.sigma


def tolerances(machine, bands: Mapping[str, float],
               distribution: str = "uniform") -> Tolerances:
    """Tolerances of ``machine`` from ``{name pattern: half-width}``.

    Patterns are shell patterns on the parameter names (:mod:`fnmatch`), e.g. for a Stewart
    platform ``{"leg*.base.*": 10e-6, "leg*.platform.*": 10e-6, "leg*.l0": 5e-6}``; later
    patterns override earlier ones.

    Parameters
    ----------
    machine : Machine
        The machine whose parameters get tolerances.
    bands : mapping of str to float
        Pattern to half-width, internal units (m, rad).
    distribution : {'uniform', 'normal'}, optional
        Distribution of the errors within the bands.

    Returns
    -------
    Tolerances
        One band per parameter (0 where no pattern matches).

    Raises
    ------
    InputError
        When a pattern names no parameter, a band is negative or not finite, or the
        distribution is unknown.
    """
    if distribution not in DISTRIBUTIONS:
        raise InputError(f"distribution: {distribution!r} is not one of "
                         f"{', '.join(DISTRIBUTIONS)}")
    names = tuple(machine.parameters.names)
    band = np.zeros(len(names))
    for pattern, value in bands.items():
        value = float(value)
        if not (np.isfinite(value) and value >= 0):
            raise InputError(f"tolerance {pattern}: must be finite and >= 0, got {value}")
        hit = [i for i, n in enumerate(names) if fnmatch.fnmatchcase(n, pattern)]
        if not hit:
            raise InputError(f"tolerance {pattern}: no parameter of the {machine.kind} machine "
                             f"matches (e.g. {names[0]}, {names[-1]})")
        band[hit] = value
    return Tolerances(names, band, distribution)


def stewart_tolerances(machine, joint: float = 10e-6, length: float = 0.0,
                       distribution: str = "uniform") -> Tolerances:
    """Tolerances of a six-leg platform's joints and leg offsets.

    Every joint coordinate (base and platform) within ``+/- joint`` and every leg offset
    ``l0`` within ``+/- length``.

    Parameters
    ----------
    machine : Stewart
        The platform.
    joint : float, optional
        Half-width of each joint coordinate, m.
    length : float, optional
        Half-width of each leg offset ``l0``, m.
    distribution : {'uniform', 'normal'}, optional
        Distribution of the errors.

    Returns
    -------
    Tolerances
        The bands (gains have none).

    Raises
    ------
    InputError
        As :func:`tolerances`.
    """
    return tolerances(machine, {"leg*.base.*": joint, "leg*.platform.*": joint,
                                "leg*.l0": length}, distribution)


def sensitivity(machine, P, R=None, u=None) -> np.ndarray:
    """``S = dx/du`` with the readings held at their nominal values: ``S = -(dq/dx)^-1 dq/du``.

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    P : array_like, shape (..., 3)
        Platform positions, m.
    R : array_like, shape (..., 3, 3), optional
        Platform orientations (translation-only machines ignore them).
    u : array_like, shape (n_params,), optional
        Parameter vector; default: the machine's.

    Returns
    -------
    ndarray, shape (..., 6, n_params)
        Rows ``[dp (m), dOmega (rad)]`` per unit parameter error; NaN at unreachable or
        singular poses.
    """
    q, dq_dx, dq_du = machine.ik_jacobians(P, R, u, want_du=True)
    ok = np.all(np.isfinite(q), axis=-1) & np.all(np.isfinite(dq_dx), axis=(-1, -2))
    scale = np.ones(dq_dx.shape[-1])
    scale[3:] = 1.0 / machine.characteristic_length()      # rotations: per unit length
    sv = np.linalg.svd(np.where(ok[..., None, None], dq_dx, 0.0) * scale, compute_uv=False)
    ok &= sv[..., -1] > SINGULAR_RTOL * sv[..., 0]
    safe = np.where(ok[..., None, None], dq_dx, np.eye(dq_dx.shape[-1]))
    S = -np.linalg.solve(safe, np.where(ok[..., None, None], dq_du, 0.0))
    return np.where(ok[..., None, None], S, np.nan)


def worst_case(S, tol: Tolerances) -> np.ndarray:
    """Worst-case bound ``|S| t`` of each pose-error component.

    Parameters
    ----------
    S : array_like, shape (..., 6, n)
        Sensitivity (:func:`sensitivity`).
    tol : Tolerances
        The tolerance bands.

    Returns
    -------
    ndarray, shape (..., 6)
        Bounds, m and rad.
    """
    return np.abs(S) @ tol.band


def linear_covariance(S, tol: Tolerances) -> np.ndarray:
    """Linear covariance ``S diag(sigma^2) S^T`` of the pose error.

    Parameters
    ----------
    S : array_like, shape (..., 6, n)
        Sensitivity (:func:`sensitivity`).
    tol : Tolerances
        The tolerance bands (their ``sigma``).

    Returns
    -------
    ndarray, shape (..., 6, 6)
        Covariance of ``[dp, dOmega]``.
    """
    return (S * tol.sigma**2) @ np.swapaxes(S, -1, -2)


@dataclass
class MonteCarloResult:
    """Pose errors of ``n`` machines built within the tolerances, at one pose.

    Attributes
    ----------
    dx : ndarray, shape (n, 6)
        Pose errors ``[dp (m), dOmega (rad)]``.
    mean : ndarray, shape (6,)
        Sample mean over the converged samples.
    cov : ndarray, shape (6, 6)
        Sample covariance over the converged samples.
    linear_cov : ndarray, shape (6, 6)
        The linear prediction.
    worst_case : ndarray, shape (6,)
        The linear worst-case bound.
    exact : bool
        True when the errors come from the exact closure (else the linear model).
    converged : ndarray of bool, shape (n,)
        Closure converged (all True for the linear model).
    """

    dx: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    linear_cov: np.ndarray
    worst_case: np.ndarray
    exact: bool
    converged: np.ndarray

    @property
    def std(self) -> np.ndarray:
        """Sample standard deviation of each pose-error component, (6,)."""
        return np.sqrt(np.diag(self.cov))


def monte_carlo(machine, P, R, tol: Tolerances, samples: int = 10000, rng=None,
                exact: bool | None = None) -> MonteCarloResult:
    """Monte Carlo of the pose error at the pose ``(P, R)``.

    Each sample is a machine ``u + du`` with ``du`` drawn from ``tol``, commanded with the
    nominal readings. ``exact`` (default: True for a Stewart platform) solves the perturbed
    closure for all samples at once (:func:`~pkmcal.analysis.errors.closure_pose`); otherwise
    ``dx = S du`` (any machine).

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    P : array_like, shape (3,)
        Platform position, m.
    R : array_like, shape (3, 3) or None
        Platform orientation; None for the identity.
    tol : Tolerances
        The tolerance bands.
    samples : int, optional
        Number of machines (>= 2).
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.
    exact : bool, optional
        Solve the exact closure (Stewart platforms only).

    Returns
    -------
    MonteCarloResult
        The samples' pose errors and their statistics, with the linear predictions.

    Raises
    ------
    InputError
        When ``samples`` is not a whole number >= 2, the pose is unreachable or singular, or
        ``exact`` is asked for a machine other than a Stewart platform.
    """
    if not (isinstance(samples, (int, np.integer)) and samples >= 2):
        raise InputError(f"samples: must be a whole number >= 2, got {samples}")
    P = np.asarray(P, float)
    R = np.eye(3) if R is None else np.asarray(R, float)
    S = sensitivity(machine, P, R)
    if not np.all(np.isfinite(S)):
        raise InputError("the pose cannot be reached by the nominal machine")
    du = tol.sample(int(samples), rng)
    q = machine.ik(P, R)                                   # nominal readings, held
    legs = machine.leg_joints(q) is not None               # straight legs: closure solvable
    exact = legs if exact is None else bool(exact)
    if exact and not legs:
        raise InputError(f"exact Monte Carlo is implemented for stewart machines, not "
                         f"{machine.kind}; use exact=False (linear model)")
    if exact:
        dx, converged = _closure_errors(machine, P, R, q, du)
    else:
        dx, converged = du @ S.T, np.ones(len(du), bool)
    good = dx[converged]
    return MonteCarloResult(dx, good.mean(axis=0), np.cov(good, rowvar=False),
                            linear_covariance(S, tol), worst_case(S, tol), exact, converged)


def _closure_errors(machine, P, R, q, du):
    """Pose errors of the machines ``u + du`` at the readings ``q`` (exact: the legs closed)."""
    base, platform, lengths = machine.leg_joints(q, machine.u + du)    # (n, ...) per sample
    sol = closure_pose(P, R, base, platform, lengths)
    return pose_difference(sol.P, sol.R, P, R), sol.converged


@dataclass
class ErrorMap:
    """Tolerance pose errors over a horizontal workspace slice.

    Attributes
    ----------
    x : ndarray, shape (nx,)
        Grid, m.
    y : ndarray, shape (ny,)
        Grid, m.
    z : float
        Height, m.
    worst : ndarray, shape (ny, nx, 6)
        Worst-case bound per component (NaN where unreachable).
    std : ndarray, shape (ny, nx, 6)
        Linear standard deviation per component (NaN where unreachable).
    valid : ndarray of bool, shape (ny, nx)
        False where the pose is unreachable or singular.
    """

    x: np.ndarray
    y: np.ndarray
    z: float
    worst: np.ndarray
    std: np.ndarray
    valid: np.ndarray


def error_map(machine, x, y, z: float, tol: Tolerances, R=None) -> ErrorMap:
    """Worst-case bound and linear standard deviation of the pose error over a grid.

    All grid points at once.

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    x : array_like, shape (nx,)
        Grid positions along X, m.
    y : array_like, shape (ny,)
        Grid positions along Y, m.
    z : float
        Height, m.
    tol : Tolerances
        The tolerance bands.
    R : array_like, shape (3, 3), optional
        Platform orientation; default identity.

    Returns
    -------
    ErrorMap
        The maps over the ``ny`` by ``nx`` grid.
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    X, Y = np.meshgrid(x, y)
    P = np.stack([X, Y, np.full_like(X, float(z))], axis=-1)
    R = np.broadcast_to(np.eye(3) if R is None else np.asarray(R, float), X.shape + (3, 3))
    S = sensitivity(machine, P, R)
    valid = np.all(np.isfinite(S), axis=(-1, -2))
    cov = linear_covariance(np.where(valid[..., None, None], S, 0.0), tol)
    std = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    return ErrorMap(x, y, float(z), worst_case(S, tol), np.where(valid[..., None], std, np.nan),
                    valid)


__all__ = ["DISTRIBUTIONS", "ErrorMap", "MonteCarloResult", "Tolerances", "error_map",
           "linear_covariance", "monte_carlo", "sensitivity", "stewart_tolerances",
           "tolerances", "worst_case"]
