"""Machines: the shared :class:`Machine` interface and one module per machine type."""

from .base import FKResult, Machine, newton_pose_solve
from .delta import Delta, default_delta, delta_parameters
from .hexaslide import HexaSlide, default_hexaslide, hexaslide_parameters, paper_table1_deviations
from .stewart import Stewart, cubic_6upu, stewart_parameters

__all__ = ["Delta", "FKResult", "HexaSlide", "Machine", "Stewart", "cubic_6upu", "default_delta",
           "default_hexaslide", "delta_parameters", "hexaslide_parameters", "newton_pose_solve",
           "paper_table1_deviations", "stewart_parameters"]
