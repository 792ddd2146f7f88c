"""Machines: the shared :class:`Machine` interface and one module per machine type."""

from .base import FKResult, Machine, PhysicalLimit, Reachability, newton_pose_solve
from .delta import Delta, default_delta, delta_parameters
from .hexaslide import HexaSlide, default_hexaslide, hexaslide_parameters, paper_table1_deviations
from .linear_delta import (
    LinearDelta,
    default_linear_delta,
    linear_delta,
    linear_delta_parameters,
)
from .stewart import Stewart, cubic_6upu, stewart_parameters

__all__ = ["Delta", "FKResult", "HexaSlide", "LinearDelta", "Machine", "PhysicalLimit",
           "Reachability", "Stewart", "cubic_6upu",
           "default_delta", "default_hexaslide", "default_linear_delta", "delta_parameters",
           "hexaslide_parameters", "linear_delta", "linear_delta_parameters",
           "newton_pose_solve", "paper_table1_deviations", "stewart_parameters"]
