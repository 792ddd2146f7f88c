"""How a machine type is read from and written to a machine file: the pieces a machine module
needs to state its own file section (:class:`MachineFormat`, the strict pydantic base, the
number types, the head every file starts with and the sections several machine types share).

They live below :mod:`pkmcal.io` because a machine module declares its section and io imports
machines (never the reverse): :mod:`pkmcal.io.machine_file` adds what every machine file has
(``pkmcal``, ``machine``, ``name``, ``units``, the instrument sections ``tracker``, ``ballbar``,
``bed``, then ``joint_limits`` and ``calibration``) to the schema a machine module gives, where
that schema does not state them itself, and reads ``FILE_FORMAT`` of every module listed in
:mod:`pkmcal.machines.registry`. A schema that derives from :class:`MachineFileHead` starts
with the head; one that declares an instrument section (``tracker: TrackerPose | None``: a
machine whose target on the platform the file fixes) places it and chooses its form.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, Strict, field_validator
from pydantic_core import PydanticCustomError

from ..kinematics import matrix_from_euler
from ..units import ANGLE, LENGTH
from .base import Machine

#: a finite number (an int is read as a float)
Number = Annotated[float, Strict(), Field(allow_inf_nan=False)]
#: a finite number > 0
Positive = Annotated[float, Strict(), Field(allow_inf_nan=False, gt=0)]
#: three finite numbers
Vector3 = Annotated[list[Number], Field(min_length=3, max_length=3)]
#: two finite numbers (a point of a plane)
Vector2 = Annotated[list[Number], Field(min_length=2, max_length=2)]
#: six finite numbers (a pose x, y, z, psi, theta, phi)
Pose6 = Annotated[list[Number], Field(min_length=6, max_length=6)]
#: a finite number >= 0
NonNegative = Annotated[float, Strict(), Field(allow_inf_nan=False, ge=0)]
#: three rows of three finite numbers
Matrix3 = Annotated[list[Vector3], Field(min_length=3, max_length=3)]

#: a rotation matrix read from a file may deviate from orthonormal by this much (6-digit
#: exports); it is then replaced by the nearest rotation. Within 1e-12 it is kept as written.
ROTATION_TOL = 1e-5


class StrictModel(BaseModel):
    """A file section: unknown keys refused, no type coercion (``"1"`` is not a number)."""

    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)


@dataclass(frozen=True)
class MachineFormat:
    """How one machine type is read from and written to a file.

    Attributes
    ----------
    schema : type of pydantic.BaseModel
        Validates the file's mapping.
    build : callable
        ``build(document, source) -> Machine`` (document validated, file units).
    dump : callable
        ``dump(machine, units) -> dict`` of the machine-specific keys, in file order.
    counts : dict of str to int
        Required length of each list key (``{"chains": 6}``), for messages.
    home_text : str, optional
        What ``home`` holds, for messages.
    hints : dict of str to str, optional
        Hints shown with a missing key of this machine type.
    kinds : dict of tuple to str, optional
        Key pattern -> ``"length"``, ``"dimension"`` (a length that is one of the machine's
        dimensions: a link, an arm, a radius; one this small relative to the machine is a
        typo), ``"angle"`` or ``"gain"`` (``"*"`` matches any key or index), for the
        plausibility of the numbers; ``home`` is known to every format.
    size : callable, optional
        ``size(document) -> (metres, what it is)``: the machine's own size for plausibility.
    kind : str, optional
        The machine type (``machine:`` in files) of the format a machine module exports
        (:mod:`pkmcal.machines.registry`).
    default : callable, optional
        ``default() -> Machine``: the module's default machine of this type (a design that
        every command runs on: tests walk every registered type with it).
    """

    schema: type[BaseModel]
    build: Callable[[Any, str], Machine]
    dump: Callable[[Machine, dict], dict]
    counts: dict[str, int]
    home_text: str = "[x, y, z, psi, theta, phi]"
    hints: dict[str, str] | None = None
    #: key pattern -> "length", "dimension", "angle" or "gain" (``"*"`` matches any key or
    #: index); ``home`` is known to every format
    kinds: dict[tuple, str] | None = None
    #: ``size(document) -> (metres, what it is)``: the machine's own size for plausibility
    size: Callable[[Any], tuple[float, str]] | None = None
    kind: str = ""
    #: ``default() -> Machine``: the module's default machine of this type
    default: Callable[[], Machine] | None = None


def show(value) -> str:
    """A file value as messages show it (``repr``, booleans in YAML's words, at most 60
    characters)."""
    text = repr(value) if not isinstance(value, bool) else str(value).lower()
    return text if len(text) <= 60 else text[:57] + "..."


def factors(units) -> tuple[float, float]:
    """SI factors ``(length, angle)`` of a file's units ``{"length": ..., "angle": ...}``."""
    return LENGTH[units["length"]], ANGLE[units["angle"]]


def home_pose(home, fl: float, fa: float):
    """``(P, R)`` of a file's ``home: [x, y, z, psi, theta, phi]`` (None without it)."""
    if home is None:
        return None
    h = np.asarray(home, float)
    return h[:3] * fl, matrix_from_euler(h[3:] * fa)


