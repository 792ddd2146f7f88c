"""Rotations and pose conventions shared by every machine (SPEC 1)."""

from .rotations import (
    euler_from_matrix,
    kabsch,
    matrix_from_euler,
    matrix_from_quaternion,
    matrix_from_rotvec,
    quaternion_from_matrix,
    rot_x,
    rot_y,
    rot_z,
    rotation_angle,
    rotvec_from_matrix,
    rotvec_from_quaternion,
    skew,
)

__all__ = [
    "euler_from_matrix", "kabsch", "matrix_from_euler", "matrix_from_quaternion",
    "matrix_from_rotvec", "quaternion_from_matrix", "rot_x", "rot_y", "rot_z", "rotation_angle",
    "rotvec_from_matrix", "rotvec_from_quaternion", "skew",
]