def vector(value, fl: float) -> list[float]:
    """A 3-vector in metres as file numbers (file length unit)."""
    return [float(v) / fl for v in np.asarray(value, float).reshape(3)]


def file_rotation(value) -> np.ndarray:
    """A rotation matrix from a file: kept as written when orthonormal to 1e-12, else the
    nearest rotation (the schema has checked it is within :data:`ROTATION_TOL`)."""
    R = np.asarray(value, float)
    if np.max(np.abs(R.T @ R - np.eye(3))) <= 1e-12:
        return R
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def frame_section(pose, fl: float) -> dict:
    """``{rotation, translation}`` of a frame ``(R, t)`` (t in metres) as file numbers."""
    R, t = pose
    return {"rotation": [[float(v) for v in row] for row in np.asarray(R, float)],
            "translation": [float(v) / fl for v in np.asarray(t, float)]}


# --------------------------------------------------------------------------------------------
# The head of every machine file and the sections several machine types share
# --------------------------------------------------------------------------------------------


class Units(StrictModel):
    """Units of the numbers in this file."""

    length: Literal["mm", "m", "in", "inch"]
    angle: Literal["deg", "rad"]


class MachineFileHead(StrictModel):
    """What every machine file starts with; :mod:`pkmcal.io.machine_file` states ``machine``
    as the format's own type."""

    pkmcal: Literal[1]
    machine: str
    name: str | None = None
    units: Units


class ConstraintLink(StrictModel):
    """Constraint link between base point O and platform point P (SPEC 2.1)."""

    length: Positive


class TrackerPose(StrictModel):
    """``base_from_tracker``: a tracker point ``m`` is ``rotation @ m + translation`` in the
    base frame."""

    rotation: Matrix3
    translation: Vector3

    @field_validator("rotation")
    @classmethod
    def _proper_rotation(cls, value):
        R = np.asarray(value, float)
        dev = float(np.max(np.abs(R.T @ R - np.eye(3))))
        det = float(np.linalg.det(R))
        if dev > ROTATION_TOL or det <= 0:
            raise PydanticCustomError(
                "rotation_matrix",
                "not a rotation matrix (rows must be orthonormal with determinant +1; "
                "|R^T R - I| = {dev}, det = {det})",
                {"dev": f"{dev:.3g}", "det": f"{det:.6g}"})
        return value


class TrackerSection(TrackerPose):
    """``tracker`` of a machine whose target the file does not fix: ``base_from_tracker`` and,
    optionally, the places of the targets on the platform (platform frame, file length unit),
    one per value of a data file's ``target`` column (1..K); without ``targets`` the target is
    the platform origin."""

    targets: Annotated[list[Vector3], Field(min_length=1)] | None = None


class BallbarSetup(StrictModel):
    """One ballbar mounting: ``pivot`` (base frame) and ``ball`` (platform frame), file length
    unit; the measured length is ``|P + R ball - pivot|``."""

    pivot: Vector3
    ball: Vector3


#: ``ballbar``: one mounting per value of a data file's ``setup`` column (1..K)
Ballbar = Annotated[list[BallbarSetup], Field(min_length=1)]


class BedSurface(StrictModel):
    """The bed's own shape beside its plane (what probed meshes show and no kinematics
    holds): heights on a square grid of ``len(values)`` nodes per side over ``[-radius,
    radius]`` in x and y, rows by ascending y (the file's length unit)."""

    radius: Positive
    values: Annotated[list[Annotated[list[Number], Field(min_length=2)]], Field(min_length=2)]

    @field_validator("values")
    @classmethod
    def _square(cls, value):
        if any(len(row) != len(value) for row in value):
            raise PydanticCustomError(
                "bed_surface", "expected a square grid: {n} rows of {n} values",
                {"n": len(value)})
        return value


class BedPlane(StrictModel):
    """The bed a probe measured: the plane ``z = height + tilt_x x + tilt_y y`` of the base
    frame (``height`` in the file's length unit; ``tilt_x``, ``tilt_y`` slopes dz/dx, dz/dy),
    and optionally its own shape beside the plane (``surface``)."""

    height: Number
    #: slopes beyond 1 (45 deg) are no bed a probe measured
    tilt_x: Annotated[float, Strict(), Field(allow_inf_nan=False, ge=-1.0, le=1.0)] = 0.0
    tilt_y: Annotated[float, Strict(), Field(allow_inf_nan=False, ge=-1.0, le=1.0)] = 0.0
    surface: BedSurface | None = None


class MeasurementFramesSection(StrictModel):
    """Frames of full-pose measurements (SPEC 2.4): ``mocap_from_base`` (a base point ``x`` is
    ``rotation @ x + translation`` in the measurement frame) and ``platform_from_marker`` (a
    marker point ``y`` is ``rotation @ y + translation`` in the platform frame)."""

    mocap_from_base: TrackerPose
    platform_from_marker: TrackerPose
